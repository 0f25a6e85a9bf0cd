"""Differentiable Gaussian rendering: one entry point, several backends.

    render(gaussians, intrinsics, w2c, *, background=0.0, backend="auto", near=0.01)
        -> Render(color H x W x 3, depth H x W, alpha H x W)

gaussians   a `Gaussians` (or a GaussianMap, whose live parameters are used): means N x 3,
            colors N x 3, rotations N x 4 (w, x, y, z), logit_opacities N, log_scales N x 1 | N x 3.
w2c         4 x 4 world-to-camera (torch, may require grad: gradients reach the pose), or numpy.
color       sum_i c_i a_i T_i + T_final * background
depth       sum_i z_i a_i T_i: alpha-weighted camera z of the centres, NOT normalised by alpha
alpha       sum_i a_i T_i: the silhouette
with a_i = min(0.99, o_i exp(-0.5 d^T Sigma_i^-1 d)) (2D covariance + 0.3 px), contributions
below 1/255 skipped, compositing stopped before transmittance drops below 1e-4, Gaussians with
camera z <= `near` culled.

Backends: "cpu" (Numba tile rasterizer), "cuda" (gsplat), "reference" (dense torch, tiny scenes),
"auto" = cuda for CUDA tensors when gsplat is installed, else cpu.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from ..camera import Intrinsics
from ..device import to_device
from ..gaussians import PARAM_NAMES, GaussianMap, Gaussians
from ._constants import TILE
from .project import frustum_mask, project_gaussians
from .reference import rasterize_reference

BACKENDS = ("auto", "cpu", "cuda", "reference")


def tile_grid(intrinsics: Intrinsics) -> tuple[int, int]:
    """(rows, columns) of TILE x TILE tiles covering the image."""
    return -(-intrinsics.height // TILE), -(-intrinsics.width // TILE)


def tile_pixels(tiles: np.ndarray, width: int, height: int) -> np.ndarray:
    """H x W boolean mask of the pixels in the chosen tiles."""
    return np.repeat(np.repeat(np.asarray(tiles, dtype=bool), TILE, 0), TILE, 1)[:height, :width]


class Render(NamedTuple):
    color: torch.Tensor  # H x W x 3
    depth: torch.Tensor  # H x W
    alpha: torch.Tensor  # H x W


def gsplat_available() -> bool:
    from . import cuda
    return cuda.available()


def resolve_backend(backend: str, device: torch.device) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"unknown render backend {backend!r}; expected one of {BACKENDS}")
    if backend == "auto":
        return "cuda" if device.type == "cuda" and gsplat_available() else "cpu"
    return backend


def render(gaussians, intrinsics: Intrinsics, w2c, *, background=0.0, backend: str = "auto",
           near: float = 0.01, eps2d: float = 0.3, screen: list | None = None,
           tiles: np.ndarray | None = None) -> Render:
    """`screen`: when a list is given, (means2d, radii) are appended to it: the screen-space centres
    in pixels (their `.grad` is kept by backward; gsplat's are 1 x N x 2) and footprint radii (0 =
    not drawn). Refinement's densification (3DGS) reads the view-space positional gradient there.

    `tiles`: a boolean grid (tile_grid(intrinsics)) of the TILE x TILE pixel tiles to draw; the
    others come back empty (background, depth 0, alpha 0). The CPU backend skips their work;
    the other backends render the whole image and blank them (same result)."""
    g = gaussians.tensors() if isinstance(gaussians, GaussianMap) else gaussians
    dtype, device = g.means.dtype, g.means.device
    if not torch.is_tensor(w2c):
        w2c = to_device(w2c, dtype, device)
    bg = to_device(background, dtype, device).reshape(-1)
    H, W = intrinsics.height, intrinsics.width

    which = resolve_backend(backend, device)
    if which == "cuda":
        from .cuda import render_gsplat
        color, depth, alpha = render_gsplat(g, intrinsics, w2c, near=near, eps2d=eps2d, screen=screen)
    else:
        if len(g) == 0:
            z = torch.zeros(H, W, dtype=dtype, device=device)
            return Render(z[..., None].expand(H, W, 3) + bg, z, z)
        p = project_gaussians(g, intrinsics, w2c, near=near, eps2d=eps2d)
        if screen is not None and p.means2d.requires_grad:
            p.means2d.retain_grad()
            screen.append((p.means2d, p.radii))
        features = torch.cat([g.colors, p.depths[:, None]], dim=1)
        if which == "cpu":
            from .cpu import rasterize_cpu
            image, alpha = rasterize_cpu(p.means2d, p.conics, p.opacities, features, p.depths.detach(),
                                         p.radii, W, H, tiles)
        else:
            image, alpha = rasterize_reference(p.means2d, p.conics, p.opacities, features, p.depths.detach(),
                                               p.radii, W, H)
        color, depth = image[..., :3], image[..., 3]
    if tiles is not None and which != "cpu":     # the CPU rasterizer left the other tiles empty itself
        keep = to_device(tile_pixels(tiles, W, H), dtype, device)
        color, depth, alpha = color * keep[..., None], depth * keep, alpha * keep
    color = color + (1.0 - alpha)[..., None] * bg
    return Render(color, depth, alpha)


def render_pixels(gaussians, intrinsics: Intrinsics, w2c, pixels, *, background=0.0, backend: str = "auto",
                  near: float = 0.01, eps2d: float = 0.3) -> Render:
    """`render` at chosen pixels only: pixels P x 2 integer (x, y) -> Render(color P x 3, depth P, alpha P).

    The CPU backend composites just those pixels (`cpu_pixels.py`); gradients reach every
    Gaussian parameter and the pose as with `render`. Other backends render the image and gather
    (gsplat has no sparse-pixel entry point; its pose gradient is exact either way)."""
    pixels = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    g = gaussians.tensors() if isinstance(gaussians, GaussianMap) else gaussians
    dtype, device = g.means.dtype, g.means.device
    which = resolve_backend(backend, device)
    if which != "cpu" or len(g) == 0:
        out = render(g, intrinsics, w2c, background=background, backend=which, near=near, eps2d=eps2d)
        flat = to_device(pixels[:, 1] * intrinsics.width + pixels[:, 0], torch.int64, device)
        return Render(out.color.reshape(-1, 3)[flat], out.depth.reshape(-1)[flat], out.alpha.reshape(-1)[flat])
    if not torch.is_tensor(w2c):
        w2c = torch.as_tensor(np.asarray(w2c), dtype=dtype, device=device)
    from .cpu_pixels import rasterize_cpu_pixels
    p = project_gaussians(g, intrinsics, w2c, near=near, eps2d=eps2d)
    features = torch.cat([g.colors, p.depths[:, None]], dim=1)
    values, alpha = rasterize_cpu_pixels(p.means2d, p.conics, p.opacities, features, p.depths.detach(), p.radii,
                                         intrinsics.width, intrinsics.height, pixels[:, 0], pixels[:, 1])
    bg = torch.as_tensor(background, dtype=dtype, device=device).reshape(-1)
    return Render(values[:, :3] + (1.0 - alpha)[:, None] * bg, values[:, 3], alpha)


@dataclass(frozen=True)
class Renderer:
    """`render` and `render_pixels` with a run's near plane and backend bound once
    (config.near_plane): the engine, the worker's live view, the viewer's novel views and
    `splatam render` all draw the map through one of these."""

    near: float = 0.01
    backend: str = "auto"

    def render(self, gaussians, intrinsics: Intrinsics, w2c, *, background=0.0, screen: list | None = None,
               tiles: np.ndarray | None = None) -> Render:
        return render(gaussians, intrinsics, w2c, background=background, backend=self.backend, near=self.near,
                      screen=screen, tiles=tiles)

    def pixels(self, gaussians, intrinsics: Intrinsics, w2c, pixels, *, background=0.0) -> Render:
        return render_pixels(gaussians, intrinsics, w2c, pixels, background=background, backend=self.backend,
                             near=self.near)

    def visible(self, gaussians, intrinsics: Intrinsics, w2c, margin: float = 0.0) -> Gaussians:
        """The Gaussians whose footprint may reach the image at w2c (`margin`: a fraction of the
        image added on each side). Rendering those gives the same image as rendering all of them,
        so a render that needs no gradient to the whole map costs what is in view, not the map."""
        g = gaussians.tensors(detach=True) if isinstance(gaussians, GaussianMap) else gaussians
        w2c = w2c.detach().cpu().numpy() if torch.is_tensor(w2c) else np.asarray(w2c)
        keep = frustum_mask(g.means, g.log_scales, intrinsics, w2c, self.near, margin=margin)
        return Gaussians(*(getattr(g, name)[keep] for name in PARAM_NAMES))

    def render_visible(self, gaussians, intrinsics: Intrinsics, w2c, *, background=0.0) -> Render:
        """`render` of what is in view (no gradient to the map: for previews, densification, evaluation)."""
        return self.render(self.visible(gaussians, intrinsics, w2c), intrinsics, w2c, background=background)
