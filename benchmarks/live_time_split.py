"""Where a run's wall time went, from its metrics.json (per_frame): frame 0's mapping (which frame 1
waits for in the live engine), the tracker's waits for the mapper (live.max_keyframe_lag), the last
frame (its wait and the final drain), tracking, and the rest (reading frames, the pipeline), with
the live mapper's busy seconds beside them; and the median frame split into tracking and the rest.

    python benchmarks/live_rate.py ... --work /tmp/lr          # keeps the run folders
    python benchmarks/live_time_split.py /tmp/lr/*

Seconds are totals over the run; `mapper` is metrics.json live.mapper_seconds (live engine only).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def split(run: Path) -> dict:
    m = json.loads((run / "metrics.json").read_text())
    pf = m["per_frame"]
    wall = np.array([r["wall_seconds"] for r in pf])
    track = np.array([r["tracking_seconds"] for r in pf])
    wait = np.array([r["mapping_seconds"] for r in pf])     # live engine: the tracker's wait for the map
    middle = slice(2, len(pf) - 1)
    live = m.get("live", {})
    return dict(run=run.name, frames=len(pf), total=wall.sum(), mean=wall.mean(),
                first=wall[0] + (wall[1] - track[1] if len(pf) > 1 else 0.0),
                waits=wait[middle].sum(), last=wall[-1], tracking=track[1:].sum(),
                rest=(wall[middle] - track[middle] - wait[middle]).sum(), mapper=live.get("mapper_seconds"),
                median=float(np.median(wall[1:])), median_tracking=float(np.median(track[1:])),
                median_rest=float(np.median((wall - track - wait)[1:-1])))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("runs", nargs="+", type=Path, help="run folders (each with its metrics.json)")
    args = p.parse_args()
    missing = [str(run) for run in args.runs if not (run / "metrics.json").is_file()]
    if missing:
        print(f"live_time_split: no metrics.json in {', '.join(missing)} (expected run folders)", file=sys.stderr)
        return 2
    print("| run | frames | total s | mean s/frame | frame 0 (+ frame 1's wait) | waits | last frame (wait + drain) | "
          "tracking | rest | mapper busy | median frame: wall / tracking / rest |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for run in args.runs:
        r = split(run)
        mapper = "–" if r["mapper"] is None else f"{r['mapper']:.1f}"
        print(f"| {r['run']} | {r['frames']} | {r['total']:.1f} | {r['mean']:.2f} | {r['first']:.1f} | {r['waits']:.1f} | "
              f"{r['last']:.1f} | {r['tracking']:.1f} | {r['rest']:.1f} | {mapper} | "
              f"{r['median']:.3f} / {r['median_tracking']:.3f} / {r['median_rest']:.3f} |")


if __name__ == "__main__":
    sys.exit(main())
