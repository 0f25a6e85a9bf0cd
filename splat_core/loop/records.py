"""What loop closure hands back: a typed record of each loop it accepted, and the correction
SplaTAM applies (splat_core/slam.py is the only writer of poses, keyframes and the map).

A LoopRecord travels in three vehicles with the same fields: FrameResult.loops (the loops closed
at that frame), MapVersion.loops (every loop so far, for the viewer) and metrics.json `loops`
(`to_dict`, read back by `from_dict`: the viewer browsing a run folder, other tools).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LoopRecord:
    keyframes: tuple = ()     # (old, current) keyframe positions, counted from 0
    frames: tuple = ()        # their processed-frame numbers
    inliers: int = 0          # RANSAC inliers of the verification
    evidence: dict = field(default_factory=dict, compare=False)   # verification's figures (verify.py)
    visible: float = 0.0      # share of the current view the old keyframe's Gaussians cover
    orb_matches: int = 0
    disagreement_cm: float | None = None    # the loop's pose against the tracked one
    disagreement_deg: float | None = None
    applied: bool = True      # a correction moved poses and map (the loop disagreed by more than the threshold)
    correction_cm: float | None = None      # how far the current keyframe moved
    correction_deg: float | None = None
    inconsistent_loops: tuple = ()          # older loops' keyframes the robust kernel turned down
    seconds: float = 0.0      # detection, verification, correction and re-mapping
    apply_seconds: float = 0.0              # the correction itself (the live engine holds its pose lock so long)

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        for key in ("keyframes", "frames", "inconsistent_loops"):
            out[key] = list(out[key])
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "LoopRecord":
        """A record as metrics.json holds it (fields an older run did not write take their defaults)."""
        known = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in d.items() if k in known}
        for key in ("keyframes", "frames", "inconsistent_loops"):
            if key in kw:
                kw[key] = tuple(kw[key])
        return cls(**kw)


@dataclass(frozen=True)
class Correction:
    """The pose graph's answer to a loop: new keyframe poses, and the keyframes to re-map after
    moving (the seam). SplaTAM.apply_correction moves keyframes, frame poses and Gaussians."""

    keyframe_frames: np.ndarray     # K processed-frame numbers of the keyframes, in order
    old_c2ws: list                  # K poses the graph started from
    new_c2ws: list                  # K optimised poses
    remap_keyframes: tuple = ()     # keyframe positions to re-map briefly
    remap_iterations: int = 0


@dataclass(frozen=True)
class LoopFound:
    """One accepted loop: its record (timings filled in by SplaTAM) and the correction, if any."""

    record: LoopRecord
    correction: Correction | None
