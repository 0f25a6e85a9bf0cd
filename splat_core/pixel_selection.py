"""Which pixels sparse tracking evaluates: a few per tile, so the loss covers the whole image.

    choose_pixels(rule, color, depth, tile, per_tile, rng) -> P x 2 int (x, y), or None (all pixels)

Rules (tracking.pixels):
    all          every pixel (dense tracking, the paper)
    random       `per_tile` random pixels with valid depth in every `tile` x `tile` block
                 (SPLATONIC's rule: one random pixel per 16 x 16 tile tracks SplaTAM at equal ATE)
    gradient     the `per_tile` pixels with the strongest grey-level gradient in each block
    depth_edges  the `per_tile` pixels with the strongest depth gradient in each block
Only pixels with valid depth are chosen (the tracking loss ignores the others); a block without
any contributes nothing. docs/history/2026-12-01-sparse-pixel-tracking.md has what each rule measured.
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
    score = np.where(depth > 0, _score(rule, color, depth, rng), -np.inf)
    # Blocks as rows of tile * tile scores (padding scores -inf), best first; keep per_tile of each.
    by, bx = -(-H // tile), -(-W // tile)
    padded = np.full((by * tile, bx * tile), -np.inf)
    padded[:H, :W] = score
    blocks = padded.reshape(by, tile, bx, tile).transpose(0, 2, 1, 3).reshape(by * bx, tile * tile)
    if per_tile == 1:   # the first of the best, as the stable sort below picks it, without sorting
        best = np.argmax(blocks, axis=1)[:, None]
    else:
        best = np.argsort(-blocks, axis=1, kind="stable")[:, :per_tile]
    keep = np.isfinite(np.take_along_axis(blocks, best, axis=1))
    block_y, block_x = np.divmod(np.repeat(np.arange(by * bx), best.shape[1]).reshape(best.shape), bx)
    ys = (block_y * tile + best // tile)[keep]
    xs = (block_x * tile + best % tile)[keep]
    chosen = np.sort(ys * W + xs)
    return np.stack([chosen % W, chosen // W], axis=1).astype(np.int64)
