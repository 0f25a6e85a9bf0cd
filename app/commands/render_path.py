"""`splatam render`: images of a map along a camera trajectory (TUM, c2w), or an MP4 video along a
smooth path through the run's keyframes (or a TUM file's poses), for figures and fly-throughs.

    splatam render RUN_DIR --trajectory FILE --out DIR           # one PNG per pose
    splatam render RUN_DIR --video OUT.mp4 [--path keyframes|FILE] [--fps N] [--size WxH] [--seconds S]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from splat_core.errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("map", metavar="RUN_DIR|MAP.ply", help="run folder (map.ply inside) or a 3DGS .ply")
    p.add_argument("--trajectory", default=None, help="TUM trajectory (t tx ty tz qx qy qz qw, camera-to-world): "
                   "render one image per pose into --out")
    p.add_argument("--out", default=None, help="folder for the images (000000.png, ...)")
    p.add_argument("--video", default=None, metavar="OUT.mp4", help="write an H.264 video along a smooth camera path")
    p.add_argument("--path", default="keyframes", metavar="keyframes|FILE",
                   help="video path through the run's keyframe poses (default) or a TUM file's poses")
    p.add_argument("--fps", type=float, default=30.0, help="video frames per second (default 30)")
    p.add_argument("--size", default=None, metavar="WxH", help="video size, even numbers (default: the run's)")
    p.add_argument("--seconds", type=float, default=None,
                   help="video length (default: the poses' time span, else 2 s between poses)")
    p.add_argument("--mode", choices=["color", "depth", "silhouette"], default="color")
    p.add_argument("--width", type=int, default=None, help="image width (default: the run's, else 640)")
    p.add_argument("--height", type=int, default=None, help="image height (default: the run's, else 480)")
    p.add_argument("--fx", type=float, default=None, help="focal length in pixels (default: the run's, else 60 deg hfov)")
    p.add_argument("--fy", type=float, default=None)
    p.add_argument("--cx", type=float, default=None)
    p.add_argument("--cy", type=float, default=None)
    p.add_argument("--depth-max", type=float, default=None, help="depth colouring range in metres (default: auto)")
    p.add_argument("--background", type=float, default=0.0, help="background grey level in [0, 1]")
    p.add_argument("--backend", default="auto", choices=["auto", "cpu", "cuda", "reference"])


def resolve_intrinsics(args, run: Path):
    """Flags override the run's recorded intrinsics; without either, 640x480 with a 60 deg hfov."""
    from splat_core.camera import Intrinsics
    from splat_core.run.run_folder import RunFolder

    base = RunFolder(run).intrinsics() if run.is_dir() else None
    width = args.width or (base.width if base else 640)
    height = args.height or (base.height if base else 480)
    if base and (width, height) != (base.width, base.height):
        base = base.scaled(width, height)
    fx = args.fx or (base.fx if base else 0.5 * width / np.tan(np.deg2rad(30.0)))
    fy = args.fy or (base.fy if base and not args.fx else fx)
    cx = args.cx if args.cx is not None else (base.cx if base else (width - 1) / 2.0)
    cy = args.cy if args.cy is not None else (base.cy if base else (height - 1) / 2.0)
    return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height))


def path_poses(run: Path, path: str) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps, c2w poses) the video path goes through: the run's keyframes or a TUM file's poses."""
    from splat_core.io.trajectory import read_tum_trajectory

    if path != "keyframes":
        stamps, c2ws = read_tum_trajectory(path)
        if len(c2ws) == 0:
            raise InputError(f"{path}: no poses")
        return stamps, c2ws
    from splat_core.camera import invert_pose
    from splat_core.run.run_folder import RunFolder

    folder = RunFolder(run)
    ckpt = folder.checkpoint_or_none() if run.is_dir() else None
    intrinsics = folder.intrinsics(ckpt) if ckpt is not None else None
    keyframes = folder.keyframes(ckpt, intrinsics) if intrinsics is not None else []
    if not keyframes:
        raise InputError(f"{run}: no keyframes (a run folder with checkpoint/ has them); "
                         f"pass --path TRAJECTORY.txt")
    frames = np.array([kf.frame_index for kf in keyframes])
    timestamps, _ = folder.read_trajectory()
    stamps = timestamps[frames] if frames.max() < len(timestamps) else np.zeros(0)
    return stamps, np.stack([invert_pose(kf.w2c) for kf in keyframes])


def video_length(stamps: np.ndarray, n_poses: int, seconds: float | None) -> float:
    """--seconds, else the poses' time span (a real-time fly-through), else 2 s between poses."""
    if seconds is not None:
        if seconds <= 0:
            raise InputError(f"--seconds {seconds}: expected a positive length")
        return float(seconds)
    span = float(stamps[-1] - stamps[0]) if len(stamps) == n_poses and n_poses > 1 else 0.0
    return span if span > 0 else 2.0 * max(n_poses - 1, 1)


def main(args) -> int:
    if args.video is None and (args.trajectory is None or args.out is None):
        raise InputError("render: pass --trajectory FILE --out DIR for images, or --video OUT.mp4")
    run = Path(args.map)
    if args.video is not None:
        return render_video(args, run)
    return render_images(args, run)


def _device(backend: str) -> str:
    import torch
    return "cuda" if backend in ("auto", "cuda") and torch.cuda.is_available() else "cpu"


def render_images(args, run: Path) -> int:
    import cv2

    from app.browse import near_plane_of
    from app.video import render_frames
    from splat_core.io.map_files import map_path_of, read_map_file
    from splat_core.io.trajectory import read_tum_trajectory

    arrays = read_map_file(map_path_of(run))
    _, c2ws = read_tum_trajectory(args.trajectory)
    if len(c2ws) == 0:
        raise InputError(f"{args.trajectory}: no poses")
    intr = resolve_intrinsics(args, run)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: expected a folder")
    out.mkdir(parents=True, exist_ok=True)
    frames = render_frames(arrays, intr, c2ws, mode=args.mode, near=near_plane_of(run), backend=args.backend,
                           background=args.background, depth_max=args.depth_max, device=_device(args.backend))
    for i, img in enumerate(frames):
        path = out / f"{i:06d}.png"
        if not cv2.imwrite(str(path), img[..., ::-1]):
            raise InputError(f"{path}: could not write the image")
    print(f"rendered {len(c2ws)} {args.mode} images of {intr.width}x{intr.height} into {out}")
    return 0


def render_video(args, run: Path) -> int:
    import time

    from app.browse import near_plane_of
    from app.video import mp4_path, parse_size, render_frames, write_mp4
    from splat_core.camera_path import CameraPath
    from splat_core.io.map_files import map_path_of, read_map_file

    out = mp4_path(args.video)
    if args.fps <= 0:
        raise InputError(f"--fps {args.fps}: expected a positive rate")
    if args.size is not None:
        args.width, args.height = parse_size(args.size)
    intr = resolve_intrinsics(args, run)
    if intr.width % 2 or intr.height % 2:   # H.264 needs even sizes: drop the last row / column
        args.width, args.height = intr.width - intr.width % 2, intr.height - intr.height % 2
        intr = resolve_intrinsics(args, run)
    arrays = read_map_file(map_path_of(run))
    stamps, poses = path_poses(run, args.path)
    n = max(1, int(round(video_length(stamps, len(poses), args.seconds) * args.fps)))
    c2ws = CameraPath(poses).sample(n)
    frames = render_frames(arrays, intr, c2ws, mode=args.mode, near=near_plane_of(run), backend=args.backend,
                           background=args.background, depth_max=args.depth_max, device=_device(args.backend))
    start = time.perf_counter()
    count = write_mp4(out, frames, fps=args.fps, size=(intr.width, intr.height), total=n, progress=True)
    seconds = time.perf_counter() - start
    print(f"wrote {count} {args.mode} frames of {intr.width}x{intr.height} at {args.fps:g} fps through "
          f"{len(poses)} poses to {out} ({seconds:.1f} s, {count / seconds:.1f} frames/s)")
    return 0
