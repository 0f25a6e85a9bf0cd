"""Camera-path video speed: frames per second of rendering a run's map along the smooth path
through its keyframes, and of rendering + H.264 encoding (what `splatam render --video` does).

    python benchmarks/video.py RUN_DIR [--size 640x480] [--frames 30] [--repeats 3] [--backend cpu]

RUN_DIR is a finished `splatam run` folder (map.ply + checkpoint/ for the keyframes). Each
repeat renders --frames poses spread over the whole path (so the views are the video's own) and
then encodes them; one warm-up frame first (Numba's cache / JIT). Figures are medians over the
repeats; the per-repeat values are listed too. Prints JSON.
"""

from __future__ import annotations

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from common import machine  # noqa: E402


def main(argv=None) -> int:
    from app.browse import load_run, near_plane_of
    from app.video import parse_size, render_frames, write_mp4
    from splat_core.camera_path import CameraPath

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("--size", default="640x480")
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--backend", default="cpu")
    args = p.parse_args(argv)

    run = Path(args.run)
    snap = load_run(run)
    if len(snap.keyframes) < 2:
        raise SystemExit(f"{run}: needs a run folder with at least two keyframes (checkpoint/)")
    width, height = parse_size(args.size)
    intr = snap.intrinsics.scaled(width, height)
    c2ws = CameraPath(np.stack([kf.c2w for kf in snap.keyframes])).sample(args.frames)
    near = near_plane_of(run)
    list(render_frames(snap.gaussians, intr, c2ws[:1], near=near, backend=args.backend))   # warm-up

    render_fps, total_fps = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            frames = list(render_frames(snap.gaussians, intr, c2ws, near=near, backend=args.backend))
            t1 = time.perf_counter()
            write_mp4(Path(tmp) / "v.mp4", iter(frames), fps=30, size=(width, height))
            t2 = time.perf_counter()
            render_fps.append(len(frames) / (t1 - t0))
            total_fps.append(len(frames) / (t2 - t0))
        video_bytes = (Path(tmp) / "v.mp4").stat().st_size
    result = {
        "run": str(run), "gaussians": snap.num_gaussians, "keyframes": len(snap.keyframes),
        "width": width, "height": height, "frames": args.frames, "repeats": args.repeats,
        "backend": args.backend,
        "render_fps": round(statistics.median(render_fps), 2),
        "render_and_encode_fps": round(statistics.median(total_fps), 2),
        "render_fps_all": [round(x, 2) for x in render_fps],
        "render_and_encode_fps_all": [round(x, 2) for x in total_fps],
        "mp4_bytes": video_bytes,
        "machine": machine(),
    }
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
