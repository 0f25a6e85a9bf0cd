"""The run folder: one owner of its file names, its writing and its reading.

    RUN/trajectory.txt      TUM, camera-to-world, OpenCV axes, the capture's timestamps
    RUN/map.ply             the map, 3DGS PLY
    RUN/metrics.json        accuracy, speed, per-frame records
    RUN/config.yaml         the resolved config
    RUN/checkpoint/         state.npz + meta.json (io/checkpoint.py), keyframes.bin (its records: keyframes.py)
    RUN/map_refined.ply     `splatam refine`'s map (its section in metrics.json: "refine")
    RUN/refine_checkpoint/  an unfinished refinement
    RUN/capture/            a live stream's frames, recorded as they arrive

The pipeline writes it (`write_results`, `save_checkpoint`); refine reads it strictly
(`require_finished`: everything must be there), browsing and rendering tolerantly (each reader
returns None or nothing for a file that is missing or unreadable). Every write is atomic.

Imports no torch (numpy and yaml only): `splatam batch`'s workers and summaries use it too; the
readers that build engine objects (keyframes) import the engine when called.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from ..errors import InputError
from ..intrinsics import Intrinsics
from ..io import checkpoint as ckpt_io
from ..io.atomic import write_text_atomic

if TYPE_CHECKING:
    from ..keyframes import Keyframe

TRAJECTORY, MAP, METRICS, CONFIG, CHECKPOINT = "trajectory.txt", "map.ply", "metrics.json", "config.yaml", "checkpoint"
REFINED_MAP, REFINE_CHECKPOINT, CAPTURE = "map_refined.ply", "refine_checkpoint", "capture"
KEYFRAME_FILE = "keyframes.bin"      # in CHECKPOINT


class RunFolder:
    def __init__(self, path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    # ------------------------------------------------------------------ names
    @property
    def trajectory(self) -> Path:
        return self.path / TRAJECTORY

    @property
    def map(self) -> Path:
        return self.path / MAP

    @property
    def metrics(self) -> Path:
        return self.path / METRICS

    @property
    def config(self) -> Path:
        return self.path / CONFIG

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT

    @property
    def keyframe_file(self) -> Path:
        return self.checkpoint_dir / KEYFRAME_FILE

    @property
    def refined_map(self) -> Path:
        return self.path / REFINED_MAP

    @property
    def refine_checkpoint_dir(self) -> Path:
        return self.path / REFINE_CHECKPOINT

    @property
    def capture_dir(self) -> Path:
        return self.path / CAPTURE

    # ------------------------------------------------------------------ writing
    def write_results(self, timestamps, c2ws, map_arrays: dict, config_dict: dict, metrics: dict,
                      comments: dict | None = None) -> None:
        """trajectory.txt, map.ply, config.yaml and metrics.json, each atomically."""
        from ..io.ply import write_ply
        from ..io.trajectory import write_tum_trajectory

        self.path.mkdir(parents=True, exist_ok=True)
        write_tum_trajectory(self.trajectory, timestamps, c2ws, comments=comments)
        write_ply(self.map, map_arrays)
        write_text_atomic(self.config, yaml.safe_dump(config_dict, sort_keys=False))
        write_text_atomic(self.metrics, json.dumps(metrics, indent=1))

    def save_checkpoint(self, arrays: dict, meta: dict) -> None:
        ckpt_io.save(self.checkpoint_dir, arrays, meta)

    def add_metrics_section(self, name: str, section: dict) -> None:
        """metrics.json with `name` set to `section` (the rest kept), rewritten atomically."""
        metrics = {}
        if self.metrics.is_file():
            try:
                metrics = json.loads(self.metrics.read_text())
            except ValueError:
                raise InputError(f"{self.metrics}: not valid JSON; not overwriting it") from None
        metrics[name] = section
        write_text_atomic(self.metrics, json.dumps(metrics, indent=1))

    # ------------------------------------------------------------------ state
    def has_checkpoint(self) -> bool:
        return ckpt_io.exists(self.checkpoint_dir)

    def is_finished(self) -> bool:
        return self.metrics.is_file()

    def load_checkpoint(self) -> ckpt_io.Checkpoint:
        return ckpt_io.load(self.checkpoint_dir)

    # ------------------------------------------------------------------ tolerant readers
    def checkpoint_or_none(self) -> ckpt_io.Checkpoint | None:
        try:
            return self.load_checkpoint() if self.has_checkpoint() else None
        except InputError:
            return None

    def checkpoint_meta(self) -> dict | None:
        """The checkpoint's meta.json alone (no arrays read), or None."""
        try:
            data = json.loads((self.checkpoint_dir / ckpt_io.META).read_text())
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def read_metrics(self) -> dict | None:
        try:
            data = json.loads(self.metrics.read_text())
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def read_config_dict(self) -> dict | None:
        try:
            data = yaml.safe_load(self.config.read_text())
        except (OSError, yaml.YAMLError):
            return None
        return data if isinstance(data, dict) else None

    def read_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(timestamps N, c2w N x 4 x 4); empty arrays when there is no trajectory."""
        if not self.trajectory.is_file():
            return np.zeros(0), np.zeros((0, 4, 4))
        from ..io.trajectory import read_tum_trajectory
        return read_tum_trajectory(self.trajectory)

    def intrinsics(self, ckpt: ckpt_io.Checkpoint | None = None) -> Intrinsics | None:
        """The working-resolution intrinsics (the checkpoint's, else metrics.json's), or None."""
        ckpt = ckpt if ckpt is not None else self.checkpoint_or_none()
        for record in ((ckpt.meta if ckpt is not None else {}).get("intrinsics"),
                       (self.read_metrics() or {}).get("intrinsics")):
            if isinstance(record, dict):
                try:
                    return Intrinsics.from_dict(record)
                except (KeyError, TypeError, InputError):
                    pass
        return None

    def near_plane(self) -> float:
        """The near plane the run was made with (config.yaml), else the engine's default."""
        from ..config import Config
        try:
            return float((self.read_config_dict() or {})["near_plane"])
        except (KeyError, TypeError, ValueError):
            return Config.near_plane

    def keyframes(self, ckpt: ckpt_io.Checkpoint, intrinsics: Intrinsics) -> list[Keyframe]:
        """The checkpoint's keyframes (poses; images read from keyframes.bin on demand)."""
        if len(ckpt.arrays.get("kf_index", ())) == 0:
            return []
        from ..keyframes import read_keyframes
        return read_keyframes(self.keyframe_file, ckpt.arrays, intrinsics)

    # ------------------------------------------------------------------ strict reader
    def require_finished(self) -> ckpt_io.Checkpoint:
        """The checkpoint of a finished run; InputError naming what is missing or unfinished."""
        if not self.path.is_dir():
            raise InputError(f"{self.path}: no such run folder")
        for path in (self.map, self.config):
            if not path.is_file():
                raise InputError(f"{self.path}: not a finished run folder (expected {path.name} inside)")
        if not self.has_checkpoint():
            raise InputError(f"{self.checkpoint_dir}: no checkpoint (this needs the run's keyframes)")
        ckpt = self.load_checkpoint()
        meta = ckpt.meta
        if meta.get("total") is not None and meta["frames_done"] < meta["total"]:
            raise InputError(f"{self.path}: the run is unfinished ({meta['frames_done']} of {meta['total']} frames); "
                             "finish it with splatam run --resume first")
        return ckpt
