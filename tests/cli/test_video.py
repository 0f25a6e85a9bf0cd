"""`splatam render --video`: an MP4 along a smooth path through a run's keyframes or a TUM
file's poses; the frames decode back at the requested count and size, and show our render."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from app.video import write_mp4
from splat_core.errors import InputError
from splat_core.io.trajectory import read_tum_trajectory, write_tum_trajectory
from splat_core.metrics import psnr

from helpers.runs import make_run, run_cli

ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg not installed (pip install '.[video]')")

from app.video import read_mp4  # noqa: E402

TINY = """base: cpu
resolution: [64, 48]
tracking: {iterations: 4}
mapping: {iterations: 2, first_frame_iterations: 4, window_size: 3}
lost_tracking: {max_speed: 10.0}
"""
# The fixture camera moves about 17 cm per frame at 30 frames/s (5 m/s): faster than the default
# hand-held limit (3 m/s), so lost-tracking held every pose at the first one and the run kept a
# single keyframe (a video from one pose). The limit is raised for this synthetic capture only.


@pytest.fixture(scope="module")
def slam_run(tmp_path_factory):
    """A real (tiny) SLAM run with a checkpoint, so it has keyframes."""
    from helpers import captures as fixtures
    from app.cli import splatam_main

    root = tmp_path_factory.mktemp("video")
    fixtures.write_tum(root / "cap", n=6)
    (root / "tiny.yaml").write_text(TINY)
    assert splatam_main(["run", "--input", str(root / "cap"), "--out", str(root / "run"),
                         "--config", str(root / "tiny.yaml"), "--quiet"]) == 0
    return root / "run"


@pytest.mark.slow
def test_video_through_the_keyframes_has_the_requested_frames_and_size(slam_run, tmp_path):
    from app.browse import load_run, near_plane_of
    from app.video import render_frames

    out = tmp_path / "fly.mp4"
    r = run_cli("render", str(slam_run), "--video", str(out), "--size", "48x36", "--fps", "10",
                "--seconds", "1.3", "--backend", "cpu")
    assert r.returncode == 0, r.stderr
    frames, size, fps = read_mp4(out)
    assert len(frames) == 13 and size == (48, 36) and fps == 10.0
    assert all(f.shape == (36, 48, 3) for f in frames)
    # the first frame is our render from the first keyframe's pose (H.264 with 4:2:0 chroma at
    # 48x36 costs a few dB); the last one, from the last keyframe, differs
    snap = load_run(slam_run)
    intr = snap.intrinsics.scaled(48, 36)
    first = next(render_frames(snap.gaussians, intr, [snap.keyframes[0].c2w], near=near_plane_of(slam_run),
                               backend="cpu"))
    assert psnr(frames[0] / 255.0, first / 255.0) > 25.0
    assert psnr(frames[-1] / 255.0, first / 255.0) < psnr(frames[0] / 255.0, first / 255.0) - 3.0


def test_video_along_a_tum_file_lasts_its_time_span(tmp_path):
    run = make_run(tmp_path)           # poses at t = 0, 0.1, 0.2 s
    out = tmp_path / "v.mp4"
    r = run_cli("render", str(run), "--video", str(out), "--path", str(run / "trajectory.txt"),
                "--size", "32x24", "--fps", "40", "--backend", "cpu")
    assert r.returncode == 0, r.stderr
    frames, size, fps = read_mp4(out)
    assert len(frames) == 8 and size == (32, 24) and fps == 40.0     # 0.2 s at 40 fps
    assert frames[0][12, 16, 0] > 150 and frames[0][12, 16, 2] < 100    # the red patch, head-on
    assert not list(tmp_path.glob(".v.mp4.*"))                          # no temporary left behind


def test_video_bad_input_is_one_line(tmp_path):
    run = make_run(tmp_path)
    traj = str(run / "trajectory.txt")
    cases = [
        (["--video", str(tmp_path / "v.mp4"), "--path", traj, "--size", "33x24"], "even"),
        (["--video", str(tmp_path / "v.avi"), "--path", traj], ".mp4"),
        (["--video", str(tmp_path / "v.mp4"), "--path", traj, "--size", "big"], "WIDTHxHEIGHT"),
        (["--video", str(tmp_path / "v.mp4")], "no keyframes"),               # map.ply + trajectory only
        (["--video", str(tmp_path / "v.mp4"), "--path", str(tmp_path / "none.txt")], "none.txt"),
        ([], "--video"),
    ]
    for args, message in cases:
        r = run_cli("render", str(run), *args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "v.mp4").exists()


def test_a_failed_render_keeps_the_previous_video(tmp_path):
    out = tmp_path / "v.mp4"
    good = [np.full((16, 16, 3), 200, np.uint8)] * 3
    assert write_mp4(out, iter(good), fps=5, size=(16, 16)) == 3
    before = out.read_bytes()

    def failing():
        yield good[0]
        raise RuntimeError("renderer crashed")
    with pytest.raises(RuntimeError):
        write_mp4(out, failing(), fps=5, size=(16, 16))
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    assert len(read_mp4(out)[0]) == 3


def test_missing_encoder_says_how_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)   # import fails as if not installed
    with pytest.raises(InputError, match=r"pip install .*video"):
        write_mp4(tmp_path / "v.mp4", iter([np.zeros((8, 8, 3), np.uint8)]), fps=5, size=(8, 8))
    assert not (tmp_path / "v.mp4").exists()


def test_path_poses_of_a_tum_file_are_its_poses(tmp_path):
    from app.commands.render_path import path_poses, video_length

    c2w = np.stack([np.eye(4)] * 4)
    c2w[:, 2, 3] = [0.0, 0.1, 0.3, 0.6]
    write_tum_trajectory(tmp_path / "t.txt", [1.0, 1.5, 2.0, 3.0], c2w)
    stamps, poses = path_poses(tmp_path, str(tmp_path / "t.txt"))
    assert np.allclose(poses, read_tum_trajectory(tmp_path / "t.txt")[1]) and np.allclose(poses, c2w)
    assert video_length(stamps, 4, None) == 2.0 and video_length(stamps, 4, 5.0) == 5.0
    assert video_length(np.zeros(0), 4, None) == 6.0            # no time stamps: 2 s between poses
