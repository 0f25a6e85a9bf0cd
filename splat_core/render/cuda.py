"""CUDA backend: gsplat's rasterizer (optional dependency, `pip install .[cuda]`).

gsplat is imported lazily and defensively: on a machine with `nvcc` but a CPU build of torch,
importing it can start a CUDA JIT build that fails, and some versions import `packaging`
without declaring it. Any failure means "not available", never an exception at import time.

Semantic differences from the CPU/reference backends (expected in parity tests): gsplat
projects with the full EWA 2D covariance (an isotropic 3D Gaussian is not exactly circular
off-axis), culls per axis at 3.33 sigma and evaluates pixels outside a Gaussian's box inside the
tiles it touches; the differences sit at alphas between 1/255 and ~0.004.
"""

from __future__ import annotations

import threading

import torch

from ..camera import Intrinsics
from ..device import to_device

_lock = threading.Lock()
_gsplat = None          # the module once imported
_import_error = None    # why it could not be imported (str), once tried


def _load():
    global _gsplat, _import_error
    with _lock:
        if _gsplat is None and _import_error is None:
            try:
                import gsplat  # noqa: F401
                from gsplat import rasterization  # noqa: F401
                _gsplat = gsplat
            except BaseException as exc:  # ImportError, a failed JIT build (RuntimeError, SystemExit...)
                if isinstance(exc, KeyboardInterrupt):
                    raise
                _import_error = f"{type(exc).__name__}: {exc}"
    return _gsplat


def available() -> bool:
    """True when a CUDA device is usable and gsplat imports."""
    try:
        if not torch.cuda.is_available():
            return False
    except Exception:
        return False
    return _load() is not None


def unavailable_reason() -> str | None:
    """Why `available()` is False (None when it is True)."""
    try:
        if not torch.cuda.is_available():
            return "torch.cuda.is_available() is False"
    except Exception as exc:
        return f"torch.cuda check failed: {exc}"
    if _load() is None:
        return f"gsplat not importable ({_import_error})"
    return None


def render_gsplat(g, intr: Intrinsics, w2c: torch.Tensor, near: float = 0.01, eps2d: float = 0.3,
                  screen: list | None = None):
    """Render with gsplat. Returns (color H x W x 3, depth H x W, alpha H x W), no background.

    g: `Gaussians` (means N x 3, colors N x 3, rotations N x 4 wxyz, logit_opacities N,
    log_scales N x 1 | N x 3). depth is gsplat's "D" channel: sum_i z_i a_i T_i, not normalised.
    """
    gs = _load()
    if gs is None:
        raise RuntimeError(f"gsplat backend unavailable: {unavailable_reason()}")
    device, dtype = g.means.device, g.means.dtype
    scales = torch.exp(g.log_scales)
    if scales.shape[-1] == 1:
        scales = scales.expand(-1, 3)
    # gsplat's pixel centres sit at half-integers (pixel (u, v) is evaluated at u + 0.5, v + 0.5);
    # ours sit at integers (camera.py), so shift the principal point by half a pixel. Staged through
    # pinned memory (device.to_device): no host synchronisation per render.
    K = to_device([[intr.fx, 0.0, intr.cx + 0.5], [0.0, intr.fy, intr.cy + 0.5], [0.0, 0.0, 1.0]], dtype, device)
    w2c = w2c.to(device=device, dtype=dtype)
    renders, alphas, _meta = gs.rasterization(
        means=g.means, quats=g.rotations, scales=scales,
        opacities=torch.sigmoid(g.logit_opacities), colors=g.colors,
        viewmats=w2c[None], Ks=K[None], width=intr.width, height=intr.height,
        near_plane=near, eps2d=eps2d, render_mode="RGB+D", packed=False,
    )
    if screen is not None and _meta["means2d"].requires_grad:     # see render(): 1 x N x 2, 1 x N (x 2)
        _meta["means2d"].retain_grad()
        screen.append((_meta["means2d"], _meta["radii"]))
    out = renders[0]                        # H x W x 4 (RGB + accumulated depth)
    return out[..., :3], out[..., 3], alphas[0, ..., 0]
