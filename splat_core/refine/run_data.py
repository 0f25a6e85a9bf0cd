"""What refinement reads from a finished run folder, and the frames it trains and evaluates on.

A run folder (run/run_folder.py) holds config.yaml, map.ply, trajectory.txt, metrics.json and
checkpoint/; the checkpoint has the map's raw parameters, the keyframes (at the working
resolution, with their frozen poses; read with keyframes.read_keyframes), every frame's estimated
pose, and the input's path.
Training views are the keyframes; held-out views are the processed frames that are not keyframes
(SplaTAM's novel-view protocol), at their estimated poses. At the capture's resolution both are
re-read from the capture (keyframes are only stored at the working resolution).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import yaml

from ..camera import Intrinsics
from ..config import Config, config_from_dict
from ..errors import InputError
from ..io.source import FrameSource
from ..mapping import View
from ..gaussians import GaussianMap
from ..keyframes import Keyframe
from ..run.run_folder import RunFolder

RESOLUTIONS = ("capture", "working")


@dataclass
class RunData:
    run_dir: Path
    config: Config
    intrinsics: Intrinsics     # the working resolution
    map: GaussianMap           # as checkpointed at the end of the run
    w2cs: list[np.ndarray]     # every processed frame's estimated pose
    scene_radius: float
    keyframes: list[Keyframe]  # frozen poses, images at the working resolution
    records: list[dict]        # per processed frame: source_index, ...
    capture: dict | None       # the input as recorded: path, format (None: not recorded)

    @property
    def keyframe_indices(self) -> list[int]:
        return [kf.frame_index for kf in self.keyframes]

    @property
    def heldout_indices(self) -> list[int]:
        keyframes = set(self.keyframe_indices)
        return [k for k in range(len(self.records)) if k not in keyframes]

    def view(self, color: np.ndarray, depth: np.ndarray, w2c: np.ndarray) -> View:
        t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=self.map.dtype, device=self.map.device)  # noqa: E731
        return View(t(color), t(depth), w2c)


def load_run_data(run_dir, device="cpu") -> RunData:
    """A finished run folder's state; InputError naming what is missing or unreadable."""
    folder = RunFolder(run_dir)
    ckpt = folder.require_finished()
    try:
        config = config_from_dict(yaml.safe_load(folder.config.read_text()))
    except (yaml.YAMLError, TypeError, ValueError) as e:
        raise InputError(f"{folder.config}: not a run's config ({e})") from None
    meta = ckpt.meta
    intr = Intrinsics.from_dict(meta["intrinsics"])
    keyframes = folder.keyframes(ckpt, intr)
    if not keyframes:
        raise InputError(f"{folder.checkpoint_dir}: the run has no keyframes")
    gmap = GaussianMap.from_numpy(ckpt.gaussians(), device=device)
    return RunData(folder.path, config, intr, gmap, [w for w in np.asarray(ckpt.arrays["w2cs"], np.float64)],
                   float(ckpt.arrays["scene_radius"]), keyframes, list(meta["records"]), meta.get("input"))


def open_run_capture(run: RunData, override=None) -> FrameSource | None:
    """The run's capture (`override`: a path given by the user), or None when none is recorded.
    A capture the run registered from its own estimate (colour and depth not registered, no colour
    camera given) is registered the same way again: the estimate is deterministic."""
    from ..registration_estimate import register_from_estimate
    from ..run import open_input

    if override is not None:
        source = open_input(str(override))
    elif not run.capture:
        return None
    else:
        path = Path(run.capture["path"])
        if not path.exists():
            raise InputError(f"{path}: the run's capture is gone (recorded in {run.run_dir / 'checkpoint'}); "
                             "pass --input CAPTURE")
        source = open_input(str(path), format=run.capture.get("format"))
    if not source.registered and run.config.estimate_registration:
        register_from_estimate(source)
    return source


def frame_views(run: RunData, source: FrameSource, intr: Intrinsics, indices: list[int]) -> list[View]:
    """Processed frames `indices` re-read from the capture at `intr`, at their estimated poses."""
    from ..run.frame_feed import prepare_frame

    views = []
    for k in indices:
        frame = prepare_frame(source, int(run.records[k]["source_index"]), intr, run.config.max_depth)
        views.append(run.view(frame.color, frame.depth, run.w2cs[k]))
    return views


def training_views(run: RunData, source: FrameSource | None, resolution: str) -> tuple[Intrinsics, list[View]]:
    """The keyframes at the capture's or the working resolution, and the intrinsics to render them."""
    if resolution not in RESOLUTIONS:
        raise InputError(f"--resolution {resolution}: expected capture or working")
    if resolution == "working":
        return run.intrinsics, [run.view(kf.color, kf.depth, kf.w2c) for kf in run.keyframes]
    if source is None:
        raise InputError(f"{run.run_dir}: the run does not record its capture; pass --input CAPTURE "
                         "(or --resolution working)")
    intr = source.intrinsics
    return intr, frame_views(run, source, intr, run.keyframe_indices)
