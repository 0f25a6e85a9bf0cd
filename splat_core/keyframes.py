"""Keyframe store (host memory) and overlap-based selection of the mapping window.

Keyframes keep their colour and depth on the host at the working resolution, so device memory
does not grow with the sequence (a known problem of the original, which keeps them on the GPU).
Poses are frozen at insertion, as in SplaTAM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics, backproject, invert_pose
from .config import KeyframeConfig


@dataclass
class Keyframe:
    frame_index: int          # processed-frame number
    w2c: np.ndarray           # 4 x 4, frozen at insertion
    color: np.ndarray         # H x W x 3 float32
    depth: np.ndarray         # H x W float32 metres


def is_keyframe_time(index: int, total: int | None, every: int) -> bool:
    """Frame 0, every `every`-th frame ((index+1) % every == 0), and the second-to-last frame."""
    return index == 0 or (index + 1) % every == 0 or (total is not None and index == total - 2)


def overlap_scores(depth: np.ndarray, w2c: np.ndarray, intr: Intrinsics, keyframes: list[Keyframe],
                   rng: np.random.Generator, samples: int = 1600, border: int = 20) -> np.ndarray:
    """Fraction of the current frame's sampled depth points that project inside each keyframe.

    Samples `samples` valid pixels (with replacement), back-projects them with the current pose,
    and counts those landing more than `border` pixels inside each keyframe's image in front of it.
    """
    valid = np.flatnonzero(depth.reshape(-1) > 0)
    if valid.size == 0 or not keyframes:
        return np.zeros(len(keyframes))
    pick = rng.choice(valid, size=samples, replace=True)
    pts_cam = backproject(depth, intr).reshape(-1, 3)[pick]
    c2w = invert_pose(w2c)
    pts_world = pts_cam @ c2w[:3, :3].T + c2w[:3, 3]
    scores = np.empty(len(keyframes))
    for k, kf in enumerate(keyframes):
        p = pts_world @ kf.w2c[:3, :3].T + kf.w2c[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = intr.fx * p[:, 0] / z + intr.cx
            v = intr.fy * p[:, 1] / z + intr.cy
        inside = (z > 0) & (u > border) & (u < intr.width - border) & (v > border) & (v < intr.height - border)
        scores[k] = inside.mean()
    return scores


class KeyframeStore:
    def __init__(self, config: KeyframeConfig, intrinsics: Intrinsics):
        self.config = config
        self.intrinsics = intrinsics
        self.items: list[Keyframe] = []

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self):
        return iter(self.items)

    def add(self, frame_index: int, w2c: np.ndarray, color: np.ndarray, depth: np.ndarray) -> Keyframe:
        kf = Keyframe(frame_index, np.array(w2c, dtype=np.float64), np.array(color, dtype=np.float32),
                      np.array(depth, dtype=np.float32))
        self.items.append(kf)
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
                                    self.config.overlap_samples, self.config.overlap_border)
            candidates = np.flatnonzero(scores > 0)
            if self.config.selection == "random":
                candidates = rng.permutation(candidates)
            else:
                candidates = candidates[np.argsort(-scores[candidates], kind="stable")]
            chosen = [earlier[i] for i in candidates[: k - 1]]
        return chosen + [latest]

    # -------------------------------------------------------------- checkpoints
    def to_arrays(self) -> dict:
        if not self.items:
            return {"kf_index": np.zeros(0, np.int64)}
        return {
            "kf_index": np.array([kf.frame_index for kf in self.items], np.int64),
            "kf_w2c": np.stack([kf.w2c for kf in self.items]),
            "kf_color": np.stack([kf.color for kf in self.items]),
            "kf_depth": np.stack([kf.depth for kf in self.items]),
        }

    def load_arrays(self, arrays: dict) -> None:
        self.items = [Keyframe(int(i), arrays["kf_w2c"][j], arrays["kf_color"][j], arrays["kf_depth"][j])
                      for j, i in enumerate(arrays["kf_index"])]
