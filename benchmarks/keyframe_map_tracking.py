"""Does tracking fail because of the map the live preset's mapper keeps? (issue 42: the corridor)

    python benchmarks/keyframe_map_tracking.py [--map keyframes|between] [--start 225] [--end 256] [--json]

The synthetic corridor (splat_core/synthetic/corridor.py) is mapped at its reference poses as the
live engine's keyframe mapper maps it (`live` preset's mapping: keyframes only, 20 iterations each),
with `--map between` also densifying every frame between keyframes (live.densify_between), the
map published after each step. From --start on, each frame is tracked against the newest published
map from the constant-velocity prediction of the reference poses (so the history is perfect and
nothing feeds back) by several trackers: the `live` preset's, the `cpu` preset's and one without
the Gauss-Newton alignment (the Adam polish alone, from the prediction). Printed per frame: each
tracker's camera-centre error (cm) and the start its polish kept (a: aligned, p: prediction); then
median and max per tracker over the frames. A tracker that leaves a perfect prediction by more than
the prediction's own error is pulled by the map. Deterministic (the sequential engine's parts).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from splat_core.camera import invert_pose, predict_constant_velocity  # noqa: E402
from splat_core.config import load_config  # noqa: E402
from splat_core.run import Pipeline  # noqa: E402
from splat_core.synthetic import CorridorSource  # noqa: E402
from splat_core.tracking import Tracker  # noqa: E402


def trackers(slam) -> dict:
    live, cpu = load_config("live").tracking, load_config("cpu").tracking
    configs = {"live": live, "cpu": cpu,
               "no_align": dataclasses.replace(cpu, align=dataclasses.replace(cpu.align, iterations=0))}
    return {name: Tracker(c, slam.intrinsics, slam.renderer, seed=0, device=slam.device, dtype=slam.dtype)
            for name, c in configs.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--map", default="keyframes", choices=["keyframes", "between"])
    p.add_argument("--start", type=int, default=225)
    p.add_argument("--end", type=int, default=256)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    source = CorridorSource(n_frames=args.end, width=320, height=240)
    pipe = Pipeline(source, load_config("live", overrides={"eval_every": 10**9}), None, engine="sequential")
    slam = pipe.engine.slam
    tracking = trackers(slam)
    c2w = np.asarray(source.c2w)
    w2c = [invert_pose(c) for c in c2w]
    rows = []
    for t in range(args.end):
        frame = pipe.frame_at(t)
        if t >= args.start:
            version = slam.latest_version()
            predicted = predict_constant_velocity(w2c[t - 1], w2c[t - 2], 1.0)
            row = dict(frame=t, map_frame=version.frame_index)
            for name, tracker in tracking.items():
                r = tracker.track(version.gaussians, frame.color, frame.depth, predicted, reuse=True)
                row[name] = [round(100 * float(np.linalg.norm(invert_pose(r.w2c)[:3, 3] - c2w[t][:3, 3])), 2),
                             r.start[0]]
            rows.append(row)
            if not args.json:
                print(t, version.frame_index, "  ".join(f"{k} {v[0]:.2f}{v[1]}" for k, v in row.items()
                                                        if isinstance(v, list)), flush=True)
        slam.track(frame, slam.map.tensors(detach=True), w2c[t])     # the reference pose
        if t == 0 or slam.is_keyframe(t):
            slam.map_frame(frame, w2c[t], t)
            slam.publish(t)
        elif args.map == "between":
            slam.map_frame(frame, w2c[t], t, optimise=False)
            slam.publish(t)
    summary = {name: dict(median_cm=statistics.median(r[name][0] for r in rows),
                          max_cm=max(r[name][0] for r in rows),
                          aligned_kept=sum(r[name][1] == "a" for r in rows)) for name in tracking}
    out = dict(map=args.map, frames=[args.start, args.end], summary=summary)
    print(json.dumps(dict(out, rows=rows) if args.json else out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
