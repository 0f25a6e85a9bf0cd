"""Which poses do a revisit's own depth images agree with: the reference's or the run's? (issue 28, item 5)

    python benchmarks/loop_pairs.py --run RUN [--sequence 7scenes_redkitchen_600]
                                    [--pairs 254:469,249:484 | --revisits 24] [--open3d-poses P.npy] [--json]

For each pair of frames (a, b) (default: the loops in RUN's metrics.json, accepted or not; with
--revisits N: N pairs at least --gap frames apart that the *reference* puts within 30 cm and 20
degrees of each other, spread evenly over those found, so the run does not choose them), the two
frames' captured depth images alone, no map, are registered by Open3D's point-to-plane ICP (full
resolution, 1 cm voxels, correspondences 4 -> 2 -> 1 cm), started once from the reference's
relative pose c2w_a^-1 c2w_b and once from the run's. Where both starts converge to the same pose
(`converged_apart_cm` small), that pose is what the sensor says, independent of any tracker, and
the table gives its distance to the reference's relative pose and to the run's (and to Open3D
t.slam's with --open3d-poses, from `benchmarks/error_profile.py --save-open3d`). A loop whose
depth registration sits on the run's side and far from the reference's says the reference, not
the run, is off there: ATE against that reference then measures agreement with its own errors.
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


def cloud(depth, intr, voxel: float):
    """Open3D point cloud of a depth image (metres; 0 invalid) back-projected at `intr`, with normals."""
    import open3d as o3d

    from splat_core.camera import backproject

    d = np.asarray(depth)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(backproject(d, intr)[d > 0])).voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * voxel, max_nn=30))
    return pc


def icp(source, target, start: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(T with target ~ T source, fitness, inlier RMSE at 1 cm) from `start`, coarse to fine."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    T = start
    for distance in (0.04, 0.02, 0.01):
        result = reg.registration_icp(source, target, distance, T, reg.TransformationEstimationPointToPlane(),
                                      reg.ICPConvergenceCriteria(max_iteration=50))
        T = result.transformation
    return np.asarray(T), float(result.fitness), float(result.inlier_rmse)


def revisits(ref: np.ndarray, gap: int, count: int) -> list[tuple[int, int]]:
    """`count` pairs (a, b), b - a >= gap, whose reference poses are within 30 cm and 20 degrees,
    evenly spaced over all such pairs ordered by b (each b once, its nearest a)."""
    from splat_core.loop.verify import pose_difference

    found = []
    for b in range(gap, len(ref)):
        near = [(pose_difference(ref[a], ref[b]), a) for a in range(0, b - gap + 1)]
        near = [(cm, a) for (cm, deg), a in near if cm < 0.3 and deg < 20]
        if near:
            found.append((min(near)[1], b))
    if len(found) <= count:
        return found
    return [found[int(i)] for i in np.linspace(0, len(found) - 1, count).round()]


def main(argv=None) -> int:
    from splat_core.io import open_capture
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.loop.verify import pose_difference

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", type=Path, required=True)
    p.add_argument("--sequence", default="7scenes_redkitchen_600")
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--pairs", default=None, help="a:b,... (default: the run's loops)")
    p.add_argument("--revisits", type=int, default=0)
    p.add_argument("--gap", type=int, default=100)
    p.add_argument("--open3d-poses", type=Path, default=None)
    p.add_argument("--voxel", type=float, default=0.01)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)

    capture = open_capture(args.data / args.sequence)
    ref = np.asarray(capture.reference_c2w())
    poses = {"run": np.asarray(read_tum_trajectory(args.run / "trajectory.txt")[1])}
    if args.open3d_poses:
        poses["open3d"] = np.load(args.open3d_poses)
    if args.revisits:
        pairs = revisits(ref, args.gap, args.revisits)
    elif args.pairs:
        pairs = [tuple(int(x) for x in s.split(":")) for s in args.pairs.split(",")]
    else:
        loops = json.loads((args.run / "metrics.json").read_text()).get("loops", [])
        pairs = [tuple(loop["frames"]) for loop in loops]
    if not pairs:
        print(f"loop_pairs: no pairs in {args.sequence} (no loops in the run, or no revisits {args.gap} frames apart)",
              file=sys.stderr)
        return 1
    intr = capture.intrinsics
    rows = []
    for a, b in pairs:
        target, source = cloud(capture[a].depth, intr, args.voxel), cloud(capture[b].depth, intr, args.voxel)
        rel = {"reference": np.linalg.inv(ref[a]) @ ref[b]}
        rel.update({name: np.linalg.inv(P[a]) @ P[b] for name, P in poses.items()})
        from_ref, fitness, rmse = icp(source, target, rel["reference"])
        from_run, _, _ = icp(source, target, rel["run"])
        row = dict(frames=[a, b], fitness=round(fitness, 3), inlier_rmse_mm=round(1000 * rmse, 2),
                   converged_apart_cm=round(100 * pose_difference(from_ref, from_run)[0], 2),
                   reference_vs_run_cm=round(100 * pose_difference(rel["reference"], rel["run"])[0], 2))
        for name, T in rel.items():
            cm, deg = pose_difference(from_ref, T)
            row[f"depth_icp_vs_{name}_cm"], row[f"depth_icp_vs_{name}_deg"] = round(100 * cm, 2), round(deg, 2)
        rows.append(row)
        if not args.json:
            print(row, flush=True)
    summary = {"machine": machine_line(), "sequence": args.sequence, "run": str(args.run), "pairs": rows}
    agreed = [r for r in rows if r["converged_apart_cm"] < 0.5]
    for name in ("reference", *poses):
        summary[f"median_depth_icp_vs_{name}_cm"] = (
            round(float(np.median([r[f"depth_icp_vs_{name}_cm"] for r in agreed])), 2) if agreed else None)
    print(json.dumps(summary, indent=1) if args.json else {k: v for k, v in summary.items() if k != "pairs"})
    return 0


if __name__ == "__main__":
    sys.exit(main())
