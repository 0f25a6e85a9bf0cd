"""`splatam export --format mesh`: TSDF fusion + marching cubes scored against the synthetic scene's
exact surfaces (accuracy: mesh to surface; completion: observed surface within 2 cm of the mesh),
at exact poses and on a finished SLAM run; colours, bounded memory, the files trimesh writes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from app.cli import splatam_main
from splat_core.camera import invert_pose
from splat_core.config import load_config
from splat_core.export.mesh import build_mesh, extract_mesh, fuse_views
from splat_core.run import Pipeline
from splat_core.refine.run_data import load_run_data
from splat_core.synthetic import SyntheticSource

from mesh_score import depth_points, scene_surface_distance, score_against_scene  # benchmarks/, on sys.path via conftest

RUN_CONFIG = """base: cpu
resolution: [128, 96]
checkpoint_every: 0
keyframes: {every: 2}
mapping: {iterations: 8, first_frame_iterations: 40, window_size: 4}
"""


def test_marching_cubes_mask_convention():
    """mesh._cube_mask relies on scikit-image meshing cube [x-1, x]^3 where mask[x, y, z] is set."""
    from skimage.measure import marching_cubes

    volume = np.ones((4, 4, 4))
    volume[0] = -1.0
    for idx, faces in (((0, 0, 0), 0), ((1, 0, 0), 0), ((1, 1, 1), 2)):
        mask = np.zeros(volume.shape, bool)
        mask[idx] = True
        try:
            _, f, _, _ = marching_cubes(volume, 0.0, mask=mask)
        except (ValueError, RuntimeError):
            f = []
        assert len(f) == faces


def test_scene_surface_distance_is_exact():
    scene = SyntheticSource(n_frames=2).scene
    pts = np.array([[0.0, 1.5, -2.0], [0.0, 1.45, -2.0], [2.9, 0.0, -2.0], [0.1, 0.75, 0.5],
                    scene.objects[1].centre + [0, 0, scene.objects[1].radius + 0.03]])
    np.testing.assert_allclose(scene_surface_distance(scene, pts), [0.0, 0.05, 0.1, 0.05, 0.03], atol=1e-12)


def test_fusion_at_exact_poses_matches_the_exact_surfaces():
    src = SyntheticSource(n_frames=12, width=96, height=72)
    views, truth = [], []
    for i in range(0, 12, 2):
        color, depth = src.render_view(src.c2w[i])
        views.append((color, depth, invert_pose(src.c2w[i])))
        truth.append(depth_points(depth, src.c2w[i], src.intrinsics, 2))
    volume = fuse_views(iter(views), src.intrinsics, voxel=0.01, trunc=0.04)
    mesh = extract_mesh(volume)
    score = score_against_scene(mesh, src.scene, np.concatenate(truth))
    assert score["accuracy"]["median_cm"] <= 0.5 and score["accuracy"]["p90_cm"] <= 1.0, score
    assert score["completion"] >= 0.9, score
    # Sparse: the allocated blocks are a small part of a dense grid over the mesh's bounding box.
    dense_voxels = np.prod(np.ceil(mesh.extents / 0.01))
    assert volume.n * 8 ** 3 < 0.25 * dense_voxels
    # Faces face the cameras that saw them (normals point out of the surface, into free space).
    centres, normals = mesh.triangles_center, mesh.face_normals
    eye = src.c2w[0][:3, 3]
    seen = np.einsum("ij,ij->i", normals, eye - centres) > 0
    assert seen.mean() > 0.9


@pytest.fixture(scope="module")
def synthetic_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("mesh")
    (root / "run.yaml").write_text(RUN_CONFIG)
    src = SyntheticSource(n_frames=10, width=128, height=96)
    pipe = Pipeline(src, load_config(str(root / "run.yaml")), root / "run")
    while pipe.step() is not None:
        pass
    pipe.finish()
    return root / "run", src


@pytest.mark.slow
def test_mesh_of_a_finished_synthetic_run_meets_the_targets(synthetic_run):
    run_dir, src = synthetic_run
    run = load_run_data(run_dir)
    mesh = build_mesh(run)                                     # captured depth, default voxel/trunc
    first = src.c2w[int(run.records[0]["source_index"])]      # run world = first camera
    mesh.apply_transform(first)
    truth = np.concatenate([depth_points(src.render_view(src.c2w[int(run.records[k]["source_index"])],
                                                         run.intrinsics)[1],
                                         src.c2w[int(run.records[k]["source_index"])], run.intrinsics, 2)
                            for k in run.keyframe_indices])
    score = score_against_scene(mesh, src.scene, truth)
    assert score["accuracy"]["median_cm"] <= 1.0, score
    assert score["completion"] >= 0.85, score
    # Vertex colours are the scene's (RGB order, not BGR): compare with the first keyframe's view.
    color, depth = src.render_view(first, run.intrinsics)
    w2c = invert_pose(first)
    cam = mesh.vertices @ w2c[:3, :3].T + w2c[:3, 3]
    K = run.intrinsics
    u = np.round(K.fx * cam[:, 0] / cam[:, 2] + K.cx).astype(int)
    v = np.round(K.fy * cam[:, 1] / cam[:, 2] + K.cy).astype(int)
    ok = (cam[:, 2] > 0.1) & (u >= 0) & (v >= 0) & (u < K.width) & (v < K.height)
    ok[ok] &= np.abs(depth[v[ok], u[ok]] - cam[ok, 2]) < 0.01
    assert ok.sum() > 1000
    mesh_rgb, seen_rgb = mesh.visual.vertex_colors[ok, :3] / 255.0, color[v[ok], u[ok]]
    err = np.median(np.abs(mesh_rgb - seen_rgb))
    assert err < 0.02
    assert err < 0.5 * np.median(np.abs(mesh_rgb[:, ::-1] - seen_rgb))        # BGR would fail


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_cli_writes_a_mesh_trimesh_reads(synthetic_run, tmp_path, capsys, suffix):
    run_dir, _ = synthetic_run
    out = tmp_path / f"map{suffix}"
    fmt = ["--format", "mesh"] if suffix == ".ply" else []       # .obj / .glb name a mesh on their own
    assert splatam_main(["export", str(run_dir), *fmt, "--out", str(out), "--voxel", "0.02", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["voxel"] == 0.02 and summary["trunc"] == pytest.approx(0.08)
    loaded = trimesh.load(out, force="mesh")
    assert len(loaded.faces) == summary["faces"] > 1000
    assert loaded.visual.kind == "vertex" and np.ptp(np.asarray(loaded.visual.vertex_colors)[:, :3]) > 50
    assert [p.name for p in tmp_path.iterdir()] == [out.name]            # nothing temporary left


@pytest.mark.slow
def test_rendered_depth_mesh_and_bad_options(synthetic_run, tmp_path, capsys):
    run_dir, _ = synthetic_run
    mesh = build_mesh(load_run_data(run_dir), voxel=0.02, depth="rendered")
    assert len(mesh.faces) > 1000 and mesh.metadata["depth"] == "rendered"
    for argv in (["--voxel", "0.02", "--trunc", "0.01"], ["--voxel", "-1"], ["--voxel", "0.0001"]):
        assert splatam_main(["export", str(run_dir), "--format", "mesh", "--out", str(tmp_path / "m.ply"),
                             "--quiet", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err
    assert not (tmp_path / "m.ply").exists()
