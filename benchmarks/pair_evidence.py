"""What the captured depth says about a few frame pairs, under the run's poses and each reference's
(issue 44: who is off where a lens has its largest error).

    python benchmarks/pair_evidence.py --run RUN --sequence 7scenes_redkitchen_600 446-448 448-452 ...
                                       [--icp] [--json]

For each pair a-b and each trajectory (the run, groundtruth.txt, groundtruth_sfm.txt where present):
1. the median |dz| (mm) of frame a's depth reprojected into frame b with that trajectory's relative
   pose (io.checks.reprojection_dz, every 2nd pixel) and the share of points within 1 cm: lower is
   what the depth agrees with (its floor is the sensor's noise, ~6-7 mm on 7-Scenes);
2. with --icp (needs open3d): point-to-plane ICP of the two depth images (loop_pairs.py), started
   from the run's relative pose and from the first reference's, and its distance (cm, deg) to each
   trajectory's relative pose (the two starts agreeing says the ICP did not just stay where it began).
Over a few frames the SfM reference's ~8 % larger scale is a millimetre or less.
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

from common import DATA, machine_line  # noqa: E402
from three_lenses import REFERENCES, matched  # noqa: E402


def main(argv=None) -> int:
    from splat_core.io import open_capture
    from splat_core.io.checks import reprojection_dz
    from splat_core.io.trajectory import read_tum_trajectory

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True)
    p.add_argument("--sequence", default="7scenes_redkitchen_600")
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--icp", action="store_true")
    p.add_argument("--json", action="store_true")
    p.add_argument("pairs", nargs="+", help="a-b frame pairs")
    args = p.parse_args(argv)
    folder = args.data / args.sequence
    stamps, est = read_tum_trajectory(args.run / "trajectory.txt")
    traj = {"run": np.asarray(est)}
    for name, file in REFERENCES.items():
        if (folder / file).is_file():
            idx, ref = matched(stamps, folder / file)
            full = np.full((len(est), 4, 4), np.nan)
            full[idx] = ref
            traj[name] = full
    capture = open_capture(folder)
    out = {"machine": machine_line(), "sequence": args.sequence, "run": str(args.run), "pairs": []}
    for pair in args.pairs:
        a, b = (int(x) for x in pair.split("-"))
        rel = {n: np.linalg.inv(T[a]) @ T[b] for n, T in traj.items() if np.isfinite(T[[a, b]]).all()}
        row = {"pair": f"{a}-{b}"}
        for n, T in rel.items():
            dz = reprojection_dz(capture[a], capture[b], traj[n][a], traj[n][b], 2)
            row[f"dz_median_mm_{n}"] = round(1000 * float(np.median(dz)), 1)
            row[f"within_1cm_{n}"] = round(float(np.mean(dz < 0.01)), 2)
        if args.icp:
            from loop_pairs import cloud, icp

            from splat_core.loop.verify import pose_difference
            intr = capture.intrinsics
            target, source = cloud(capture[a].depth, intr, 0.01), cloud(capture[b].depth, intr, 0.01)
            for start in [n for n in rel if n != "sfm"][:2]:
                sensor, fitness, _ = icp(source, target, rel[start])
                for n, T in rel.items():
                    m, deg = pose_difference(sensor, T)
                    row[f"icp_from_{start}_vs_{n}"] = [round(100 * m, 2), round(deg, 2)]
                row[f"icp_from_{start}_fitness"] = round(fitness, 2)
        out["pairs"].append(row)
    print(json.dumps(out, indent=None if args.json else 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
