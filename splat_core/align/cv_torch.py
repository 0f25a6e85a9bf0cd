"""OpenCV's image operations that the direct alignment's pyramid uses, in torch (any device),
with OpenCV's numbers: cv2.resize (INTER_NEAREST, INTER_AREA when shrinking, INTER_LINEAR when
enlarging), cv2.Sobel with ksize 3 and its reflect-101 border, cv2.erode with a 3 x 3 square.
tests/align/test_direct_align_torch.py checks each against OpenCV."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F

@lru_cache(maxsize=64)
def _nearest_index_np(n_in: int, n_out: int) -> np.ndarray:
    """cv2.INTER_NEAREST's source index of each output index (floor(x * in/out), clipped)."""
    ifx = 1.0 / (n_out / n_in)
    return np.minimum(np.floor(np.arange(n_out) * ifx).astype(np.int64), n_in - 1)


@lru_cache(maxsize=64)
def _area_matrix_np(n_in: int, n_out: int) -> np.ndarray:
    """cv2.INTER_AREA (shrinking) along one axis as an n_out x n_in matrix of overlap weights
    (OpenCV's: a plain box mean for an integer ratio, else overlaps stored as float32)."""
    scale = n_in / n_out
    W = np.zeros((n_out, n_in))
    if scale == int(scale):
        k = int(scale)
        for dx in range(n_out):
            W[dx, dx * k:(dx + 1) * k] = 1.0 / k
        return W
    for dx in range(n_out):
        fsx1 = dx * scale
        fsx2 = fsx1 + scale
        cell = min(scale, n_in - fsx1)
        sx1, sx2 = math.ceil(fsx1), math.floor(fsx2)
        sx2 = min(sx2, n_in - 1)
        sx1 = min(sx1, sx2)
        if sx1 - fsx1 > 1e-3:
            W[dx, sx1 - 1] = np.float32((sx1 - fsx1) / cell)
        W[dx, sx1:sx2] = np.float32(1.0 / cell)
        if fsx2 - sx2 > 1e-3:
            W[dx, sx2] = np.float32(min(min(fsx2 - sx2, 1.0), cell) / cell)
    return W


_device_cache: dict = {}


def _on(device: torch.device, key: tuple, make) -> torch.Tensor:
    """A constant tensor made once per device (no host-to-device copy inside the solve)."""
    full = (str(device),) + key
    if full not in _device_cache:
        if len(_device_cache) > 256:
            _device_cache.clear()
        _device_cache[full] = torch.as_tensor(make()).to(device)
    return _device_cache[full]


def resize_nearest(image: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """cv2.resize(..., INTER_NEAREST) of an H x W (x C) tensor."""
    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image
    ys = _on(image.device, ("nn", h, height), lambda: _nearest_index_np(h, height))
    xs = _on(image.device, ("nn", w, width), lambda: _nearest_index_np(w, width))
    return image.index_select(0, ys).index_select(1, xs)


def resize_smooth(image: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """frame.resize_to(..., nearest=False) of an H x W float64 tensor: area averaging when
    shrinking (cv2.INTER_AREA), bilinear when enlarging (cv2.INTER_LINEAR)."""
    h, w = image.shape
    if (h, w) == (height, width):
        return image
    if width < w:       # resize_to decides by the width, as cv2 is called with one mode for both axes
        if height > h:
            raise ValueError("resize_smooth: shrinking one axis while enlarging the other")
        Wy = _on(image.device, ("area", h, height), lambda: _area_matrix_np(h, height)).to(image.dtype)
        Wx = _on(image.device, ("area", w, width), lambda: _area_matrix_np(w, width)).to(image.dtype)
        return Wy @ image @ Wx.T
    return F.interpolate(image[None, None], size=(height, width), mode="bilinear", align_corners=False)[0, 0]


def sobel(image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """cv2.Sobel(image, CV_64F, 1, 0 / 0, 1, ksize=3) with its reflect-101 border."""
    p = F.pad(image[None], (1, 1, 1, 1), mode="reflect")[0]
    gx = (p[:-2, 2:] - p[:-2, :-2]) + 2.0 * (p[1:-1, 2:] - p[1:-1, :-2]) + (p[2:, 2:] - p[2:, :-2])
    gy = (p[2:, :-2] - p[:-2, :-2]) + 2.0 * (p[2:, 1:-1] - p[:-2, 1:-1]) + (p[2:, 2:] - p[:-2, 2:])
    return gx, gy


def erode3(mask: torch.Tensor) -> torch.Tensor:
    """cv2.erode(mask, 3 x 3 ones): a pixel stays where its whole 3 x 3 neighbourhood inside the
    image is set (the border does not erode)."""
    x = mask.to(torch.float32)[None, None]
    return (-F.max_pool2d(-x, 3, stride=1, padding=1))[0, 0] > 0.5
