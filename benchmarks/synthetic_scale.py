"""Does tracking shrink the motion where the intrinsics are exact? (issue 44)

    python benchmarks/synthetic_scale.py [--frames 150] [--noise 0.0015] [--color-weight 0] [--piece 50]

Runs the `cpu` preset (sequential engine, loop closure off) on the synthetic room (exact poses,
exact intrinsics, depth noise std = noise * z^2 like a Kinect v1) and prints, whole and per piece
of --piece frames: the Sim(3) scale of the run onto the exact poses (above 1: the truth moved
further than the run), the ratio of path lengths (truth over run), SE(3) and Sim(3) ATE (cm).
--color-weight sets the alignment's colour weight (the polish's is half of it, as in `cpu`);
0 tracks by depth alone.
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

from common import machine_line  # noqa: E402


def piece_rows(est: np.ndarray, ref: np.ndarray, piece: int) -> list[dict]:
    from splat_core.metrics import align_similarity, ate_errors

    rows = []
    for a in range(0, len(est), piece):
        e, r = est[a:a + piece], ref[a:a + piece]
        if len(e) < 5:
            continue
        path = lambda x: float(np.linalg.norm(np.diff(x[:, :3, 3], axis=0), axis=1).sum())  # noqa: E731
        rows.append({"frames": f"{a}-{a + len(e) - 1}",
                     "scale": round(float(align_similarity(e[:, :3, 3], r[:, :3, 3])[0]), 4),
                     "path_ratio": round(path(r) / max(path(e), 1e-12), 4),
                     "se3_cm": round(100 * float(np.sqrt(np.mean(ate_errors(e, r) ** 2))), 3),
                     "sim3_cm": round(100 * float(np.sqrt(np.mean(ate_errors(e, r, scale=True) ** 2))), 3)})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--noise", type=float, default=0.0015)
    parser.add_argument("--color-weight", type=float, default=0.0)
    parser.add_argument("--piece", type=int, default=50)
    args = parser.parse_args(argv)

    from splat_core.config import load_config
    from splat_core.run.pipeline import Pipeline
    from splat_core.synthetic import SyntheticSource

    cw = args.color_weight
    config = load_config("cpu", {"tracking": {"color_weight": 0.5 * cw, "align": {"color_weight": cw}},
                                 "loop_closure": {"enabled": False}})
    pipe = Pipeline(SyntheticSource(n_frames=args.frames, noise=args.noise), config, None, device="cpu")
    started = time.perf_counter()
    while pipe.step() is not None:
        pass
    est, ref = np.asarray(pipe.estimated_c2w()), np.asarray(pipe.reference_c2w())
    print(json.dumps({"machine": machine_line(), "frames": args.frames, "noise": args.noise, "color_weight": cw,
                      "seconds": round(time.perf_counter() - started),
                      "whole": piece_rows(est, ref, len(est))[0], "pieces": piece_rows(est, ref, args.piece)},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
