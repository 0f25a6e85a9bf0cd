"""Hard captures: the synthetic sequence with one disturbance (a jump, a covered lens, a fast turn)."""

from __future__ import annotations

import numpy as np

from ..camera import Intrinsics
from ..frame import Frame
from ..io.source import FrameSource
from .scene import FPS
from .source import SyntheticSource


# ----------------------------------------------------------------------------- hard captures

HARD_KINDS = ("none", "jump", "covered", "turn")


def turn_away(c2w: np.ndarray, degrees: float) -> np.ndarray:
    """c2w turned by `degrees` about the camera's own vertical axis (a pan, in place)."""
    a = np.radians(degrees)
    pan = np.eye(4)
    pan[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    return c2w @ pan


class HardCapture(FrameSource):
    """The synthetic sequence with one disturbance at frame `at` (issue 13's hard captures):

    none      the undisturbed sequence (the baseline)
    jump      `length` frames (30) missing: frame `at` is followed by frame at+31 of the path, as
              in a recording that dropped a second (indices run on, timestamps jump)
    covered   `length` frames (5) of a covered lens: black colour, no depth (the pipeline skips
              them as bad frames; tracking must pick up after them)
    turn      a fast 90-degree pan away from the objects and back: 90 degrees in 3 frames, held for
              `length` frames (4), 3 frames back; the camera keeps moving along its path

    Reference poses are the poses rendered (`c2w_ref`); the undisturbed path has n_frames frames.
    """

    format_name = "synthetic"
    path = None

    def __init__(self, kind: str = "none", n_frames: int = 60, at: int = 25, length: int | None = None,
                 width: int = 160, height: int = 120, seed: int = 0):
        if kind not in HARD_KINDS:
            raise ValueError(f"kind must be one of {', '.join(HARD_KINDS)}, got {kind!r}")
        self.kind, self.at = kind, int(at)
        self.length = int(length if length is not None else {"jump": 30, "covered": 5, "turn": 4}.get(kind, 0))
        first_undisturbed = at + 1 + {"jump": 0, "covered": self.length, "turn": self.length + 5}.get(kind, 0)
        if not 0 <= at < first_undisturbed < n_frames:
            raise ValueError(f"a '{kind}' at frame {at} does not fit in {n_frames} frames")
        path_frames = n_frames + (self.length if kind == "jump" else 0)
        self.base = SyntheticSource(n_frames=path_frames, width=width, height=height, seed=seed)
        self.path_index = np.arange(path_frames)
        if kind == "jump":
            self.path_index = np.concatenate([self.path_index[: at + 1], self.path_index[at + 1 + self.length:]])
        self.c2w = self.base.c2w[self.path_index].copy()
        if kind == "turn":
            profile = np.concatenate([[30, 60], np.full(self.length + 1, 90), [60, 30]])
            for k, deg in enumerate(profile):
                self.c2w[at + 1 + k] = turn_away(self.c2w[at + 1 + k], deg)

    def __len__(self) -> int:
        return len(self.path_index)

    @property
    def intrinsics(self) -> Intrinsics:
        return self.base.intrinsics

    @property
    def timestamps(self) -> np.ndarray:
        return self.path_index / FPS

    @property
    def has_reference_poses(self) -> bool:
        return True

    def reference_c2w(self) -> np.ndarray:
        return self.c2w.copy()

    def __getitem__(self, i: int) -> Frame:
        color, depth = self.base.scene.render(self.c2w[i], self.intrinsics)
        if self.kind == "covered" and self.at < i <= self.at + self.length:
            color, depth = np.zeros_like(color), np.zeros_like(depth)
        return Frame(index=i, timestamp=float(self.timestamps[i]), color=color, depth=depth,
                     intrinsics=self.intrinsics, c2w_ref=self.c2w[i].copy())

    def describe(self) -> str:
        return f"synthetic hard capture '{self.kind}' at frame {self.at} ({len(self)} frames)"
