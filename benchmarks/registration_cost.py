"""The cost per frame of registering colour at load (issue 44, target 3): two configurations stepped
frame by frame in one process, so that both see the same machine load.

    python benchmarks/registration_cost.py [--sequence 7scenes_redkitchen_300] [--frames 100]
                                           [--config cpu] [--json]

"registered": the preset as it is (`estimate_registration: true`: a capture whose camera file says
colour and depth are not registered gets the colour camera estimated from its own edges, every
frame registered when read, and colour used in tracking). "as stored": the old behaviour,
`estimate_registration: false` (colour left where it is, tracking on depth alone). Each frame is
processed by one pipeline and then by the other (the order alternating from frame to frame), each
step timed on its own; the median over frames 1.. (frame 0 maps 100 iterations) and the mean,
and the set-up time (the estimate) apart.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

from common import DATA, machine_line  # noqa: E402

SIDES = {"registered": {}, "as stored": {"estimate_registration": False}}


def main(argv=None) -> int:
    from splat_core.config import load_config
    from splat_core.io import open_capture
    from splat_core.io.detect import detect_format
    from splat_core.run.pipeline import Pipeline

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sequence", default="7scenes_redkitchen_300")
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--config", default="cpu")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    folder = args.data / args.sequence
    if not folder.is_dir():
        print(f"registration_cost: {folder} not found", file=sys.stderr)
        return 2
    pipes, setup = {}, {}
    for name, overrides in SIDES.items():
        source = open_capture(folder)
        config = load_config(args.config, overrides, format=detect_format(folder))
        begun = time.perf_counter()
        pipes[name] = Pipeline(source, config, None, device="cpu", max_frames=args.frames)
        setup[name] = time.perf_counter() - begun
    seconds = {name: [] for name in pipes}
    for k in range(args.frames):
        order = list(pipes) if k % 2 == 0 else list(pipes)[::-1]
        for name in order:
            begun = time.perf_counter()
            if pipes[name].step() is None:
                break
            seconds[name].append(time.perf_counter() - begun)
        if (k + 1) % 10 == 0:
            print(f"registration_cost: {k + 1} frames", file=sys.stderr, flush=True)
    out = {"machine": machine_line(), "sequence": args.sequence, "config": args.config, "sides": {}}
    for name, s in seconds.items():
        s = np.asarray(s)
        out["sides"][name] = {"frames": int(len(s)), "setup_s": round(setup[name], 2),
                              "median_s_per_frame": round(float(np.median(s[1:])), 3),
                              "mean_s_per_frame": round(float(np.mean(s)), 3),
                              "ate_cm": round(float(pipes[name].ate_cm() or float("nan")), 2),
                              "notes": pipes[name].notes}
    a, b = out["sides"]["registered"], out["sides"]["as stored"]
    out["median_ratio"] = round(a["median_s_per_frame"] / b["median_s_per_frame"], 3)
    out["mean_ratio"] = round(a["mean_s_per_frame"] / b["mean_s_per_frame"], 3)
    print(json.dumps(out, indent=None if args.json else 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
