"""Phone captures: map colour at the LiDAR depth grid, or above it with depth upsampled? Prints JSON.

    python benchmarks/phone_resolution.py --frames 20 --json
    python benchmarks/phone_resolution.py --sizes 256x192,320x240,512x384 --preset cpu

A synthetic phone-shaped capture (splat_core/synthetic/phone.py: colour 1024x768, depth 256x192,
4x smaller, exact poses) is mapped by the same Pipeline at each working size in turn, in one
process, sequential engine (--repeats R: R rounds, interleaved). For each size: ATE, the median wall seconds per frame (frame 0, the
long first mapping, left out) and the map's PSNR rendered at one common size (--eval-size, the
largest tested by default) against the capture's colour at that size, on frame 0 and every 5th
frame; so a map made at the depth grid is judged on the same pixels as one made above it.
`depth_upsampling` is set to let each size through (size / depth grid).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from benchmarks.common import machine  # noqa: E402
from splat_core import metrics as M  # noqa: E402
from splat_core.config import load_config  # noqa: E402
from splat_core.run import Pipeline  # noqa: E402
from splat_core.run.resolution import parse_resolution  # noqa: E402
from splat_core.synthetic import SyntheticPhoneCapture  # noqa: E402


def map_psnr(pipe: Pipeline, source, size) -> float:
    """Mean PSNR of the final map at the estimated poses, rendered at `size`, on the eval frames."""
    intr = source.intrinsics.scaled(*size)
    g = pipe.engine.slam.map.tensors(detach=True)
    values = []
    for k in range(len(pipe.records)):
        if k != 0 and (k + 1) % 5 != 0:
            continue
        gt = source.frame_at_size(int(pipe.records[k]["source_index"]), *size).color
        with torch.no_grad():
            out = pipe.engine.slam.renderer.render(g, intr, pipe.engine.slam.w2cs[k])
        values.append(float(M.psnr(out.color, torch.as_tensor(gt, device=out.color.device))))
    return statistics.fmean(values)


def run_size(source, preset: str, size, frames: int, eval_size) -> dict:
    dw = source.depth_size[0]
    config = load_config(preset, {"resolution": list(size), "depth_upsampling": max(1.0, size[0] / dw),
                                  "checkpoint_every": 0})
    pipe = Pipeline(source, config, None, max_frames=frames, engine="sequential")
    assert (pipe.intrinsics.width, pipe.intrinsics.height) == tuple(size), (pipe.intrinsics, size)
    start = time.perf_counter()
    while pipe.step() is not None:
        pass
    total = time.perf_counter() - start
    wall = [r["wall_seconds"] for r in pipe.records]
    return dict(size=f"{size[0]}x{size[1]}", upsampling=round(size[0] / dw, 3), frames=len(pipe.records),
                seconds_per_frame_median=statistics.median(wall[1:]), total_seconds=total,
                ate_cm=pipe.ate_cm(), psnr_at_eval_size=map_psnr(pipe, source, eval_size),
                psnr_at_working_size=pipe.evaluate()["psnr"], num_gaussians=len(pipe.engine.slam.map))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--preset", default="cpu")
    p.add_argument("--sizes", default="256x192,320x240,512x384", help="working sizes, the depth grid first")
    p.add_argument("--color", default="1024x768", help="the capture's colour size")
    p.add_argument("--depth", default="256x192", help="the capture's depth grid")
    p.add_argument("--eval-size", default=None, help="size the maps are compared at (default: the largest of --sizes)")
    p.add_argument("--noise", type=float, default=0.0, help="depth noise coefficient (std = noise * depth^2)")
    p.add_argument("--repeats", type=int, default=1, help="runs per size, interleaved; s/frame is their median")
    p.add_argument("--json", action="store_true", help="one JSON object (default: one JSON line per size, then it)")
    args = p.parse_args()
    sizes = [parse_resolution(s, "--sizes") for s in args.sizes.split(",")]
    eval_size = parse_resolution(args.eval_size, "--eval-size") if args.eval_size else max(sizes, key=lambda s: s[0])
    source = SyntheticPhoneCapture(args.frames, parse_resolution(args.color), parse_resolution(args.depth),
                                   noise=args.noise)
    for i in range(len(source)):      # render every frame once, before anything is timed
        source._render(i)
    runs = {tuple(s): [] for s in sizes}
    for _ in range(args.repeats):   # interleaved, so a busy moment of a shared machine hits every size
        for size in sizes:
            runs[tuple(size)].append(run_size(source, args.preset, size, args.frames, eval_size))
            if not args.json:
                print(json.dumps(runs[tuple(size)][-1]), flush=True)
    rows = []
    for size in sizes:
        row = dict(runs[tuple(size)][0])
        row["seconds_per_frame_median"] = statistics.median(r["seconds_per_frame_median"] for r in runs[tuple(size)])
        row["seconds_per_frame_runs"] = [r["seconds_per_frame_median"] for r in runs[tuple(size)]]
        rows.append(row)
    base = rows[0]
    for r in rows:
        r["cost_vs_first"] = r["seconds_per_frame_median"] / base["seconds_per_frame_median"]
        r["psnr_gain_db_vs_first"] = r["psnr_at_eval_size"] - base["psnr_at_eval_size"]
    print(json.dumps(dict(machine=machine(), torch_threads=torch.get_num_threads(), preset=args.preset,
                          frames=args.frames, repeats=args.repeats,
                          capture=source.describe(), eval_size=f"{eval_size[0]}x{eval_size[1]}",
                          noise=args.noise, runs=rows), indent=1 if args.json else None))


if __name__ == "__main__":
    main()
