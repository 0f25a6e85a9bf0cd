"""Where along a run does the pose error grow, and where is it pulled back? (issue 28, item 5)

    python benchmarks/error_profile.py --run RUN [--sequence 7scenes_redkitchen_600] [--fit 122:600]
                                       [--frames 380:520:5] [--open3d-voxel 0.01 | --open3d-poses P.npy]
                                       [--save-open3d P.npy] [--sensor-steps] [--json]

RUN is a run folder (`splatam run --out RUN`); its trajectory.txt is compared with the capture's
reference poses, and, side by side, Open3D's dense SLAM on the same frames (benchmarks/
baseline_open3d.py's run, or poses saved by an earlier --save-open3d). Each trajectory's camera
centres are fitted rigidly to the reference's over --fit (one fit for the whole range, so a
stretch that drifts and is later pulled back shows as error that grows, then falls), and the
distance to the reference is printed at --frames. `step_error_mm` is the error of the relative
motion from each printed frame f to f + --step (keyframes are every 5 frames; with --frames
A:B:5 the steps are consecutive), and `mean_step_error_mm` its mean over the printed frames.

--sensor-steps adds a map-independent odometry for comparison ("sensor"): each step's second frame
aligned (the tracker's direct alignment with loop verification's settings, from the cpu preset as
the pipeline adapts it to the capture) against Gaussians made from the first
frame's own colour and depth (one per pixel, opaque) at the run's pose of that frame, starting from
the run's step; and, as its counterpart, Open3D's RGB-D odometry (hybrid term) of the same frame
pairs at full resolution ("open3d_pairs"). A pose graph needs odometry edges that the map does not
pull; this says how good the simplest ones are, next to frame-to-model tracking (ours, Open3D's).
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


def profile(est: np.ndarray, ref: np.ndarray, fit: range, frames: range, step: int) -> dict:
    from splat_core.loop.verify import rigid_fit

    n = min(len(est), len(ref))
    fit = [f for f in fit if f < n]
    T = rigid_fit(est[fit, :3, 3], ref[fit, :3, 3])          # rigid, no scale
    error = np.linalg.norm(est[:n, :3, 3] @ T[:3, :3].T + T[:3, 3] - ref[:n, :3, 3], axis=1)
    shown = [f for f in frames if f < n]
    steps = {f: np.linalg.inv(est[f]) @ est[f + step] for f in shown if f + step < n}
    return dict(error_cm={f: round(100 * float(error[f]), 2) for f in shown}, **step_errors(steps, ref, step))


def step_errors(steps: dict, ref: np.ndarray, step: int) -> dict:
    """Errors (mm) of relative motions {f: c2w_f^-1 c2w_f+step} against the reference's."""
    from splat_core.loop.verify import pose_difference

    errors = {f: 1000 * pose_difference(T, np.linalg.inv(ref[f]) @ ref[f + step])[0] for f, T in steps.items()}
    return dict(step_error_mm={f: round(e, 2) for f, e in errors.items()},
                mean_step_error_mm=round(float(np.mean(list(errors.values()))), 2) if errors else None)


def sensor_steps(path: Path, est: np.ndarray, frames: range, step: int) -> dict:
    """{f: the sensor's relative motion c2w_f^-1 c2w_f+step} for f in frames."""
    from splat_core.align import align_to_map
    from splat_core.camera import backproject, invert_pose
    from splat_core.config import load_config
    from splat_core.gaussians import GaussianMap
    from splat_core.io import open_capture
    from splat_core.loop.closer import verification_align
    from splat_core.run.pipeline import Pipeline

    pipe = Pipeline(open_capture(path), load_config("cpu"), None, device="cpu")
    intr, kw = pipe.intrinsics, verification_align(pipe.engine.slam.view())
    out = {}
    for f in frames:
        if f + step >= len(est):
            break
        fa, fb = pipe.frame_at(f), pipe.frame_at(f + step)
        mask = fa.depth > 0
        c2w = est[f]
        pts = backproject(fa.depth, intr)[mask] @ c2w[:3, :3].T + c2w[:3, 3]
        g = GaussianMap.from_points(pts, fa.color[mask], fa.depth[mask] / intr.mean_focal, 0, opacity=0.99)
        aligned = align_to_map(g.tensors(detach=True), fb.color, fb.depth, intr, invert_pose(est[f + step]), **kw)
        out[f] = invert_pose(c2w) @ invert_pose(aligned.w2c)
    return out


def open3d_pair_steps(path: Path, frames: range, step: int) -> dict:
    """{f: Open3D RGB-D odometry's relative motion c2w_f^-1 c2w_f+step} for f in frames."""
    import baseline_open3d as b

    o3d = b.import_open3d()
    colors, depths, intr, _, _ = b.load_frames(path, frames.stop + step)
    rgbd, odometry = b.rgbd_odometry(o3d, colors, depths, intr, 3.0)
    # the second camera's points into the first's: the first's c2w^-1 times the second's
    return {f: odometry(rgbd(f + step), rgbd(f))[1] for f in frames if f + step < len(depths)}


def open3d_poses(path: Path, voxel: float) -> np.ndarray:
    import baseline_open3d as b

    o3d = b.import_open3d()
    colors, depths, intr, _, _ = b.load_frames(path, None)
    poses, _, _ = b.run_dense_slam(o3d, colors, depths, intr, voxel, 3.0, "CPU:0", 40000)
    return np.asarray(poses)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, type=Path)
    p.add_argument("--sequence", default="7scenes_redkitchen_600")
    p.add_argument("--data", default=str(DATA))
    p.add_argument("--fit", default="122:600", help="first:last+1 frames of the rigid fit")
    p.add_argument("--frames", default="380:520:5", help="first:last+1:every frames to print")
    p.add_argument("--step", type=int, default=5)
    p.add_argument("--open3d-voxel", type=float, default=None)
    p.add_argument("--open3d-poses", type=Path, default=None)
    p.add_argument("--save-open3d", type=Path, default=None)
    p.add_argument("--sensor-steps", action="store_true")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    from splat_core.io import open_capture
    from splat_core.io.trajectory import read_tum_trajectory

    path = Path(args.data) / args.sequence
    ref = np.asarray(open_capture(path).reference_c2w())
    fit, frames = range(*map(int, args.fit.split(":"))), range(*map(int, args.frames.split(":")))
    methods = {"ours": read_tum_trajectory(args.run / "trajectory.txt")[1]}
    if args.open3d_poses is not None:
        methods["open3d"] = np.load(args.open3d_poses)
    elif args.open3d_voxel is not None:
        methods["open3d"] = open3d_poses(path, args.open3d_voxel)
        if args.save_open3d is not None:
            np.save(args.save_open3d, methods["open3d"])
    rows = {name: profile(est, ref, fit, frames, args.step) for name, est in methods.items()}
    if args.sensor_steps:
        rows["sensor"] = dict(error_cm={}, **step_errors(sensor_steps(path, methods["ours"], frames, args.step), ref,
                                                         args.step))
        rows["open3d_pairs"] = dict(error_cm={}, **step_errors(open3d_pair_steps(path, frames, args.step), ref,
                                                               args.step))
    if args.json:
        print(json.dumps(dict(sequence=args.sequence, run=str(args.run), fit=args.fit, step=args.step,
                              open3d_voxel=args.open3d_voxel, profiles=rows, machine=machine_line())))
        return 0
    print(f"{args.sequence}: position error (cm) after a rigid fit on frames {args.fit}; "
          f"{args.step}-frame step error from there (mm)")
    print("frame  " + "  ".join(f"{name:>18s}" for name in rows))
    for f in frames:
        cells = [f"{r['error_cm'].get(f, float('nan')):7.2f} {r['step_error_mm'].get(f, float('nan')):8.2f}"
                 for r in rows.values()]
        print(f"{f:5d}  " + "  ".join(f"{c:>18s}" for c in cells))
    print("mean   " + "  ".join(f"{'':7s} {r['mean_step_error_mm'] or float('nan'):8.2f}".rjust(18) for r in rows.values()))
    print(machine_line())
    return 0


if __name__ == "__main__":
    sys.exit(main())
