"""Is "no worse on both references" possible? (issue 44): a run's positions blended towards the
KinectFusion reference, each blend judged against both references.

    python benchmarks/reference_blend.py --run RUN [--sequence 7scenes_redkitchen_300] [--steps 10]

x(l) = (1 - l) run + l KF, positions only, KF aligned onto the run per piece of its split (rigid),
l = 0 .. 1. Prints, per l, the split ATE against groundtruth.txt and the whole SE(3) / Sim(3) ATE
against groundtruth_sfm.txt (cm). A construction that uses the reference, not a method: it shows
where the trade-off between the two references lies, and that rigid ATE obeys the triangle
inequality (ATE_a(x) + ATE_b(x) >= ATE(a, b)).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import DATA  # noqa: E402
from three_lenses import ate_cm, matched  # noqa: E402


def main(argv=None) -> int:
    from splat_core.io import open_capture
    from splat_core.io.checks import reference_breaks
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.metrics import align_rigid

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True)
    p.add_argument("--sequence", default="7scenes_redkitchen_300")
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--steps", type=int, default=10)
    args = p.parse_args(argv)
    folder = args.data / args.sequence
    stamps, est = read_tum_trajectory(args.run / "trajectory.txt")
    est = np.asarray(est)
    _, kf = matched(stamps, folder / "groundtruth.txt")
    _, sfm = matched(stamps, folder / "groundtruth_sfm.txt")
    cuts = [b + 1 for b in reference_breaks(open_capture(folder)) if b + 1 < len(kf)]
    kf_on = kf.copy()
    for a, b in zip([0, *cuts], [*cuts, len(kf)]):
        R, t = align_rigid(kf[a:b, :3, 3], est[a:b, :3, 3])
        kf_on[a:b, :3, 3] = kf[a:b, :3, 3] @ R.T + t
    rows = []
    for lam in np.linspace(0, 1, args.steps + 1):
        x = est.copy()
        x[:, :3, 3] = (1 - lam) * est[:, :3, 3] + lam * kf_on[:, :3, 3]
        rows.append({"l": round(float(lam), 2), "kinectfusion_split_cm": ate_cm(x, kf, cuts=cuts),
                     "sfm_se3_cm": ate_cm(x, sfm), "sfm_sim3_cm": ate_cm(x, sfm, True)})
    print(json.dumps({"sequence": args.sequence, "run": str(args.run), "cuts": cuts, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
