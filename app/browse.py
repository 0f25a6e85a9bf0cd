"""Browse mode: a finished run folder or any 3DGS `.ply` as a MapSnapshot, without SLAM.

A run folder holds map.ply and trajectory.txt (required: map.ply); when it also has
checkpoint/, the checkpoint gives birth frames, keyframes (poses and images) and the working
intrinsics, so scrubbing works as in a live run. metrics.json, when present, gives the ATE and
the loops closed (its `loops` list, shown as edges between keyframes and in the status panel).
Reading follows RunFolder's tolerant readers: a missing or unreadable extra is left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from splat_core.camera import invert_pose
from splat_core.io.map_files import map_path_of, read_map_file
from splat_core.loop.records import LoopRecord
from splat_core.run.run_folder import RunFolder

from .snapshot import KeyframeView, MapSnapshot, freeze_gaussians, frozen, make_thumbnail


def near_plane_of(path) -> float:
    """The near plane a run was made with (its config.yaml, beside a map file too), else the default."""
    path = Path(path)
    return RunFolder(path if path.is_dir() else path.parent).near_plane()


def load_run(path) -> MapSnapshot:
    """A browse-mode snapshot of RUN_DIR (map.ply + trajectory.txt [+ checkpoint/]) or MAP.ply."""
    path = Path(path)
    gaussians = read_map_file(map_path_of(path))
    timestamps, c2w = np.zeros(0), np.zeros((0, 4, 4))
    keyframes: tuple = ()
    intrinsics = ate = loops = None
    if path.is_dir():
        folder = RunFolder(path)
        timestamps, c2w = folder.read_trajectory()
        ckpt = folder.checkpoint_or_none()
        if ckpt is not None:
            g = ckpt.gaussians()
            if "birth_frame" in g and len(g["birth_frame"]) == len(gaussians["means"]):
                gaussians["birth_frame"] = np.asarray(g["birth_frame"], np.int64)
        intrinsics = folder.intrinsics(ckpt)
        if ckpt is not None and intrinsics is not None:
            keyframes = tuple(KeyframeView(kf.frame_index, frozen(invert_pose(kf.w2c)), frozen(make_thumbnail(kf.color)), kf)
                              for kf in folder.keyframes(ckpt, intrinsics))
        metrics = folder.read_metrics() or {}
        ate = metrics.get("ate_rmse_cm")
        if isinstance(metrics.get("loops"), list):      # written when the run had loop closure on
            loops = tuple(LoopRecord.from_dict(r) for r in metrics["loops"] if isinstance(r, dict))
    return MapSnapshot(
        version=1, state="browse", near_plane=near_plane_of(path), frame_index=len(c2w) - 1, total_frames=len(c2w),
        map_version=1, gaussians=freeze_gaussians(gaussians), keyframes=keyframes, intrinsics=intrinsics,
        timestamps=frozen(timestamps), estimated_c2w=frozen(c2w), history={},
        ate_cm=float(ate) if ate is not None else None, message=str(path),
        out_dir=path if path.is_dir() else None, loops=loops)
