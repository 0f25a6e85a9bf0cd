"""Keyframe store (host memory, compact, spilled to a file past a budget) and overlap-based
selection of the mapping window.

Keyframes keep their colour and depth on the host at the working resolution, so device memory
does not grow with the sequence (a known problem of the original, which keeps them on the GPU),
and compactly, so host memory grows by little: colour as uint8 (the captures' own precision) and
depth as uint16 in steps of the keyframe's largest depth / 65535 (0.08 mm at 5 m). 320x240 costs
0.38 MB per keyframe instead of 1.2 MB in float32. Poses are frozen at insertion, as in SplaTAM.

With a file (a run folder's `checkpoint/keyframes.bin`) every keyframe is appended to it when it
is added: the file is both the checkpoint's copy (written once, so a checkpoint's cost does not
grow with the run) and where keyframes live once the newest ones fill `memory_mb`; without one,
keyframes past the budget go to an anonymous temporary file. A spilled keyframe is read back with
pread when a mapping window or the viewer asks for it. Records have a fixed size, so keyframe j
is at offset j * record size, and a checkpoint that names the number of keyframes it holds
ignores (and a resume truncates) whatever a crash appended after it.
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path

import numpy as np

from .camera import Intrinsics, backproject, invert_pose
from .config import KeyframeConfig
from .errors import InputError

DEPTH_LEVELS = 65535


def encode(color: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(uint8 colour, uint16 depth, depth step in metres) of float images."""
    c8 = np.clip(np.rint(np.asarray(color, np.float32) * 255.0), 0, 255).astype(np.uint8)
    top = float(np.max(depth, initial=0.0))
    step = top / DEPTH_LEVELS if top > 0 else 1.0
    d16 = np.clip(np.rint(np.asarray(depth, np.float64) / step), 0, DEPTH_LEVELS).astype(np.uint16)
    c8.setflags(write=False)             # shared with snapshots and other threads: never modified
    d16.setflags(write=False)
    return c8, d16, step


class Keyframe:
    """One keyframe: processed-frame number, frozen w2c, and its images (decoded on access)."""

    __slots__ = ("frame_index", "w2c", "depth_step", "_images", "_store", "_slot")

    def __init__(self, frame_index: int, w2c: np.ndarray, color8: np.ndarray, depth16: np.ndarray,
                 depth_step: float, store: "KeyframeStore | None" = None, slot: int | None = None):
        self.frame_index = int(frame_index)
        self.w2c = np.array(w2c, dtype=np.float64)
        self.depth_step = float(depth_step)
        self._images = None if color8 is None else (color8, depth16)
        self._store, self._slot = store, slot

    @classmethod
    def from_images(cls, frame_index: int, w2c: np.ndarray, color: np.ndarray, depth: np.ndarray) -> "Keyframe":
        return cls(frame_index, w2c, *encode(color, depth))

    @property
    def resident(self) -> bool:
        return self._images is not None

    def images8(self) -> tuple[np.ndarray, np.ndarray]:
        """The compact images (uint8 colour, uint16 depth), from memory or the store's file."""
        images = self._images          # one read: the mapper may spill this keyframe meanwhile
        return images if images is not None else self._store.read(self._slot)

    @property
    def color(self) -> np.ndarray:
        """H x W x 3 float32 in [0, 1]."""
        return self.images8()[0].astype(np.float32) / np.float32(255.0)

    @property
    def depth(self) -> np.ndarray:
        """H x W float32 metres (0 = invalid)."""
        return (self.images8()[1] * self.depth_step).astype(np.float32)


def is_keyframe_time(index: int, total: int | None, every: int, step_before: int | None = None,
                     step: int | None = None, from_end: int = 2) -> bool:
    """Frame 0, every `every`-th frame ((index+1) % every == 0), and the frame `from_end` from the end
    of a run of `total` frames (2: the second-to-last, SplaTAM's rule).

    With `step` and `step_before` (the frame's and the frame before's place in the capture, when
    frames were dropped between processed ones): the first frame at or past every `every`-th capture
    step, i.e. (step+1) // every passed a multiple since the frame before. With step = index and
    step_before = index - 1 (no frame dropped) the two rules agree."""
    if step is None or step_before is None:
        step, step_before = index, index - 1
    return index == 0 or (step + 1) // every > (step_before + 1) // every or (total is not None and index == total - from_end)


def overlap_scores(depth: np.ndarray, w2c: np.ndarray, intr: Intrinsics, keyframes: list[Keyframe],
                   rng: np.random.Generator, samples: int = 1600, border: int = 20,
                   within_depth: bool = False) -> np.ndarray:
    """Fraction of the current frame's sampled depth points that project inside each keyframe.

    Samples `samples` valid pixels (with replacement), back-projects them with the current pose,
    and counts those landing more than `border` pixels inside each keyframe's image in front of it
    (SplaTAM's test). `within_depth` also asks that the point's depth in the keyframe's view be
    no more than the farthest depth the keyframe measured (+5%): a keyframe ten metres back down a
    corridor "sees" today's view inside its image but never measured it, and choosing it would put
    the whole stretch in between into the mapping window, so that mapping's cost grows with the
    run.
    """
    valid = np.flatnonzero(depth.reshape(-1) > 0)
    if valid.size == 0 or not keyframes:
        return np.zeros(len(keyframes))
    pick = rng.choice(valid, size=samples, replace=True)
    pts_cam = backproject(depth, intr).reshape(-1, 3)[pick]
    c2w = invert_pose(w2c)
    pts_world = pts_cam @ c2w[:3, :3].T + c2w[:3, 3]
    w2cs = np.stack([kf.w2c for kf in keyframes])                      # K x 4 x 4
    p = w2cs[:, :3, :3] @ pts_world.T + w2cs[:, :3, 3, None]            # K x 3 x N: one pass for all
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intr.fx * p[:, 0] / z + intr.cx
        v = intr.fy * p[:, 1] / z + intr.cy
    inside = (z > 0) & (u > border) & (u < intr.width - border) & (v > border) & (v < intr.height - border)
    if within_depth:
        far = np.array([kf.depth_step * DEPTH_LEVELS for kf in keyframes]) * 1.05
        inside &= z <= far[:, None]
    return inside.mean(axis=1)


class KeyframeStore:
    def __init__(self, config: KeyframeConfig, intrinsics: Intrinsics):
        self.config = config
        self.intrinsics = intrinsics
        self.items: list[Keyframe] = []
        self.shape = (intrinsics.height, intrinsics.width)
        self._fd: int | None = None      # the keyframe file (append-only records), once there is one
        self._path: Path | None = None
        self._written = 0                # keyframes the file holds
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self):
        return iter(list(self.items))

    @property
    def record_bytes(self) -> int:
        h, w = self.shape
        return h * w * 3 + h * w * 2

    def resident_bytes(self) -> int:
        """Host memory the keyframes' images take now (the rest are in the file)."""
        return sum(self.record_bytes for kf in self.items if kf.resident)

    # -------------------------------------------------------------- the file
    def attach(self, path, keep: int = 0, readonly: bool = False) -> None:
        """Write keyframes to `path` from now on: a new file, or (resume) the first `keep` records
        of it, dropping what a crash appended after them; `readonly` only reads those records."""
        path = Path(path)
        if keep and (not path.is_file() or path.stat().st_size < keep * self.record_bytes):
            raise InputError(f"{path}: holds fewer than the {keep} keyframes the checkpoint names")
        if readonly:
            fd = os.open(path, os.O_RDONLY)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            os.ftruncate(fd, keep * self.record_bytes)
        self._close()
        self._fd, self._path, self._written = fd, path, keep

    def _ensure_file(self) -> None:
        if self._fd is None:             # no run folder: an anonymous file, gone when closed
            f = tempfile.TemporaryFile()
            self._fd, self._written = os.dup(f.fileno()), 0
            f.close()

    def _write(self, kf: Keyframe) -> None:
        c8, d16 = kf.images8()
        slot = self._written
        os.pwrite(self._fd, c8.tobytes() + d16.tobytes(), slot * self.record_bytes)
        kf._store, kf._slot = self, slot
        self._written += 1

    def read(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.shape
        data = os.pread(self._fd, self.record_bytes, slot * self.record_bytes)
        if len(data) != self.record_bytes:
            raise InputError(f"{self._path or 'keyframe file'}: keyframe record {slot} is truncated")
        c8 = np.frombuffer(data, np.uint8, h * w * 3).reshape(h, w, 3)
        d16 = np.frombuffer(data, np.uint16, h * w, offset=h * w * 3).reshape(h, w)
        return c8, d16

    def _close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def close(self) -> None:
        with self._lock:
            for kf in self.items:        # keyframes read after closing come from memory
                if not kf.resident:
                    kf._images = self.read(kf._slot)
            self._close()

    def _spill(self) -> None:
        """Keep the newest keyframes within memory_mb; older ones are read from the file."""
        budget = self.config.memory_mb * 2**20
        resident = self.resident_bytes()
        for kf in self.items:
            if resident <= budget:
                break
            if kf.resident:
                if kf._slot is None:
                    self._ensure_file()
                    self._write(kf)
                kf._images = None
                resident -= self.record_bytes

    # -------------------------------------------------------------- keyframes
    def add(self, frame_index: int, w2c: np.ndarray, color: np.ndarray, depth: np.ndarray) -> Keyframe:
        kf = Keyframe.from_images(frame_index, w2c, color, depth)
        with self._lock:
            if self._fd is not None and self._path is not None:
                self._write(kf)
            self.items.append(kf)
            self._spill()
        return kf

    def select(self, depth: np.ndarray, w2c: np.ndarray, k: int, rng: np.random.Generator) -> list[Keyframe]:
        """The mapping window besides the current frame: the latest keyframe plus up to k-1
        earlier keyframes that overlap the current view (top-k by overlap, or a random subset of
        the overlapping ones with selection="random" as the original code does)."""
        if not self.items or k <= 0:
            return []
        latest, earlier = self.items[-1], self.items[:-1]
        chosen: list[Keyframe] = []
        if earlier and k > 1:
            scores = overlap_scores(depth, w2c, self.intrinsics, earlier, rng,
                                    self.config.overlap_samples, self.config.overlap_border,
                                    self.config.overlap_within_depth)
            candidates = np.flatnonzero(scores > 0)
            if self.config.selection == "random":
                candidates = rng.permutation(candidates)
            else:
                candidates = candidates[np.argsort(-scores[candidates], kind="stable")]
            chosen = [earlier[i] for i in candidates[: k - 1]]
        return chosen + [latest]

    # -------------------------------------------------------------- checkpoints
    def to_arrays(self) -> dict:
        """Poses and depth steps; the images are in the attached file (kf_count records of it)."""
        with self._lock:
            if self.items and self._path is None:
                raise RuntimeError("a checkpoint needs the keyframe file: attach() it first")
            items = list(self.items)
        return {"kf_index": np.array([kf.frame_index for kf in items], np.int64),
                "kf_w2c": np.array([kf.w2c for kf in items], np.float64).reshape(-1, 4, 4),
                "kf_depth_step": np.array([kf.depth_step for kf in items], np.float64),
                "kf_shape": np.array(self.shape, np.int64)}

    def load_arrays(self, arrays: dict, path=None, readonly: bool = False) -> None:
        """Keyframes of a checkpoint: images from the keyframe file at `path` (kept open for
        appending), or from kf_color / kf_depth arrays of checkpoints made before the file."""
        index = np.asarray(arrays["kf_index"])
        if "kf_color" in arrays:
            self.items = [Keyframe.from_images(int(i), arrays["kf_w2c"][j], arrays["kf_color"][j], arrays["kf_depth"][j])
                          for j, i in enumerate(index)]
            if path is not None:
                self.attach(path)
                for kf in self.items:
                    self._write(kf)
        else:
            if tuple(arrays.get("kf_shape", self.shape)) != self.shape:
                raise InputError(f"{path}: keyframes of size {tuple(arrays['kf_shape'])}, expected {self.shape}")
            if path is None:
                raise InputError("keyframe images are in the checkpoint's keyframes.bin: no path given")
            self.attach(path, keep=len(index), readonly=readonly)
            self.items = [Keyframe(int(i), arrays["kf_w2c"][j], None, None, arrays["kf_depth_step"][j], self, j)
                          for j, i in enumerate(index)]
            budget = self.config.memory_mb * 2**20
            for kf in reversed(self.items):          # the newest back in memory, within the budget
                if self.resident_bytes() + self.record_bytes > budget:
                    break
                kf._images = self.read(kf._slot)
        with self._lock:
            self._spill()


def read_keyframes(keyframe_file, arrays: dict, intrinsics: Intrinsics) -> list[Keyframe]:
    """The keyframes of a finished run's checkpoint (for browsing and refinement), read into memory
    (their images from `keyframe_file`, the run folder's checkpoint/keyframes.bin)."""
    store = KeyframeStore(KeyframeConfig(memory_mb=float("inf")), intrinsics)
    if len(arrays.get("kf_index", ())) == 0:
        return []
    store.load_arrays(arrays, None if "kf_color" in arrays else Path(keyframe_file), readonly=True)
    items = list(store.items)
    store._close()
    return items

