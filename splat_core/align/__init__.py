"""Direct alignment of a frame to the rendered map: one entry point, two backends.

    align_to_map(gaussians, color, depth, intrinsics, w2c_init, *, backend="auto", levels=3, iterations=10,
                 passes=1, color_weight=1.0, silhouette=0.99, near=0.01, max_distance=0.1,
                 depth_noise=False, live_stride=1, sync=None, exposure=False)
        -> AlignResult(w2c 4 x 4, correspondences, rmse_depth, first_render, first_pyramid)

gaussians   a `Gaussians` (the map's detached tensors: means N x 3, ...); the map is rendered at
            w2c_init (and again at each solved pose for passes > 1), on the Gaussians' device.
color       H x W x 3 in [0, 1] and depth H x W in metres (0 = invalid) at `intrinsics`: numpy
            (the torch backend also takes tensors).
w2c_init    4 x 4 world-to-camera start (numpy).
w2c         4 x 4 float64 numpy: the solved world-to-camera, or w2c_init where the map explains
            too little of the frame (fewer than 50 depth residuals).
correspondences, rmse_depth   the depth residuals of the last iteration at full resolution and
            their point-to-plane RMS (metres; relative to 1 m with depth_noise).
first_render   the map rendered at w2c_init (a `Render`: callers reuse it).
first_pyramid  that render's arrays on each pyramid level (Numba backend, without exposure; else
            None): handed back with the render (`model`), they are not made again.

The solve (numba_backend.py's docstring): point-to-plane depth + grey-level residuals against the
rendered map, Huber weights, Gauss-Newton coarse to fine over `levels` pyramid levels with
`iterations` per level, every live_stride-th live pixel at the finest level, rendered pixels with
silhouette > `silhouette` only, associations farther than `max_distance` dropped. `exposure`: the
rendered grey levels are scaled by `exposure_gain` (live over rendered, on the pixels both have)
before the photometric term, once per render.

Backends (tracking.align.backend): "numba" (numba_backend.py: float64 on the host), "torch"
(torch_backend.py: the same numbers in float64 on the map's device, no host synchronisation
inside the solve; `sync` lets the host stop converged loops early, by default on the CPU),
"auto" = torch for CUDA tensors, else numba.
"""

from __future__ import annotations

import torch

from ..camera import Intrinsics
from ..config_sections import ALIGN_BACKENDS
from .numba_backend import AlignResult
from .numba_backend import align_to_map as align_numba

__all__ = ["ALIGN_BACKENDS", "AlignResult", "align_to_map", "resolve_backend"]


def resolve_backend(backend: str, device) -> str:
    """The backend that runs on `device`: auto is torch on CUDA, else numba."""
    if backend not in ALIGN_BACKENDS:
        raise ValueError(f"unknown alignment backend {backend!r}; expected one of {ALIGN_BACKENDS}")
    if backend == "auto":
        return "torch" if torch.device(device).type == "cuda" else "numba"
    return backend


def align_to_map(gaussians, color, depth, intrinsics: Intrinsics, w2c_init, *, backend: str = "auto",
                 levels: int = 3, iterations: int = 10, passes: int = 1, color_weight: float = 1.0,
                 silhouette: float = 0.99, near: float = 0.01, max_distance: float = 0.1,
                 depth_noise: bool = False, live_stride: int = 1, tolerance: float = 1e-7,
                 sync: bool | None = None, model: tuple | None = None, exposure: bool = False) -> AlignResult:
    """Solve for the w2c of (colour, depth at `intrinsics`) against the map rendered near w2c_init,
    by `backend` (see the module docstring). `sync` concerns the torch backend only (the Numba one
    always stops a converged level early). `model`: (a Render, its w2c[, its pyramid]) to align against
    instead of rendering at w2c_init in the first pass (Numba backend; the torch one renders)."""
    options = dict(levels=levels, iterations=iterations, passes=passes, color_weight=color_weight,
                   silhouette=silhouette, near=near, max_distance=max_distance, depth_noise=depth_noise,
                   live_stride=live_stride, tolerance=tolerance, exposure=exposure)
    if resolve_backend(backend, gaussians.means.device) == "torch":
        from .torch_backend import align_to_map_torch
        return align_to_map_torch(gaussians, color, depth, intrinsics, w2c_init, sync=sync, **options)
    return align_numba(gaussians, color, depth, intrinsics, w2c_init, model=model, **options)
