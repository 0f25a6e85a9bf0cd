"""Small image helpers for the panels and the render command: uint8 conversion, depth and
silhouette colouring, labelled mosaics, PSNR."""

from __future__ import annotations

import numpy as np


def to_uint8(color: np.ndarray) -> np.ndarray:
    return (np.clip(np.asarray(color, np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def depth_max_of(*depths, fallback: float = 3.0) -> float:
    """A colouring range: the 99th percentile of the valid depths of the given images."""
    valid = [np.asarray(d)[np.asarray(d) > 0] for d in depths if d is not None]
    valid = [v for v in valid if v.size]
    if not valid:
        return fallback
    return float(max(np.percentile(np.concatenate(valid), 99), 1e-3))


def colorize_depth(depth: np.ndarray, depth_max: float | None = None) -> np.ndarray:
    """H x W metres -> H x W x 3 uint8 (turbo colormap, near = blue, far = red; invalid = black)."""
    import cv2

    d = np.asarray(depth, np.float32)
    dmax = depth_max if depth_max else depth_max_of(d)
    scaled = np.clip(d / dmax * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[..., ::-1].copy()
    rgb[d <= 0] = 0
    return rgb


def colorize_silhouette(alpha: np.ndarray) -> np.ndarray:
    return np.repeat(to_uint8(np.asarray(alpha, np.float32))[..., None], 3, axis=2)


def labelled(img: np.ndarray, text: str) -> np.ndarray:
    """Write a small label in the top-left corner (black outline, white text)."""
    import cv2

    out = np.ascontiguousarray(img).copy()
    scale = max(0.3, out.shape[0] / 400.0)
    for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(out, text, (4, int(14 * scale / 0.4)), cv2.FONT_HERSHEY_SIMPLEX, scale, colour,
                    width, cv2.LINE_AA)
    return out


def mosaic(rows: list[list[tuple[np.ndarray | None, str]]], tile_width: int = 240) -> np.ndarray:
    """Tiles (uint8 image or None, label) arranged in rows, each tile resized to `tile_width`."""
    import cv2

    first = next(img for row in rows for img, _ in row if img is not None)
    tile_h = max(1, int(round(first.shape[0] * tile_width / first.shape[1])))
    out_rows = []
    ncols = max(len(r) for r in rows)
    for row in rows:
        tiles = []
        for img, label in row + [(None, "")] * (ncols - len(row)):
            if img is None:
                tile = np.full((tile_h, tile_width, 3), 40, np.uint8)
            else:
                tile = cv2.resize(img, (tile_width, tile_h), interpolation=cv2.INTER_AREA)
            tiles.append(labelled(tile, label) if label else tile)
        out_rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(out_rows, axis=0)
