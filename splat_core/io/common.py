"""What the capture readers share: a lazily indexed FrameSource (file access inside folders or
zip archives: stores.py; camera files: camera_files.py).

Policies every reader follows (stated once here):
- A frame without depth is skipped and counted in `source.warnings`; pairing is never shifted
  to fill the gap.
- A frame without a reference pose (no ground-truth sample near it, or an invalid -inf pose) is
  kept with `c2w_ref = None` and counted: reference poses are for evaluation only.
- Colour and depth of different sizes are brought to one working resolution:
  `resolution="depth"` (default) shrinks colour to the depth size with area averaging,
  `resolution="color"` enlarges depth to the colour size with nearest neighbour. Depth is never
  blended. Intrinsics are scaled with `Intrinsics.scaled`.
- Phone confidence maps (ARKit's 0 low, 1 medium, 2 high): depth with confidence below
  `min_confidence` becomes invalid. Default 2 (high only), as viser's Record3D loader, usa's
  reader, concept-graphs' converter and Stray Scanner's own `convert_to_open3d.py` do for
  reconstruction (docs/formats.md, capture layouts section 1); the map is built from depth, and medium-confidence pixels
  are where flying pixels at depth edges and far range live. StrayVisualizer's point-cloud view
  defaults to 1: pass `min_confidence=1` for that denser, noisier depth, or 0 to keep everything.
- Intrinsics that vary per frame (ARKit refocuses) are given per frame when the capture stores
  them; `intrinsics` is then the capture's nominal camera.
- Two cameras (a camera file with `color_intrinsics` / `depth_to_color`, registration.py): the
  reader's intrinsics are the depth camera's, and each frame's colour is registered to the depth
  grid when read (`register_frame`), before any resizing; the frames are then on the depth camera's
  grid whatever `resolution` says. A description of one camera (identity) changes nothing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..frame import Frame, resize_to
from ..registration import TwoCameras, register_frame
from .source import FrameSource

RESOLUTIONS = ("depth", "color")
DEFAULT_MIN_CONFIDENCE = 2  # ARKit high confidence only (see above)


# ----------------------------------------------------------------------------- the base reader

class IndexedCapture(FrameSource):
    """A capture whose frames are addressed by index and read from files on demand.

    Subclasses fill, in their constructor: `_timestamps` (seconds, one per frame), `_c2w` (list of
    4x4 c2w OpenCV or None), `_color_intr` (intrinsics of the colour images as stored) and, when
    depth is stored at another size, `_depth_size` (width, height); then implement `_read_color`,
    `_read_depth` and optionally `_read_confidence`.
    """

    format_name = "unknown"

    def __init__(self, path, *, resolution: str = "depth", min_confidence: int | None = None):
        if resolution not in RESOLUTIONS:
            raise InputError(f"resolution must be one of {RESOLUTIONS}, got {resolution!r}")
        self.path = Path(path)
        self.resolution = resolution
        self.min_confidence = DEFAULT_MIN_CONFIDENCE if min_confidence is None else int(min_confidence)
        self.warnings: list[str] = []
        self.invalid_depth_pixels = 0  # NaN / inf / negative / "no reading" pixels seen so far
        self._timestamps = np.zeros(0)
        self._c2w: list[np.ndarray | None] = []
        self._color_intr: Intrinsics | None = None
        self._depth_size: tuple[int, int] | None = None
        self.two_cameras: TwoCameras | None = None   # colour registered to depth when read (use_two_cameras)

    # -- to implement
    def _read_color(self, i: int) -> np.ndarray:
        raise NotImplementedError

    def _read_depth(self, i: int) -> tuple[np.ndarray, int]:
        """(HxW float32 metres with 0 invalid, number of pixels invalidated) and the file's name."""
        raise NotImplementedError

    def _read_confidence(self, i: int) -> np.ndarray | None:
        return None

    def _frame_color_intr(self, i: int) -> Intrinsics:
        """Intrinsics of frame i's colour image as stored (override for per-frame intrinsics)."""
        return self._color_intr

    def _name(self, i: int, kind: str) -> str:
        """The file behind frame i's colour/depth, for error messages."""
        return f"{self.path} frame {i} ({kind})"

    # -- FrameSource
    def __len__(self) -> int:
        return len(self._timestamps)

    @property
    def timestamps(self) -> np.ndarray:
        return self._timestamps

    @property
    def color_size(self) -> tuple[int, int]:
        c = self.two_cameras.color if self.two_cameras is not None else self._color_intr
        return c.width, c.height

    @property
    def depth_size(self) -> tuple[int, int]:
        return self._depth_size or (self._color_intr.width, self._color_intr.height)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the frames this source yields."""
        return self.depth_size if self.resolution == "depth" or self.two_cameras else self.color_size

    def use_two_cameras(self, cams: TwoCameras | None) -> None:
        """The camera file describes the colour camera beside the depth camera (`_color_intr`, set
        before, is then the depth camera's): frames are registered when read, unless the two
        cameras are one (then nothing changes)."""
        if cams is None or cams.is_identity(self._color_intr):
            return
        if self._depth_size not in (None, (self._color_intr.width, self._color_intr.height)):
            raise InputError(f"{self.path}: the camera file's width x height ({self._color_intr.width}x"
                             f"{self._color_intr.height}) must be the depth images' ({self._depth_size[0]}x"
                             f"{self._depth_size[1]}) when it describes two cameras")
        self.two_cameras = cams
        self.registered = True

    @property
    def intrinsics(self) -> Intrinsics:
        return self._at_working_size(self._color_intr)

    def _at_working_size(self, intr: Intrinsics) -> Intrinsics:
        w, h = self.size
        return intr if (w, h) == (intr.width, intr.height) else intr.scaled(w, h)

    @property
    def has_reference_poses(self) -> bool:
        return any(T is not None for T in self._c2w)

    def reference_c2w(self) -> np.ndarray | None:
        if not self.has_reference_poses:
            return None
        out = np.full((len(self), 4, 4), np.nan)
        for i, T in enumerate(self._c2w):
            if T is not None:
                out[i] = T
        return out

    def __getitem__(self, i: int) -> Frame:
        return self.frame_at_size(i, *self.size)

    def frame_at_size(self, i: int, width: int, height: int) -> Frame:
        """Frame i at width x height, colour and depth each resampled from the grid it is stored on
        (so depth is never upsampled twice)."""
        n = len(self)
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"frame index must be an integer, got {type(i).__name__}")
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} out of range (capture has {n} frames)")
        i = int(i)
        color, depth = self.raw_pair(i)
        if self.two_cameras is not None:
            color, depth = register_frame(color, depth, self._frame_color_intr(i), self.two_cameras)
        intr = self._frame_color_intr(i)
        if (width, height) != (intr.width, intr.height):
            intr = intr.scaled(width, height)
        if color.shape[:2] != (intr.height, intr.width):
            color = np.clip(resize_to(color, intr, False), 0.0, 1.0)
        depth = resize_to(depth, intr, True)
        T = self._c2w[i] if self._c2w else None
        return Frame(i, float(self._timestamps[i]), np.ascontiguousarray(color, dtype=np.float32),
                     np.ascontiguousarray(depth, dtype=np.float32), intr, None if T is None else T.copy())

    def raw_pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame i's colour and depth (metres, confidence applied) as stored, each on its own grid."""
        color = self._read_color(i)
        if (color.shape[1], color.shape[0]) != self.color_size:
            raise InputError(f"{self._name(i, 'color')}: image is {color.shape[1]}x{color.shape[0]}, "
                             f"expected {self.color_size[0]}x{self.color_size[1]} like the other frames")
        depth, n_bad = self._read_depth(i)
        if (depth.shape[1], depth.shape[0]) != self.depth_size:
            raise InputError(f"{self._name(i, 'depth')}: depth is {depth.shape[1]}x{depth.shape[0]}, "
                             f"expected {self.depth_size[0]}x{self.depth_size[1]}")
        self.invalid_depth_pixels += n_bad
        conf = self._read_confidence(i)
        if conf is not None:
            if conf.shape != depth.shape:
                raise InputError(f"{self._name(i, 'confidence')}: confidence map is {conf.shape[1]}x{conf.shape[0]}, "
                                 f"expected the depth size {depth.shape[1]}x{depth.shape[0]}")
            depth = np.where(conf >= self.min_confidence, depth, np.float32(0)).astype(np.float32)
        return color, depth

    def describe(self) -> str:
        w, h = self.size
        return f"{self.format_name} capture at {self.path} ({len(self)} frames, {w}x{h})"

    # -- helpers for subclasses
    def warn(self, message: str) -> None:
        self.warnings.append(message)

    def _finish(self, stamps, c2w, what: str) -> None:
        """Store timestamps and poses; refuse an empty capture."""
        self._timestamps = np.asarray(stamps, dtype=np.float64)
        self._c2w = list(c2w)
        if len(self._timestamps) == 0:
            raise InputError(f"{self.path}: no usable frames ({what})")
        n_missing = sum(T is None for T in self._c2w)
        if 0 < n_missing < len(self._c2w):
            self.warn(f"{n_missing} of {len(self._c2w)} frames have no reference pose (kept, without one)")


def sort_by_time(stamps: np.ndarray, name: str, warnings: list[str]) -> np.ndarray:
    """Order that sorts timestamps (stable); warns when the file was not in time order."""
    stamps = np.asarray(stamps, dtype=np.float64)
    order = np.argsort(stamps, kind="stable")
    if np.any(np.diff(stamps) < 0):
        warnings.append(f"{name}: timestamps out of order; sorted by time")
    return order
