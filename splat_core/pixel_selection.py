"""Which pixels sparse tracking evaluates: a few per tile, so the loss covers the whole image.

    choose_pixels(rule, color, depth, tile, per_tile, rng) -> P x 2 int (x, y), or None (all pixels)

Rules (tracking.pixels):
    all          every pixel (dense tracking, the paper)
    random       `per_tile` random pixels with valid depth in every `tile` x `tile` block
                 (SPLATONIC's rule: one random pixel per 16 x 16 tile tracks SplaTAM at equal ATE)
    gradient     the `per_tile` pixels with the strongest grey-level gradient in each block
    depth_edges  the `per_tile` pixels with the strongest depth gradient in each block
Only pixels with valid depth are chosen (the tracking loss ignores the others); a block without
any contributes nothing. README "Accuracy and speed" has what each rule measured.
"""

from __future__ import annotations

import cv2
import numpy as np

RULES = ("all", "random", "gradient", "depth_edges")


def _score(rule: str, color: np.ndarray, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    if rule == "random":
        return rng.random(depth.shape)
    if rule == "gradient":
        image = (color @ np.array([0.299, 0.587, 0.114], dtype=np.float32)).astype(np.float32)
    else:
        image = depth.astype(np.float32)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)
    # A tiny random term breaks ties (flat regions) without favouring a corner of the block.
    return np.hypot(gx, gy) + 1e-6 * rng.random(depth.shape)


def choose_pixels(rule: str, color: np.ndarray, depth: np.ndarray, tile: int, per_tile: int,
                  rng: np.random.Generator) -> np.ndarray | None:
    if rule == "all":
        return None
    if rule not in RULES:
        raise ValueError(f"unknown pixel rule {rule!r}; expected one of {RULES}")
    H, W = depth.shape
    score = _score(rule, color, depth, rng).ravel()
    ys, xs = np.divmod(np.arange(H * W), W)
    block = (ys // tile) * ((W + tile - 1) // tile) + xs // tile
    valid = depth.ravel() > 0
    idx = np.flatnonzero(valid)
    # Sort by block, best score first; keep the first per_tile of every block.
    order = idx[np.lexsort((-score[idx], block[idx]))]
    b = block[order]
    first = np.r_[0, np.flatnonzero(b[1:] != b[:-1]) + 1]
    rank = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
    chosen = np.sort(order[rank < per_tile])
    return np.stack([xs[chosen], ys[chosen]], axis=1).astype(np.int64)
