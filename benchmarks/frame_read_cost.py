"""Seconds to make one frame at the working resolution (320x240) in the pipeline's reader: the
synthetic scene is ray-cast per frame, a capture's images are decoded and resized. Median over the
first --frames frames, per sequence.

    python benchmarks/frame_read_cost.py
    python benchmarks/frame_read_cost.py --sequences synthetic,7scenes_redkitchen_300 --frames 20
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))


def main() -> None:
    from splat_core.io.detect import open_capture
    from splat_core.run.frame_feed import prepare_frame
    from splat_core.synthetic.source import SyntheticSource

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", default="synthetic,7scenes_redkitchen_300,sun3d_3dmatch_fragment1,sun3d_3dmatch_fragment2")
    p.add_argument("--frames", type=int, default=10)
    args = p.parse_args()
    print(f"# {machine_line()} · load average {os.getloadavg()[0]:.2f}")
    print("| sequence | ms per frame (median) |\n|---|---|")
    for name in args.sequences.split(","):
        source = SyntheticSource(n_frames=60) if name == "synthetic" else open_capture(DATA / name)
        working = source.intrinsics.scaled(320, 240)
        seconds = []
        for i in range(args.frames):
            start = time.perf_counter()
            prepare_frame(source, i, working, None)
            seconds.append(time.perf_counter() - start)
        print(f"| {name} | {1e3 * float(np.median(seconds)):.1f} |")
    print(f"# load average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
