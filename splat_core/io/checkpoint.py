"""Checkpoints of a SLAM run: `checkpoint/state.npz` (arrays) + `checkpoint/meta.json`.

Both are written atomically, meta last: meta names the number of frames the arrays hold, so a
crash between the two writes is detected and the older pair is never mixed with the newer.
The keyframe images are not in state.npz: they are appended once each to
`checkpoint/keyframes.bin` as they are made (keyframes.py), and the arrays name how many of its
records belong to the checkpoint, so a checkpoint costs the map and the poses, not the run's
length.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path, write_text_atomic

STATE, META = "state.npz", "meta.json"


@dataclass
class Checkpoint:
    arrays: dict            # SplaTAM.state_arrays(): map_*, kf_*, w2cs, scene_radius, rng_state
    meta: dict              # frames_done, per-frame records, config, input, ...

    @property
    def frames_done(self) -> int:
        return int(self.meta["frames_done"])

    def gaussians(self) -> dict:
        """The map's raw arrays (means, colors, rotations, logit_opacities, log_scales, birth_frame)."""
        return {k[4:]: v for k, v in self.arrays.items() if k.startswith("map_")}


def save(directory, arrays: dict, meta: dict) -> None:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with atomic_path(directory / STATE) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    write_text_atomic(directory / META, json.dumps(meta, indent=1))


def exists(directory) -> bool:
    return (Path(directory) / META).is_file() and (Path(directory) / STATE).is_file()


def load(directory) -> Checkpoint:
    directory = Path(directory)
    if not exists(directory):
        raise InputError(f"{directory}: no checkpoint here (expected {STATE} and {META})")
    try:
        meta = json.loads((directory / META).read_text())
        with np.load(directory / STATE, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{directory}: unreadable checkpoint ({e})") from None
    if len(arrays.get("w2cs", ())) != meta.get("frames_done"):
        raise InputError(f"{directory}: checkpoint arrays and {META} disagree; delete the folder to start over")
    return Checkpoint(arrays, meta)
