"""The synthetic room as a phone captures it: sharp colour on a large grid, LiDAR depth on a
grid several times smaller (an iPhone: colour 1920x1440, depth 256x192), exact poses.

It is an `IndexedCapture`, like the Record3D / Stray Scanner / NeRFCapture readers, so the
Pipeline resamples colour and depth from their own grids exactly as for a real phone capture.
Frames are rendered once and kept (a benchmark then times SLAM, not the ray caster).
"""

from __future__ import annotations

import numpy as np

from ..io.common import IndexedCapture
from .paths import camera_path, default_intrinsics
from .scene import FPS, SyntheticScene
from .source import add_depth_noise


class SyntheticPhoneCapture(IndexedCapture):
    format_name = "synthetic-phone"

    def __init__(self, n_frames: int = 20, color_size=(1024, 768), depth_size=(256, 192), seed: int = 0,
                 noise: float = 0.0, **options):
        super().__init__("synthetic-phone", **options)
        self.scene = SyntheticScene(seed=seed)
        self.seed, self.noise = seed, noise
        self._color_intr = default_intrinsics(*color_size)
        self._depth_size = tuple(depth_size)
        self._finish(np.arange(n_frames) / FPS, list(camera_path(n_frames, seed)), "n_frames must be >= 1")
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _render(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in self._cache:
            color, _ = self.scene.render(self._c2w[i], self._color_intr)
            _, depth = self.scene.render(self._c2w[i], self._color_intr.scaled(*self._depth_size))
            depth = add_depth_noise(depth, self.noise, np.random.default_rng([self.seed, i, 1]))
            self._cache[i] = (color, depth)
        return self._cache[i]

    def _read_color(self, i: int) -> np.ndarray:
        return self._render(i)[0]

    def _read_depth(self, i: int) -> tuple[np.ndarray, int]:
        return self._render(i)[1], 0

    def describe(self) -> str:
        (cw, ch), (dw, dh) = self.color_size, self.depth_size
        return f"synthetic phone capture ({len(self)} frames, colour {cw}x{ch}, depth {dw}x{dh})"
