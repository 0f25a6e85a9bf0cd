"""`splatam export --format mesh --frames keyframes|all|N`: fusing the frames between the keyframes
(re-read from the capture) completes the mesh; without a readable capture, one warning and the
keyframes alone; the CLI option."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from app.cli import splatam_main
from splat_core.camera import invert_pose
from splat_core.config import load_config
from splat_core.export.decimate import decimate
from splat_core.export.mesh import build_mesh, fusion_indices
from splat_core.refine.run_data import load_run_data
from splat_core.run import Pipeline, open_input
from splat_core.run.frame_feed import prepare_frame
from splat_core.synthetic import SyntheticSource
from helpers import captures as fixtures

from mesh_score import depth_points, score_against_scene  # benchmarks/, on sys.path via conftest

N = 16
KEYFRAMES = (0, 8)


def exact_run(src, capture=None):
    """A run of `src` at its exact poses whose keyframes are KEYFRAMES (what build_mesh reads of a run)."""
    intr = src.intrinsics
    w2cs = [invert_pose(src.c2w[i]) for i in range(N)]
    keyframes = []
    for k in KEYFRAMES:
        f = prepare_frame(src, k, intr, None)
        keyframes.append(SimpleNamespace(frame_index=k, color=f.color, depth=f.depth, w2c=w2cs[k]))
    records = [dict(index=i, source_index=i) for i in range(N)]
    records[5]["lost"] = "tracking residual too high"
    return SimpleNamespace(run_dir=Path("run"), intrinsics=intr, w2cs=w2cs, keyframes=keyframes, records=records,
                           keyframe_indices=list(KEYFRAMES), config=SimpleNamespace(max_depth=None), capture=capture)


def test_fusing_every_frame_completes_the_mesh_keyframes_leave_holes():
    src = SyntheticSource(n_frames=N, width=96, height=72)
    run = exact_run(src)
    truth = np.concatenate([depth_points(src.render_view(src.c2w[i])[1], src.c2w[i], src.intrinsics, 2)
                            for i in range(N)])
    assert fusion_indices(run, "keyframes") == [0, 8]
    assert fusion_indices(run, "all") == [i for i in range(N) if i != 5]          # the lost frame left out
    assert fusion_indices(run, "3") == [0, 3, 6, 8, 9, 12, 15]
    scores = {}
    for frames in ("keyframes", "all"):
        mesh = build_mesh(run, voxel=0.02, frames=frames, source=src)
        assert mesh.metadata["fused"] == len(fusion_indices(run, frames))
        scores[frames] = score_against_scene(mesh, src.scene, truth)
    assert scores["all"]["completion"] >= scores["keyframes"]["completion"] + 0.04, scores
    assert scores["all"]["completion"] >= 0.85, scores
    assert scores["all"]["accuracy"]["median_cm"] <= 1.0, scores
    # What the viewer is sent: a quarter of the faces, still on the surface, colours kept.
    small = decimate(mesh, len(mesh.faces) // 4)
    assert len(mesh.faces) // 8 < len(small.faces) <= len(mesh.faces) // 4
    score = score_against_scene(small, src.scene, truth)
    assert score["accuracy"]["median_cm"] <= 1.0 and score["completion"] >= scores["all"]["completion"] - 0.05, score
    assert np.abs(np.median(small.visual.vertex_colors[:, :3], 0) - np.median(mesh.visual.vertex_colors[:, :3], 0)).max() < 8
    assert decimate(mesh, len(mesh.faces)) is mesh


@pytest.mark.parametrize("capture", [None, {"path": "/nonexistent/capture", "format": None}])
def test_without_a_readable_capture_one_warning_and_the_keyframes(capture):
    src = SyntheticSource(n_frames=N, width=64, height=48)
    run = exact_run(src, capture)
    warnings = []
    mesh = build_mesh(run, voxel=0.03, frames="all", warn=warnings.append)
    assert len(warnings) == 1 and "keyframes only" in warnings[0] and "\n" not in warnings[0], warnings
    assert mesh.metadata["fused"] == len(KEYFRAMES) and mesh.metadata["frames"] == "keyframes"
    assert len(mesh.faces) > 0


TINY = """base: cpu
resolution: [32, 24]
checkpoint_every: 0
keyframes: {every: 4}
tracking: {iterations: 4}
mapping: {iterations: 3, first_frame_iterations: 10, window_size: 4}
"""


@pytest.fixture(scope="module")
def capture_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("meshframes")
    fixtures.write_tum(root / "cap", n=8)
    (root / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(open_input(root / "cap"), load_config(str(root / "tiny.yaml")), root / "run")
    while pipe.step() is not None:
        pass
    pipe.finish()
    return root


def export(run_dir, out, capsys, *argv):
    code = splatam_main(["export", str(run_dir), "--format", "mesh", "--out", str(out), "--voxel", "0.02",
                         "--quiet", *argv])
    captured = capsys.readouterr()
    summary = json.loads(captured.out.strip().splitlines()[-1]) if code == 0 else None
    return code, summary, captured.err.strip()


def test_cli_frames_option_and_fallback(capture_run, tmp_path, capsys):
    run_dir, out = capture_run / "run", tmp_path / "m.ply"
    code, kf, err = export(run_dir, out, capsys, "--frames", "keyframes")
    assert code == 0 and kf["frames"] == "keyframes" and not err
    code, every, err = export(run_dir, out, capsys, "--frames", "all")
    assert code == 0 and every["frames"] == "all" and every["fused"] == 8 > kf["fused"] and not err
    code, third, _ = export(run_dir, out, capsys)                                    # default: every 3rd frame
    assert code == 0 and third["frames"] == "3" and kf["fused"] <= third["fused"] < 8
    assert third["fused"] == len(set(range(0, 8, 3)) | set(load_run_data(run_dir).keyframe_indices))
    # The capture moved: one warning line, keyframes; --input names it again.
    shutil.move(capture_run / "cap", capture_run / "moved")
    code, fallback, err = export(run_dir, out, capsys, "--frames", "all")
    assert code == 0 and fallback["fused"] == kf["fused"]
    assert err.startswith("warning: ") and "\n" not in err and "keyframes only" in err
    code, again, err = export(run_dir, out, capsys, "--input", str(capture_run / "moved"), "--frames", "all")
    assert code == 0 and again["fused"] == 8 and not err
    for argv in (["--frames", "zero"], ["--frames", "all", "--input", str(capture_run / "nowhere")]):
        code, _, err = export(run_dir, out, capsys, *argv)
        assert code == 2 and err.startswith("error: ") and "\n" not in err
