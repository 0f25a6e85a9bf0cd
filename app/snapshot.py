"""MapSnapshot: what the SLAM worker publishes and the viewer draws (docs/design.md, data flow).

A snapshot is immutable once published: the map, the keyframes, both trajectories and the recent
metrics. Only the latest one is kept; the viewer pulls it at its own pace, so a slow browser never
slows tracking down. Arrays are marked read-only so an accidental write fails loudly instead of
racing with the worker.

The map crosses from SLAM to the viewer once: a snapshot carries the engine's published
`MapVersion` (immutable tensors) wrapped as `VersionArrays`; numpy arrays of it are made on the
first read, on the reader's thread, and kept by the version. A map read from a file (browse
mode) or refined in the viewer is a `FrozenArrays`. Both offer the arrays as a read-only mapping
and `tensors()` for the renderer, made once.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from splat_core.camera import Intrinsics
from splat_core.gaussians import Gaussians

# Worker / viewer states shown in the status panel.
STATES = ("starting", "running", "paused", "finished", "stopped", "error", "browse")

# When the browser gets the growing map while SLAM runs (app/viewer/scene.py MapLayer.policy).
MAP_UPDATE_POLICIES = ("keyframes", "continuous", "off")
# How the browser draws the map while SLAM runs (MapLayer.running_style; auto: points while a page that
# draws WebGL in software is connected, splats otherwise); always splats once it stops.
RUNNING_STYLES = ("auto", "splats", "points")

HISTORY_KEYS = ("frame", "tracking_loss", "ate_cm", "seconds", "psnr", "num_gaussians")
# The live panel's tiles are this many pixels wide (app/viewer/panels.py live_mosaic); the worker
# renders the map for it no wider (app/worker.py): pixels past it are drawn and then thrown away.
LIVE_TILE_WIDTH = 200


def frozen(a, copy: bool = True):
    """A read-only numpy array: a copy of `a`, or with copy=False `a` itself made read-only (an array
    the caller made for this and holds no other reference to)."""
    if a is None:
        return None
    a = np.array(a, copy=True) if copy else a
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class KeyframeView:
    """One keyframe as the viewer shows it: pose, a small thumbnail and the captured images.

    The images stay with the engine's keyframe (compact, maybe in its file) and are decoded when
    asked for, so snapshots do not hold a float copy of every keyframe."""

    frame_index: int            # processed-frame number (matches Gaussians' birth_frame)
    c2w: np.ndarray             # 4 x 4, camera-to-world, OpenCV axes
    thumbnail: np.ndarray       # h x w x 3 uint8 (about 100 px tall)
    images: object = None       # a splat_core.keyframes.Keyframe (immutable images), or None

    @property
    def color(self) -> np.ndarray | None:
        """H x W x 3 float32 in [0, 1] at the working resolution."""
        return None if self.images is None else self.images.color

    @property
    def depth(self) -> np.ndarray | None:
        """H x W float32 metres."""
        return None if self.images is None else self.images.depth


@dataclass(frozen=True)
class LiveView:
    """The latest frame: what the camera captured and our render of the map from its tracked pose."""

    frame_index: int
    color: np.ndarray           # captured, H x W x 3 float32
    depth: np.ndarray           # captured, H x W float32
    render_color: np.ndarray | None = None
    render_depth: np.ndarray | None = None
    render_alpha: np.ndarray | None = None   # the silhouette
    psnr: float | None = None


@dataclass(frozen=True)
class MapSnapshot:
    version: int                           # increases with every publication
    state: str                             # one of STATES
    frame_index: int                       # last processed frame (-1 before the first)
    total_frames: int
    map_version: int                       # changes only when `gaussians` changed
    gaussians: "MapArrays"                 # raw arrays as GaussianMap.to_numpy() (read-only)
    keyframes: tuple = ()                  # KeyframeView, in insertion order
    intrinsics: Intrinsics | None = None   # working resolution
    near_plane: float = 0.01               # the run's config.near_plane: every render of this map uses it
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimated_c2w: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    reference_c2w: np.ndarray | None = None  # T x 4 x 4, NaN where a frame has none
    history: dict = field(default_factory=dict)  # HISTORY_KEYS -> 1-D arrays, one entry per frame
    live: LiveView | None = None
    seconds_per_frame: float | None = None
    ate_cm: float | None = None
    message: str = ""
    out_dir: Path | None = None
    skipped_frames: tuple = ()             # (source index, reason) of bad frames the run skipped
    lost_frames: tuple = ()                # processed-frame numbers where tracking was lost (pose held, not mapped)
    received: tuple | None = None          # a live source (a stream, --realtime): (frames received, dropped)
    loops: tuple | None = None             # loops closed so far (splat_core/loop/closer.py records); None: loop closure off

    @property
    def tracking_lost(self) -> bool:
        """The newest frame is lost: SLAM is relocalising."""
        return bool(self.lost_frames) and self.lost_frames[-1] == self.frame_index

    @property
    def num_gaussians(self) -> int:
        return int(len(self.gaussians.get("means", ())))

    @property
    def keyframe_frames(self) -> np.ndarray:
        return np.array([kf.frame_index for kf in self.keyframes], dtype=np.int64)

    @property
    def processed(self) -> int:
        return self.frame_index + 1


class MapArrays(Mapping):
    """A map's arrays (GaussianMap.to_numpy() layout, read-only) and its renderer tensors."""

    def __getitem__(self, name: str) -> np.ndarray:
        return self._arrays()[name]

    def __iter__(self):
        return iter(self._arrays())

    def __len__(self) -> int:
        return len(self._arrays())

    def _arrays(self) -> dict:
        raise NotImplementedError

    def tensors(self) -> Gaussians:
        raise NotImplementedError


class VersionArrays(MapArrays):
    """A MapVersion published by the engine: its tensors as they are, its arrays made on first read."""

    def __init__(self, version):
        self.version = version

    def _arrays(self) -> dict:
        return self.version.arrays

    def tensors(self) -> Gaussians:
        return self.version.gaussians


class FrozenArrays(MapArrays):
    """Read-only copies of map arrays (a file, a refined map); tensors made on first use."""

    def __init__(self, arrays: dict):
        n = len(arrays["means"])
        self._frozen = {k: frozen(v) for k, v in arrays.items()}
        if self._frozen.get("birth_frame") is None:
            self._frozen["birth_frame"] = frozen(np.zeros(n, np.int64))
        self._tensors: Gaussians | None = None
        self._lock = threading.Lock()

    def _arrays(self) -> dict:
        return self._frozen

    def tensors(self) -> Gaussians:
        with self._lock:
            if self._tensors is None:
                self._tensors = Gaussians.from_arrays(self._frozen)
            return self._tensors


def empty_gaussians() -> dict:
    return dict(means=np.zeros((0, 3), np.float32), colors=np.zeros((0, 3), np.float32),
                rotations=np.zeros((0, 4), np.float32), logit_opacities=np.zeros(0, np.float32),
                log_scales=np.zeros((0, 1), np.float32), birth_frame=np.zeros(0, np.int64))


def freeze_gaussians(arrays: dict) -> FrozenArrays:
    """Read-only copies of the Gaussian arrays (birth_frame added as zeros when absent)."""
    return FrozenArrays(arrays)


def make_thumbnail(color: np.ndarray, height: int = 100) -> np.ndarray:
    """A small uint8 copy of a float colour image for frustum textures."""
    import cv2

    h, w = color.shape[:2]
    width = max(1, int(round(w * height / h)))
    img = np.clip(np.asarray(color, np.float32), 0, 1)
    small = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA) if h > height else img
    return (small * 255.0 + 0.5).astype(np.uint8)


def keyframe_buckets(birth_frame: np.ndarray, keyframe_frames: np.ndarray) -> np.ndarray:
    """For each Gaussian, the keyframe whose map first contains it.

    Bucket k holds the Gaussians born in (kf_{k-1}, kf_k]; K (= number of keyframes) is the
    tail born after the last keyframe. Showing buckets 0..k shows the map as it was at keyframe k.
    """
    return np.searchsorted(np.asarray(keyframe_frames, np.int64), np.asarray(birth_frame, np.int64),
                           side="left")
