"""What the depth images alone say about the camera's motion, under a choice of depth focal length
(issue 44: does depth-only tracking shrink the motion, or do the depth images at these intrinsics?).

    python benchmarks/depth_focal_pairs.py --sequence 7scenes_redkitchen_600 [--run RUN]
        [--focals 585/585,560/585] [--step 15] [--every 15] [--frames 0-600] [--max-depth 3.5]

For frame pairs (a, a + --step), one every --every frames within --frames, the two captured depth
images are registered by point-to-plane ICP (Open3D, 1 cm voxels, coarse to fine from the run's
relative pose, or the identity without --run), no map and none of our tracking code, with the
depth back-projected at each focal length fx/fy of --focals (principal point from the camera file).
Each ICP translation (camera a's axes) is compared with every trajectory's relative translation
over the same pair: each reference of the sequence (7-Scenes: KinectFusion `groundtruth.txt`, SfM
`groundtruth_sfm.txt`) and the run's:

    rms_cm         RMS of (trajectory - ICP) relative translations
    slope_x/y/z    least-squares factor s in trajectory = s * ICP, per camera axis (above 1: the
                   trajectory moved further along that axis than the depth at this focal says)

The depth is judged against two independent references: at the focal length the depth is
really taken with, the ICP's motion should match both as well as they match each other.
Needs open3d (the bench extra).
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

REFERENCES = {"kinectfusion": "groundtruth.txt", "sfm": "groundtruth_sfm.txt"}


def icp_relative(depth_a: np.ndarray, depth_b: np.ndarray, intr, start: np.ndarray) -> np.ndarray:
    """The 4x4 pose of camera b in camera a's axes (inv(c2w_a) c2w_b) by point-to-plane ICP of the
    two depth images, coarse to fine (4, 2, 1 cm) from `start` (loop_pairs.py's ICP, 1 cm voxels)."""
    from loop_pairs import cloud, icp

    return icp(cloud(depth_b, intr, 0.01), cloud(depth_a, intr, 0.01), np.asarray(start, dtype=np.float64))[0]


def compare(icp_t: np.ndarray, traj_t: np.ndarray) -> dict:
    """rms_cm and per-axis slopes (traj = s * icp) of two P x 3 sets of relative translations."""
    slopes = [float(icp_t[:, j] @ traj_t[:, j] / max(float(icp_t[:, j] @ icp_t[:, j]), 1e-12)) for j in range(3)]
    return {"rms_cm": round(100 * float(np.sqrt(np.mean(np.sum((traj_t - icp_t) ** 2, axis=1)))), 2),
            "slope_x": round(slopes[0], 3), "slope_y": round(slopes[1], 3), "slope_z": round(slopes[2], 3)}


def pair_motions(depths: dict, trajectories: dict, pairs: list, intr, start_from: str | None = None) -> dict:
    """{name: compare(...)} of the ICP relative translations at `intr` against each trajectory's.
    depths: {frame: H x W metres}; trajectories: {name: N x 4 x 4 c2w indexed by frame}; pairs: (a, b);
    start_from: the trajectory whose relative pose starts each ICP (None: the identity)."""
    icp_t, traj_t = [], {name: [] for name in trajectories}
    for a, b in pairs:
        rel = {name: np.linalg.inv(c2w[a]) @ c2w[b] for name, c2w in trajectories.items()}
        start = rel[start_from] if start_from else np.eye(4)
        icp_t.append(icp_relative(depths[a], depths[b], intr, start)[:3, 3])
        for name in trajectories:
            traj_t[name].append(rel[name][:3, 3])
    icp_t = np.array(icp_t)
    return {name: compare(icp_t, np.array(t)) for name, t in traj_t.items()}


def parse_focals(text: str) -> list[tuple[float, float]]:
    out = []
    for item in text.split(","):
        fx, _, fy = item.partition("/")
        out.append((float(fx), float(fy or fx)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequence", required=True)
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--run", help="a run folder: its trajectory is compared too and starts each ICP")
    parser.add_argument("--focals", default="585/585,560/585", help="fx/fy,... (fy defaults to fx)")
    parser.add_argument("--step", type=int, default=15, help="frames between the two of a pair")
    parser.add_argument("--every", type=int, default=15, help="frames between pairs")
    parser.add_argument("--frames", default=None, help="lo-hi: pairs start at lo and end before hi")
    parser.add_argument("--max-depth", type=float, default=3.5, help="depth beyond this is left out (metres)")
    args = parser.parse_args(argv)

    from three_lenses import matched

    from splat_core.camera import Intrinsics
    from splat_core.io import open_capture
    from splat_core.io.trajectory import read_tum_trajectory

    folder = Path(args.data) / args.sequence
    source = open_capture(folder)
    stamps = np.asarray(source.timestamps)
    trajectories = {}
    for name, file in REFERENCES.items():
        if (folder / file).exists():
            idx, c2w = matched(stamps, folder / file)
            if len(idx) != len(stamps):
                raise SystemExit(f"{file}: {len(idx)} of {len(stamps)} frames have a pose")
            trajectories[name] = c2w
    if args.run:
        run_stamps, c2w = read_tum_trajectory(Path(args.run) / "trajectory.txt")
        by_stamp = {round(float(t), 4): pose for t, pose in zip(run_stamps, np.asarray(c2w))}
        if any(round(float(t), 4) not in by_stamp for t in stamps):
            raise SystemExit(f"{args.run}: the run has no pose for some frames of {args.sequence}")
        trajectories["run"] = np.array([by_stamp[round(float(t), 4)] for t in stamps])
    lo, hi = (int(v) for v in args.frames.split("-")) if args.frames else (0, len(source))
    pairs = [(a, a + args.step) for a in range(lo, min(hi, len(source)) - args.step, args.every)]
    depths = {}
    for k in sorted({f for pair in pairs for f in pair}):
        d = np.asarray(source[k].depth, dtype=np.float64)
        depths[k] = np.where(d > args.max_depth, 0.0, d)
    base = source.intrinsics
    rows = []
    for fx, fy in parse_focals(args.focals):
        intr = Intrinsics(fx, fy, base.cx, base.cy, base.width, base.height)
        rows.append({"fx": fx, "fy": fy, **pair_motions(depths, trajectories, pairs, intr,
                                                         "run" if args.run else None)})
    print(json.dumps({"machine": machine_line(), "sequence": args.sequence, "pairs": len(pairs),
                      "step": args.step, "frames": f"{lo}-{hi}", "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
