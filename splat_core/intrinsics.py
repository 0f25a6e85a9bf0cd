"""Intrinsics: a pinhole camera at one image size (torch-free: the run folder and the input
contract use it; the pixel-centre convention is stated in camera.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics for an image of `width` x `height` pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        if not (self.fx > 0 and self.fy > 0 and self.width > 0 and self.height > 0):
            raise InputError(
                f"intrinsics must be positive, got fx={self.fx} fy={self.fy} "
                f"width={self.width} height={self.height}"
            )
        if not all(np.isfinite([self.fx, self.fy, self.cx, self.cy])):
            raise InputError(f"intrinsics must be finite, got {self}")

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """The same camera at another resolution (pixel-centre convention preserved)."""
        sx, sy = width / self.width, height / self.height
        # With centres at integer coordinates, the image spans [-0.5, W-0.5]; scaling maps that span.
        return Intrinsics(
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5,
            int(width), int(height),
        )

    def fraction(self, s: float) -> "Intrinsics":
        """The same camera at s times the resolution (at least one pixel); itself when s == 1."""
        if s == 1:
            return self
        return self.scaled(max(1, round(self.width * s)), max(1, round(self.height * s)))

    @classmethod
    def from_fov(cls, fov_y: float, width: int, height: int) -> "Intrinsics":
        """Square pixels, centred principal point, vertical field of view fov_y (radians; a
        browser camera's): the inverse of `fov_y`."""
        fy = (height / 2.0) / np.tan(fov_y / 2.0)
        return cls(fy, fy, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def mean_focal(self) -> float:
        return 0.5 * (self.fx + self.fy)

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * float(np.arctan2(self.height / 2.0, self.fy))

    def to_dict(self) -> dict:
        return dict(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=self.width, height=self.height)

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        """The inverse of to_dict (extra keys ignored); KeyError / TypeError when one is missing."""
        return cls(**{k: d[k] for k in ("fx", "fy", "cx", "cy", "width", "height")})
