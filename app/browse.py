"""Browse mode: a finished run folder or any 3DGS `.ply` as a MapSnapshot, without SLAM.

A run folder holds map.ply and trajectory.txt (required: map.ply); when it also has
checkpoint/, the checkpoint gives birth frames, keyframes (poses and images) and the working
intrinsics, so scrubbing works as in a live run. metrics.json, when present, gives the ATE.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from splat_core.camera import Intrinsics, invert_pose
from splat_core.errors import InputError

from .snapshot import KeyframeView, MapSnapshot, freeze_gaussians, frozen, make_thumbnail


def read_map(path: Path) -> dict:
    from splat_core.io.map_files import read_map_file

    return read_map_file(path)


def intrinsics_from_run(run_dir: Path) -> Intrinsics | None:
    """The working-resolution intrinsics recorded in a run folder (checkpoint or metrics), if any."""
    ckpt = _checkpoint(run_dir)
    intr = _checkpoint_intrinsics(ckpt) if ckpt is not None else None
    metrics = run_dir / "metrics.json"
    if intr is None and metrics.is_file():
        try:
            intr = _intrinsics_from(json.loads(metrics.read_text()).get("intrinsics"))
        except ValueError:
            intr = None
    return intr


def _checkpoint(run_dir: Path):
    try:
        from splat_core.io import checkpoint
    except ImportError:
        return None
    if not checkpoint.exists(run_dir / "checkpoint"):
        return None
    return checkpoint.load(run_dir / "checkpoint")


def _checkpoint_intrinsics(ckpt) -> Intrinsics | None:
    return _intrinsics_from(ckpt.meta.get("intrinsics"))


def _intrinsics_from(intr) -> Intrinsics | None:
    """Intrinsics from a dict like Intrinsics.to_dict() (as recorded in meta/metrics), or None."""
    if isinstance(intr, dict):
        try:
            return Intrinsics(**{k: intr[k] for k in ("fx", "fy", "cx", "cy", "width", "height")})
        except (KeyError, TypeError, InputError):
            pass
    return None


def near_plane_of(path) -> float:
    """The near plane a run was made with (its config.yaml), else the engine's default."""
    import yaml

    from splat_core.config import Config
    config = Path(path) / "config.yaml" if Path(path).is_dir() else Path(path).parent / "config.yaml"
    try:
        return float(yaml.safe_load(config.read_text())["near_plane"])
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        return Config.near_plane


def load_run(path) -> MapSnapshot:
    """A browse-mode snapshot of RUN_DIR (map.ply + trajectory.txt [+ checkpoint/]) or MAP.ply."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such run folder or map file")
    timestamps = np.zeros(0)
    c2w = np.zeros((0, 4, 4))
    keyframes: tuple = ()
    intrinsics = None
    ate = None
    if path.is_dir():
        map_path = path / "map.ply"
        if not map_path.is_file():
            raise InputError(f"{path}: not a run folder (expected map.ply inside)")
        gaussians = read_map(map_path)
        traj = path / "trajectory.txt"
        if traj.is_file():
            from splat_core.io.trajectory import read_tum_trajectory
            timestamps, c2w = read_tum_trajectory(traj)
        ckpt = _checkpoint(path)
        if ckpt is not None:
            g = ckpt.gaussians()
            if "birth_frame" in g and len(g["birth_frame"]) == len(gaussians["means"]):
                gaussians["birth_frame"] = np.asarray(g["birth_frame"], np.int64)
            intrinsics = _checkpoint_intrinsics(ckpt)
            keyframes = _checkpoint_keyframes(path / "checkpoint", ckpt.arrays, intrinsics)
        metrics = path / "metrics.json"
        if metrics.is_file():
            try:
                data = json.loads(metrics.read_text())
                ate = data.get("ate_rmse_cm")
                intrinsics = intrinsics or _intrinsics_from(data.get("intrinsics"))
            except (ValueError, AttributeError):
                ate = None
    else:
        gaussians = read_map(path)
    return MapSnapshot(
        version=1, state="browse", near_plane=near_plane_of(path), frame_index=len(c2w) - 1, total_frames=len(c2w), map_version=1,
        gaussians=freeze_gaussians(gaussians), keyframes=keyframes, intrinsics=intrinsics,
        timestamps=frozen(timestamps), estimated_c2w=frozen(c2w), history={},
        ate_cm=float(ate) if ate is not None else None, message=str(path),
        out_dir=path if path.is_dir() else None)


def _checkpoint_keyframes(checkpoint_dir: Path, arrays: dict, intrinsics: Intrinsics | None) -> tuple:
    if "kf_index" not in arrays or len(arrays["kf_index"]) == 0 or intrinsics is None:
        return ()
    from splat_core.keyframes import read_keyframes

    return tuple(KeyframeView(kf.frame_index, frozen(invert_pose(kf.w2c)), frozen(make_thumbnail(kf.color)), kf)
                 for kf in read_keyframes(checkpoint_dir, arrays, intrinsics))
