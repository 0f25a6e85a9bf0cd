"""COLMAP and nerfstudio exports of finished runs checked against the runs; prints JSON.

    python benchmarks/handoff.py RUN_DIR ... [--frames keyframes|all|N]

Per run: export time and size; the COLMAP model read back by pycolmap: images, points, mean
track length, the largest pose difference from the run's poses (w2c entries), the largest
distance between a track's 2D point and where its Gaussian projects with the run's pose (px; the
targets are 1e-6 and 1 px); the nerfstudio transforms.json: the largest difference between each
transform_matrix taken back to an OpenCV w2c and the run's pose.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
from common import machine  # noqa: E402

from splat_core.camera import invert_pose  # noqa: E402
from splat_core.export import write_colmap, write_nerfstudio  # noqa: E402
from splat_core.export.frames import choose_frames, frame_name  # noqa: E402
from splat_core.export.nerfstudio import OPENCV_TO_OPENGL  # noqa: E402
from splat_core.export.seed_points import project_points  # noqa: E402
from splat_core.refine.run_data import load_run_data, open_run_capture  # noqa: E402


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def check_run(run_dir: Path, frames: str) -> dict:
    import pycolmap

    run = load_run_data(run_dir)
    kf_pose = {kf.frame_index: kf.w2c for kf in run.keyframes}
    pose_of = {frame_name(run, k): kf_pose.get(k, run.w2cs[k]) for k in choose_frames(run, frames)}
    intr = open_run_capture(run).intrinsics
    out = dict(run=str(run_dir), frames=frames)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        summary = write_colmap(run, Path(tmp) / "colmap", frames=frames)
        out["colmap"] = dict(seconds=round(time.perf_counter() - t0, 2), bytes=folder_bytes(Path(tmp) / "colmap"), **summary)
        rec = pycolmap.Reconstruction(str(Path(tmp) / "colmap" / "sparse" / "0"))
        cam = rec.cameras[1]
        pose_err, reproj, own = 0.0, 0.0, 0.0
        for image in rec.images.values():
            w2c = pose_of[image.name.rsplit(".", 1)[0]]
            pose_err = max(pose_err, float(np.abs(image.cam_from_world().matrix() - w2c[:3]).max()))
        track_lengths = []
        for point in rec.points3D.values():
            track_lengths.append(point.track.length())
            for el in point.track.elements:
                image = rec.images[el.image_id]
                xy = image.points2D[el.point2D_idx].xy
                u, v, _ = project_points(np.asarray(point.xyz)[None], pose_of[image.name.rsplit(".", 1)[0]], intr)
                own = max(own, float(np.hypot(u[0] + 0.5 - xy[0], v[0] + 0.5 - xy[1])))
                reproj = max(reproj, float(np.linalg.norm(cam.img_from_cam(image.cam_from_world() * point.xyz) - xy)))
        out["colmap"].update(read_images=len(rec.images), read_points=len(rec.points3D),
                             mean_track_length=float(np.mean(track_lengths)), max_pose_diff=pose_err,
                             max_track_vs_gaussian_px=own, max_track_vs_pycolmap_projection_px=reproj)
        t0 = time.perf_counter()
        summary = write_nerfstudio(run, Path(tmp) / "ns", frames=frames)
        out["nerfstudio"] = dict(seconds=round(time.perf_counter() - t0, 2), bytes=folder_bytes(Path(tmp) / "ns"), **summary)
        meta = json.loads((Path(tmp) / "ns" / "transforms.json").read_text())
        diff = 0.0
        for f in meta["frames"]:
            w2c = invert_pose(np.asarray(f["transform_matrix"]) @ OPENCV_TO_OPENGL)
            diff = max(diff, float(np.abs(w2c - pose_of[Path(f["file_path"]).stem]).max()))
        out["nerfstudio"]["max_pose_diff"] = diff
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR")
    p.add_argument("--frames", default="keyframes")
    args = p.parse_args()
    print(json.dumps(dict(benchmark="handoff", machine=machine(), date=time.strftime("%Y-%m-%d"),
                          runs=[check_run(Path(r), args.frames) for r in args.runs]), indent=1))


if __name__ == "__main__":
    main()
