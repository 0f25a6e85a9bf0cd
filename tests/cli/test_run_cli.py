"""`splatam run`: outputs, resume, and bad input (one line, exit 2, no traceback)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from app.cli import splatam_main
from splat_core.config import load_config
from splat_core.io.ply import read_ply
from splat_core.io.trajectory import read_tum_trajectory
from splat_core.run import Pipeline, open_input
from helpers import captures as fixtures
from helpers.configs import TINY



@pytest.fixture()
def capture(tmp_path):
    fixtures.write_tum(tmp_path / "cap", n=8)
    (tmp_path / "tiny.yaml").write_text(TINY)
    return tmp_path


def run_cli(args, capsys):
    code = splatam_main(args)
    err = capsys.readouterr().err
    return code, err


def test_run_writes_a_complete_run_folder(capture, capsys):
    out = capture / "run"
    code = splatam_main(["run", "--input", str(capture / "cap"), "--out", str(out),
                         "--config", str(capture / "tiny.yaml"), "--quiet"])
    assert code == 0
    stamps, c2w = read_tum_trajectory(out / "trajectory.txt")
    assert len(stamps) == 8 and np.allclose(c2w[0], np.eye(4), atol=1e-6)
    ply = read_ply(out / "map.ply")
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(ply["means"]) == metrics["num_gaussians"] > 0
    for key in ("ate_rmse_cm", "psnr", "ssim", "depth_l1_cm", "seconds_per_frame", "peak_memory_mb", "per_frame"):
        assert metrics[key] is not None, key
    assert len(metrics["per_frame"]) == 8
    # CPU time per frame (every thread), summed over the records: the run did work on every frame
    cpu = [r["cpu_seconds"] for r in metrics["per_frame"]]
    assert all(c >= 0 for c in cpu) and sum(cpu) > 0
    assert metrics["cpu_seconds_per_frame"] == pytest.approx(sum(cpu) / 8)
    # which pose tracking kept, per frame: none on frame 0 (the origin), a tracker candidate after
    starts = [r["tracking_start"] for r in metrics["per_frame"]]
    assert starts[0] is None and set(starts[1:]) <= {"aligned", "prediction"} and None not in starts[1:]
    # the map's coverage of each tracked frame's depth (what lost_tracking.min_coverage judges)
    cover = [r["tracking_coverage"] for r in metrics["per_frame"]]
    assert cover[0] is None and all(0.5 < c <= 1.0 for c in cover[1:])
    assert load_config(str(out / "config.yaml")).mapping.iterations == 3
    assert (out / "checkpoint" / "state.npz").is_file()
    # A second run into the same folder must not silently overwrite it.
    code, err = run_cli(["run", "--input", str(capture / "cap"), "--out", str(out), "--quiet"], capsys)
    assert code == 2 and "--resume" in err


@pytest.mark.parametrize("pixels,memory_mb", [("all", 512.0), ("random", 0.01)])
def test_resume_equals_an_uninterrupted_run(capture, pixels, memory_mb):
    # Sequential engine: bit for bit, sparse tracking's random pixel choice included (its state
    # is in the checkpoint). memory_mb 0.01 keeps no keyframe in memory: all are read back from
    # checkpoint/keyframes.bin, and the killed run's keyframe 4, appended after the checkpoint
    # of frame 3 (when it is one), must be dropped on resume.
    cfg = load_config(str(capture / "tiny.yaml"), overrides={"tracking": {"pixels": pixels, "pixel_tile": 4},
                                                             "keyframes": {"memory_mb": memory_mb}})
    full = Pipeline(open_input(capture / "cap"), cfg, capture / "full")
    while full.step() is not None:
        pass
    full.finish()

    killed = Pipeline(open_input(capture / "cap"), cfg, capture / "resumed")
    for _ in range(5):                     # checkpoint written after frame 3; frames 4-5 are lost
        killed.step()
    store = killed.engine.slam.keyframes
    assert len(store) >= 1 and store.resident_bytes() == (memory_mb > 1) * len(store) * store.record_bytes
    del killed
    resumed = Pipeline(open_input(capture / "cap"), cfg, capture / "resumed", resume=True)
    assert len(resumed.records) == 3
    while resumed.step() is not None:
        pass
    resumed.finish()
    for name in ("trajectory.txt", "map.ply"):
        assert (capture / "full" / name).read_bytes() == (capture / "resumed" / name).read_bytes(), name


def test_resume_refuses_a_different_run(capture, capsys):
    out = capture / "run"
    assert splatam_main(["run", "--input", str(capture / "cap"), "--out", str(out),
                         "--config", str(capture / "tiny.yaml"), "--quiet"]) == 0
    code, err = run_cli(["run", "--input", str(capture / "cap"), "--out", str(out), "--resume",
                         "--config", str(capture / "tiny.yaml"), "--stride", "2", "--quiet"], capsys)
    assert code == 2 and "other frames" in err


@pytest.mark.parametrize("case", ["missing", "empty", "not_a_capture", "bad_image", "bad_intrinsics",
                                  "bad_config", "unknown_key"])
def test_bad_input_is_one_line_and_exit_2(capture, capsys, case):
    cap, cfg = capture / "cap", capture / "tiny.yaml"
    if case == "missing":
        cap = capture / "nope"
    elif case == "empty":
        cap = capture / "empty"
        cap.mkdir()
    elif case == "not_a_capture":
        cap = capture / "junk"
        cap.mkdir()
        (cap / "notes.txt").write_text("hello")
    elif case == "bad_image":                     # every image: one bad frame alone is skipped
        for image in sorted((cap / "rgb").iterdir()):
            image.write_bytes(b"not an image")
    elif case == "bad_intrinsics":
        text = (cap / "camera.yaml").read_text()
        lines = [("fx: -1.0" if line.strip().startswith("fx") else line) for line in text.splitlines()]
        (cap / "camera.yaml").write_text("\n".join(lines) + "\n")
    elif case == "bad_config":
        cfg.write_text("tracking: [unclosed")
    elif case == "unknown_key":
        cfg.write_text("base: cpu\ntracking: {iterationz: 3}\n")
    out = capture / "out"
    code, err = run_cli(["run", "--input", str(cap), "--out", str(out), "--config", str(cfg), "--quiet"], capsys)
    assert code == 2
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    assert not (out / "map.ply").exists() and not (out / "metrics.json").exists()


def test_bad_frames_are_skipped_with_a_warning_and_the_run_goes_on(capture, capsys):
    import cv2
    cap = capture / "cap"
    depths, images = sorted((cap / "depth").iterdir()), sorted((cap / "rgb").iterdir())
    for k in (3, 5):                              # a LiDAR dropout, a hand over the sensor
        cv2.imwrite(str(depths[k]), np.zeros_like(cv2.imread(str(depths[k]), cv2.IMREAD_UNCHANGED)))
    images[6].write_bytes(b"truncated")
    out = capture / "run"
    code, err = run_cli(["run", "--input", str(cap), "--out", str(out), "--config", str(capture / "tiny.yaml"),
                         "--quiet"], capsys)
    assert code == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("warning: skipped")]
    assert len(warnings) == 3 and "Traceback" not in err
    assert depths[3].name in warnings[0] and depths[5].name in warnings[1] and images[6].name in warnings[2]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 5 and metrics["frames_skipped"] == 3
    assert [s["source_index"] for s in metrics["skipped"]] == [3, 5, 6]
    stamps, _ = read_tum_trajectory(out / "trajectory.txt")
    assert len(stamps) == 5


def test_a_capture_whose_first_frames_are_all_bad_is_refused(capture, capsys):
    import cv2
    fixtures.write_tum(capture / "long", n=12)
    for depth in sorted((capture / "long" / "depth").iterdir())[:10]:
        cv2.imwrite(str(depth), np.zeros_like(cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)))
    out = capture / "out"
    code, err = run_cli(["run", "--input", str(capture / "long"), "--out", str(out),
                         "--config", str(capture / "tiny.yaml"), "--quiet"], capsys)
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert code == 2 and len(lines) == 1 and "first 10 frames are unusable" in lines[0], err
    assert not (out / "map.ply").exists()


@pytest.mark.parametrize("writer,name", [("write_replica", "rep"), ("write_scannet", "sn"),
                                         ("write_scannetpp", "snpp"), ("write_nerfcapture", "nc"),
                                         ("write_record3d", "cap.r3d"), ("write_strayscanner", "stray")])
def test_run_works_on_every_capture_format(tmp_path, capsys, writer, name):

    kwargs = {"as_zip": True} if writer == "write_record3d" else {}
    fixture = getattr(fixtures, writer)(tmp_path / name, n=3, **kwargs)
    (tmp_path / "tiny.yaml").write_text(TINY)
    out = tmp_path / "run"
    code, err = run_cli(["run", "--input", str(fixture.path), "--out", str(out),
                         "--config", str(tmp_path / "tiny.yaml"), "--quiet"], capsys)
    assert code == 0, err
    stamps, _ = read_tum_trajectory(out / "trajectory.txt")
    assert len(stamps) == len(open_input(fixture.path)) >= 2      # ScanNet++ skips its is_bad frame


def test_a_run_killed_before_its_first_checkpoint_starts_again(capture, capsys):
    # Killed at frame 1: the run folder holds only the keyframe file that keyframe 0 went into.
    out = capture / "run"
    (out / "checkpoint").mkdir(parents=True)
    (out / "checkpoint" / "keyframes.bin").write_bytes(b"\0" * 1000)
    args = ["run", "--input", str(capture / "cap"), "--out", str(out), "--config", str(capture / "tiny.yaml"),
            "--max-frames", "2", "--quiet"]
    code, err = run_cli(args + ["--resume"], capsys)
    assert code == 0 and "no checkpoint written yet; starting from the first frame" in err
    assert len(read_tum_trajectory(out / "trajectory.txt")[0]) == 2
    code, err = run_cli(args, capsys)         # finished now: the folder is taken
    assert code == 2 and "already holds a run" in err
    (out / "metrics.json").unlink()
    shutil.rmtree(out / "checkpoint")
    (out / "checkpoint").mkdir()
    (out / "checkpoint" / "keyframes.bin").write_bytes(b"\0" * 1000)
    code, err = run_cli(args, capsys)         # without --resume it starts again too
    assert code == 0, err
