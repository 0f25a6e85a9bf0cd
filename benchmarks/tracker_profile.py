"""Where the time of one frame goes: the tracker's parts (map culling, the alignment's render and its
Gauss-Newton solve, the Adam polish's renders and backward passes, lost-tracking checks) and the
mapper's (densify, window, optimise, publish), timed by wrapping those functions in one run.

    python benchmarks/tracker_profile.py --input ../shared/data/7scenes_redkitchen_300 --max-frames 60
    python benchmarks/tracker_profile.py --input synthetic --config live --engine live

Prints per part: calls, calls per frame, median and total seconds, and ms per frame (total / frames
after frame 0). Parts nest (the tracker's total includes its parts); times are inclusive and per
thread (in the live engine the mapper's run beside the tracker's). Frame 0 (no tracking, the long
first mapping) is left out of the figures.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))

TIMES: dict = defaultdict(list)
STATE = {"frame": 0}
LOCK = threading.Lock()


def timed(owner, name: str, label: str) -> None:
    original = getattr(owner, name)

    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            if STATE["frame"] > 0:
                who = "mapper" if threading.current_thread().name == "slam-mapper" else "main"
                with LOCK:
                    TIMES[(who, label)].append(time.perf_counter() - start)
    setattr(owner, name, wrapper)


def instrument() -> None:
    import torch

    from splat_core import mapping, slam, tracking
    from splat_core.align import numba_backend
    from splat_core.relocalise import LostTracking
    from splat_core.render import Renderer

    timed(slam.SplaTAM, "track", "track (all)")
    timed(tracking.Tracker, "track", "  tracker.track")
    timed(tracking.Tracker, "nearby", "    nearby (cull)")
    timed(tracking.Tracker, "observe", "    observe (pixels)")
    timed(tracking.Tracker, "align", "    align (all)")
    timed(numba_backend, "render", "      align: dense render")
    timed(numba_backend, "_gauss_newton_step", "      align: GN step")
    timed(tracking, "candidate", "    candidate (prediction loss)")
    timed(tracking, "polish", "    polish (Adam, all)")
    timed(tracking.Observation, "render", "      polish: render")
    timed(tracking, "tracking_loss", "      polish: loss")
    timed(torch.Tensor, "backward", "      backward (any)")
    timed(LostTracking, "check", "  lost-tracking check")
    timed(slam.SplaTAM, "map_frame", "map_frame (all)")
    timed(slam.SplaTAM, "densify", "  densify")
    timed(slam.SplaTAM, "select_window", "  select_window")
    timed(slam.SplaTAM, "prune", "  prune")
    timed(slam.SplaTAM, "optimise", "  optimise")
    timed(mapping, "mapping_loss", "    mapping: loss")
    timed(Renderer, "render", "    renderer.render (any)")
    timed(slam.SplaTAM, "publish", "publish (copy)")
    timed(slam.SplaTAM, "close_loops", "close_loops")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--input", default="synthetic")
    p.add_argument("--config", default="cpu")
    p.add_argument("--engine", default="sequential")
    p.add_argument("--max-frames", type=int, default=60)
    args = p.parse_args()
    instrument()
    from splat_core.run import pipeline as pipeline_module

    original = pipeline_module.Pipeline.step if hasattr(pipeline_module.Pipeline, "step") else None
    frames: list[float] = []
    if original is not None:
        @functools.wraps(original)
        def step(self, *a, **k):
            start = time.perf_counter()
            out = original(self, *a, **k)
            if STATE["frame"] > 0:
                frames.append(time.perf_counter() - start)
            STATE["frame"] += 1
            return out
        pipeline_module.Pipeline.step = step
    from app.cli import splatam_main

    out = tempfile.mkdtemp(prefix="tracker_profile_")
    argv = ["run", "--input", args.input, "--out", out, "--config", args.config, "--engine", args.engine,
            "--device", "cpu", "--quiet", "--max-frames", str(args.max_frames)]
    load = os.getloadavg()
    start = time.perf_counter()
    splatam_main(argv)
    wall = time.perf_counter() - start
    n = max(1, STATE["frame"] - 1)
    print(f"# {args.input} · {args.config} · {args.engine} · {args.max_frames} frames · {machine_line()} · "
          f"load {load[0]:.2f} · wall {wall:.1f} s")
    if frames:
        print(f"# pipeline step per frame (after frame 0): median {np.median(frames) * 1e3:.0f} ms, "
              f"mean {np.mean(frames) * 1e3:.0f} ms")
    print("| thread | part | calls/frame | median ms | ms/frame |")
    print("|---|---|---|---|---|")
    for (who, label), values in TIMES.items():
        print(f"| {who} | {label} | {len(values) / n:.2f} | {np.median(values) * 1e3:.1f} | "
              f"{np.sum(values) / n * 1e3:.1f} |")


if __name__ == "__main__":
    main()
