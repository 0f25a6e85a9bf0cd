"""The synthetic room as a FrameSource: rendered frames along the orbit, with optional sensor effects."""

from __future__ import annotations

import numpy as np

from ..camera import Intrinsics
from ..frame import Frame
from ..io.source import FrameSource
from .paths import camera_path, default_intrinsics
from .scene import FPS, SyntheticScene


# ----------------------------------------------------------------------------- sensor effects

def add_depth_noise(depth: np.ndarray, coeff: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with standard deviation coeff * depth^2 (Kinect-like; coeff in 1/m,
    e.g. 0.0015 gives 6 mm at 2 m). Invalid (0) pixels stay 0."""
    if coeff <= 0:
        return depth
    noisy = depth + rng.normal(size=depth.shape) * coeff * depth.astype(np.float64) ** 2
    return np.where(depth > 0, np.maximum(noisy, 1e-3), 0.0).astype(np.float32)


def hole_mask(height: int, width: int, fraction: float, rng: np.random.Generator,
              blob_px: int = 12) -> np.ndarray:
    """Boolean HxW mask of random blobs (about `blob_px` pixels across) covering `fraction` of the
    image: a coarse random field, smoothly upsampled, thresholded at its `fraction` quantile."""
    import cv2

    if fraction <= 0:
        return np.zeros((height, width), dtype=bool)
    gh, gw = max(2, height // blob_px + 2), max(2, width // blob_px + 2)
    field_ = cv2.resize(rng.random((gh, gw)).astype(np.float32), (width, height),
                        interpolation=cv2.INTER_CUBIC)
    return field_ < np.quantile(field_, min(fraction, 1.0))


# ----------------------------------------------------------------------------- the FrameSource

class SyntheticSource(FrameSource):
    """A procedural RGB-D sequence with exact camera-to-world poses (OpenCV axes).

    n_frames, width, height   sequence length and image size
    seed                      textures, path phase and sensor noise (fully deterministic per seed)
    noise                     depth noise coefficient: std = noise * depth^2 (metres; 0 = exact)
    holes                     fraction of pixels set invalid (depth 0) in random blobs (0 = none)
    max_depth                 far-range cutoff: depth beyond it set to 0 (None = no cutoff)
    fov_deg / intrinsics      horizontal field of view, or explicit intrinsics (overrides fov)
    speed                     scales per-frame camera motion (1.0 ~ hand-held at 30 fps)

    Frame i has timestamp i / 30 s and `c2w_ref` = the exact pose used to render it.
    """

    format_name = "synthetic"
    path = None
    registered_by = "the synthetic scene: colour and depth rendered from one camera"

    def __init__(self, n_frames: int = 60, width: int = 320, height: int = 240, seed: int = 0,
                 noise: float = 0.0, holes: float = 0.0, max_depth: float | None = None,
                 fov_deg: float = 60.0, intrinsics: Intrinsics | None = None, speed: float = 1.0):
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        if not 0.0 <= holes < 1.0:
            raise ValueError(f"holes must be a fraction in [0, 1), got {holes}")
        if noise < 0:
            raise ValueError(f"noise must be >= 0, got {noise}")
        self.n_frames = int(n_frames)
        self.seed = int(seed)
        self.noise = float(noise)
        self.holes = float(holes)
        self.max_depth = max_depth
        if intrinsics is None:
            intrinsics = default_intrinsics(width, height, fov_deg)
        self._intrinsics = intrinsics
        self.scene = SyntheticScene(seed=self.seed)
        self.c2w = camera_path(self.n_frames, self.seed, speed)

    def __len__(self) -> int:
        return self.n_frames

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    @property
    def timestamps(self) -> np.ndarray:
        return np.arange(self.n_frames, dtype=np.float64) / FPS

    @property
    def has_reference_poses(self) -> bool:
        return True

    def reference_c2w(self) -> np.ndarray:
        return self.c2w.copy()

    def render_view(self, c2w: np.ndarray, intrinsics: Intrinsics | None = None):
        """Exact (noise-free, hole-free) colour and depth from any pose inside the room."""
        return self.scene.render(c2w, intrinsics or self._intrinsics)

    def __getitem__(self, i: int) -> Frame:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i} out of range for {self.n_frames} synthetic frames")
        i = i % self.n_frames
        color, depth = self.scene.render(self.c2w[i], self._intrinsics)
        rng = np.random.default_rng([self.seed, i, 1])
        depth = add_depth_noise(depth, self.noise, rng)
        if self.max_depth is not None:
            depth = np.where(depth > self.max_depth, 0.0, depth).astype(np.float32)
        if self.holes > 0:
            depth = np.where(hole_mask(*depth.shape, self.holes, rng), 0.0, depth).astype(np.float32)
        return Frame(index=i, timestamp=i / FPS, color=color, depth=depth,
                     intrinsics=self._intrinsics, c2w_ref=self.c2w[i].copy())

    def describe(self) -> str:
        return (f"synthetic scene (seed {self.seed}, {self.n_frames} frames, "
                f"{self._intrinsics.width}x{self._intrinsics.height})")


def render_view(c2w: np.ndarray, intrinsics: Intrinsics, seed: int = 0):
    """Colour and depth of the synthetic scene with textures from `seed`, at any pose."""
    return SyntheticScene(seed=seed).render(c2w, intrinsics)
