"""Open3D baselines on the real sequences: what a classical RGB-D pipeline gets on the same data.

    python benchmarks/baseline_open3d.py [--data ../shared/data] [--sequences a,b,c]
        [--methods dense,odometry] [--voxel-size 0.02[,0.0058,...]] [--depth-max 3.0] [--max-frames N]
        [--device CPU:0]

Needs the optional benchmark extra: `pip install -e ".[bench]"` (open3d). Prints one JSON
object per sequence and method, e.g.

    {"sequence": "7scenes_redkitchen_300", "method": "open3d_dense_slam", "frames": 300,
     "ate_rmse_cm": 2.4, "s_per_frame": 0.14, ...}

Methods
  dense     open3d.t.pipelines.slam.Model: frame-to-model tracking (point-to-plane ICP against
            the TSDF volume ray-cast at the previous pose), TSDF integration, ray-casting; the
            loop of Open3D's examples/python/t_reconstruction_system/dense_slam.py. Voxel size
            --voxel-size (default 0.02 m; a comma-separated list runs each), depth cut
            --depth-max (3.0 m), truncation 8 voxels, depth_diff 0.07 m (Open3D's defaults).
  odometry  frame-to-frame RGB-D odometry, open3d.pipelines.odometry.compute_rgbd_odometry with
            the hybrid (photometric + geometric) Jacobian, each frame registered to the previous
            one starting from identity, poses chained. A failed registration keeps the previous
            pose (counted in "failures").

ATE: splat_core.metrics.ate_rmse (camera centres, rigid alignment without scale, RMSE) against
groundtruth.txt. Where the reference has steps its own depth contradicts
(splat_core.io.checks.inconsistent_steps: 7-Scenes redkitchen 121 -> 122), the row adds
reference_breaks and ate_rmse_split_cm, the ATE with the trajectory cut there and each piece
aligned on its own (metrics.ate_rmse_segments). s_per_frame is the Open3D compute time per frame (tracking + integration +
ray-casting, or odometry), excluding reading and decoding the images; io_s_per_frame is that.

Frames are read with splat_core.io.open_capture (TUM layout + camera.yaml; 7-Scenes depth 65535
is invalid) and handed to Open3D as uint16 millimetres (depth_scale 1000) and uint8 colour.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data"
DEFAULT_SEQUENCES = ["7scenes_redkitchen_300", "sun3d_3dmatch_fragment1", "sun3d_3dmatch_fragment2"]
DEPTH_SCALE = 1000.0  # what we hand to Open3D: uint16 millimetres


def import_open3d():
    try:
        import open3d as o3d
    except ImportError as e:
        sys.exit(
            "benchmarks/baseline_open3d.py needs Open3D, an optional benchmark dependency:\n"
            "    pip install -e '.[bench]'      (or: pip install open3d)\n"
            f"import failed: {e}\n"
            "(On Debian/Ubuntu a missing libusb-1.0.so.0 is fixed by: apt-get install libusb-1.0-0)"
        )
    return o3d


def load_frames(path: Path, max_frames: int | None):
    """uint8 colour, uint16 depth (mm), intrinsics and reference c2w of a capture, plus read time."""
    from splat_core.io import open_capture

    src = open_capture(path)
    n = len(src) if max_frames is None else min(len(src), max_frames)
    t0 = time.perf_counter()
    colors, depths = [], []
    for i in range(n):
        f = src[i]
        colors.append(np.ascontiguousarray(np.clip(np.rint(f.color * 255.0), 0, 255).astype(np.uint8)))
        depths.append(np.ascontiguousarray(np.clip(np.rint(f.depth * DEPTH_SCALE), 0, 65535).astype(np.uint16)))
    io_s = (time.perf_counter() - t0) / max(n, 1)
    ref = src.reference_c2w()
    ref = ref[:n] if ref is not None else None
    return colors, depths, src.intrinsics, ref, io_s


def run_dense_slam(o3d, colors, depths, intr, voxel_size, depth_max, device_name, block_count):
    o3c = o3d.core
    device = o3c.Device(device_name)
    K = o3c.Tensor(intr.K, dtype=o3c.Dtype.Float64)
    T = o3c.Tensor(np.eye(4), dtype=o3c.Dtype.Float64)
    model = o3d.t.pipelines.slam.Model(voxel_size, 16, block_count, T, device)
    h, w = depths[0].shape
    input_frame = o3d.t.pipelines.slam.Frame(h, w, K, device)
    raycast_frame = o3d.t.pipelines.slam.Frame(h, w, K, device)
    poses, failures = [], 0
    t0 = time.perf_counter()
    for i, (color, depth) in enumerate(zip(colors, depths)):
        input_frame.set_data_from_image("depth", o3d.t.geometry.Image(o3c.Tensor(depth)).to(device))
        input_frame.set_data_from_image("color", o3d.t.geometry.Image(o3c.Tensor(color)).to(device))
        if i > 0:
            try:
                result = model.track_frame_to_model(input_frame, raycast_frame, DEPTH_SCALE, depth_max, 0.07)
                T = T @ result.transformation
            except RuntimeError:   # too few correspondences: keep the last pose
                failures += 1
        poses.append(T.cpu().numpy().copy())
        model.update_frame_pose(i, T)
        model.integrate(input_frame, DEPTH_SCALE, depth_max, 8.0)
        model.synthesize_model_frame(raycast_frame, DEPTH_SCALE, 0.1, depth_max, 8.0, False)
    elapsed = time.perf_counter() - t0
    return np.stack(poses), elapsed / len(depths), failures


def rgbd_odometry(o3d, colors, depths, intr, depth_max):
    """(rgbd(i): frame i as an Open3D RGBDImage, odometry(source, target): (ok, T) with T mapping the
    source camera's points into the target's), Open3D's RGB-D odometry with the hybrid term."""
    pinhole = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
    option = o3d.pipelines.odometry.OdometryOption()
    option.depth_max = depth_max
    jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()

    def rgbd(i):
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(colors[i]), o3d.geometry.Image(depths[i]),
            depth_scale=DEPTH_SCALE, depth_trunc=depth_max, convert_rgb_to_intensity=True)

    def odometry(source, target):
        ok, T, _ = o3d.pipelines.odometry.compute_rgbd_odometry(source, target, pinhole, np.eye(4), jacobian, option)
        return ok, np.asarray(T)
    return rgbd, odometry


def run_rgbd_odometry(o3d, colors, depths, intr, depth_max):
    rgbd, odometry = rgbd_odometry(o3d, colors, depths, intr, depth_max)
    c2w = np.eye(4)
    poses, failures = [c2w.copy()], 0
    t0 = time.perf_counter()
    previous = rgbd(0)
    for i in range(1, len(depths)):
        current = rgbd(i)
        ok, cur_to_prev = odometry(current, previous)
        if ok:
            c2w = c2w @ cur_to_prev
        else:
            failures += 1
        poses.append(c2w.copy())
        previous = current
    elapsed = time.perf_counter() - t0
    return np.stack(poses), elapsed / len(depths), failures


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--sequences", default=",".join(DEFAULT_SEQUENCES))
    ap.add_argument("--methods", default="dense,odometry")
    ap.add_argument("--voxel-size", default="0.02", help="TSDF voxel size(s) in metres, comma-separated")
    ap.add_argument("--block-count", type=int, default=None,
                    help="voxel blocks to allocate (default 10000 at >= 0.01 m voxels, else 40000)")
    ap.add_argument("--depth-max", type=float, default=3.0)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--device", default="CPU:0", help="Open3D device for dense SLAM (CPU:0, CUDA:0)")
    ap.add_argument("--save-trajectories", type=Path, default=None, metavar="DIR",
                    help="write each run's trajectory there (TUM, the capture's timestamps: "
                         "SEQUENCE__METHOD.txt), e.g. for benchmarks/three_lenses.py --trajectory")
    args = ap.parse_args(argv)

    o3d = import_open3d()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    sys.path.insert(0, str(ROOT))
    from splat_core.io import open_capture
    from splat_core.io.checks import reference_breaks
    from splat_core.metrics import ate_rmse, ate_rmse_segments

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = set(methods) - {"dense", "odometry"}
    if unknown:
        ap.error(f"unknown method(s) {sorted(unknown)}; choose from dense, odometry")
    try:
        voxel_sizes = [float(v) for v in args.voxel_size.split(",") if v.strip()]
    except ValueError:
        ap.error(f"--voxel-size {args.voxel_size}: expected metres, comma-separated")
    info = machine() | {"open3d": o3d.__version__, "device": args.device}
    status = 0
    for name in [s.strip() for s in args.sequences.split(",") if s.strip()]:
        path = args.data / name
        if not path.is_dir():
            print(json.dumps({"sequence": name, "error": f"{path} not found"}), flush=True)
            status = 1
            continue
        colors, depths, intr, ref, io_s = load_frames(path, args.max_frames)
        breaks = [b for b in reference_breaks(open_capture(path)) if b < len(depths) - 1]
        runs = [("dense", v) for v in voxel_sizes] if "dense" in methods else []
        runs += [("odometry", None)] if "odometry" in methods else []
        for method, voxel_size in runs:
            if method == "dense":
                block_count = args.block_count or (10000 if voxel_size >= 0.01 else 40000)
                est, s_per_frame, failures = run_dense_slam(
                    o3d, colors, depths, intr, voxel_size, args.depth_max, args.device, block_count)
                extra = {"method": "open3d_dense_slam", "voxel_size": voxel_size, "block_count": block_count}
            else:
                est, s_per_frame, failures = run_rgbd_odometry(o3d, colors, depths, intr, args.depth_max)
                extra = {"method": "open3d_rgbd_odometry_hybrid"}
            ate = ate_rmse(est, ref) if ref is not None else float("nan")
            if args.save_trajectories is not None:
                from splat_core.io.trajectory import write_tum_trajectory
                args.save_trajectories.mkdir(parents=True, exist_ok=True)
                tag = method if voxel_size is None else f"{method}_{voxel_size:g}"
                stamps = open_capture(path).timestamps[:len(est)]
                write_tum_trajectory(args.save_trajectories / f"{name}__{tag}.txt", stamps, est,
                                     header=f"Open3D {extra['method']} on {name}")
            split = {"reference_breaks": breaks,
                     "ate_rmse_split_cm": round(100 * ate_rmse_segments(est, ref, breaks), 3)} if breaks else {}
            print(json.dumps({
                "sequence": name, **extra, "frames": len(depths), "depth_max": args.depth_max,
                "ate_rmse_cm": round(100 * ate, 3), **split, "s_per_frame": round(s_per_frame, 4),
                "io_s_per_frame": round(io_s, 4), "failures": failures, "machine": info,
            }), flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
