"""Mapping: optimise the Gaussians over a window of keyframes, and prune.

Each iteration renders one randomly chosen view of the window (current frame, latest keyframe,
overlapping keyframes) at its frozen pose and minimises
    L = w_d mean_valid |D - D_hat| + w_c ((1 - w_s) mean |C - C_hat| + w_s (1 - SSIM(C_hat, C)))
with Adam (per-parameter learning rates, eps 1e-15, fresh every frame). Low-opacity and
oversized Gaussians are pruned at iterations 0, 20, ... up to `prune_until`.

With mapping.tile_fraction < 1 an iteration draws and compares only that fraction of the
image's 16 x 16 tiles, chosen at random (the CPU rasterizer skips the others' work), but at
least mapping.min_tiles of them: a small image (80 x 60 has 20 tiles) maps on every tile, as
half of so few leaves large parts of the view out of each step, for little saving.

With mapping.exposure the loss compares each view with the render under that view's own affine
colour change, c -> g c + b per channel, fitted at every iteration by least squares against the
view over the pixels the map covers (`exposure_fit`; the map's colours held, the fit pulled
towards identity by mapping.exposure_prior), so a frame's auto-exposure does not pull the
Gaussians' colours: they keep one exposure, near the views' average. The fit is a function of the
render and the view, so no state is kept per frame; the gradient to the map goes through g.

Only Gaussians near the window's view frusta are optimised: the others receive exactly zero
gradient, and a freshly created Adam moves nothing with zero gradients, so the result equals
optimising the whole map while the cost follows the visible part only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .camera import Intrinsics
from .config import MappingConfig
from .device import to_device
from .gaussians import PARAM_NAMES, GaussianMap
from .losses import ssim
from .render import Renderer, tile_grid, tile_pixels
from .render.project import frustum_mask


@dataclass
class View:
    """One observation in the mapping window: images as torch tensors on the map's device."""

    color: torch.Tensor   # H x W x 3
    depth: torch.Tensor   # H x W
    w2c: np.ndarray       # 4 x 4 (fixed during mapping)


def mapping_loss(rendered, view: View, config: MappingConfig, pixels: torch.Tensor | None = None):
    """The loss above; `pixels` (H x W bool): over those pixels only (the tiles an iteration drew).
    SSIM then compares the drawn pixels set into the observed image (the rest match exactly, so
    they add nothing but their window's overlap with drawn pixels), scaled by H W / drawn pixels.

    CPU tensors of one float dtype run `mapping_loss_cpu` (same value and gradient, one autograd
    step instead of a dozen); anything else the torch definition below."""
    tensors = (rendered.color, rendered.depth, view.color, view.depth)
    if (all(t.device.type == "cpu" and t.dtype == rendered.color.dtype for t in tensors)
            and rendered.color.dtype in (torch.float32, torch.float64)
            and not (view.color.requires_grad or view.depth.requires_grad)):
        from .losses.mapping_loss_cpu import mapping_loss_cpu
        return mapping_loss_cpu(*tensors, None if pixels is None else pixels.cpu(), config.depth_weight,
                                config.color_weight, config.ssim_weight)
    return _mapping_loss_torch(rendered, view, config, pixels)


def _mapping_loss_torch(rendered, view: View, config: MappingConfig, pixels: torch.Tensor | None = None):
    """`mapping_loss` in torch (the definition; CUDA, and the CPU path's reference in tests)."""
    valid = view.depth > 0
    if pixels is not None:
        valid = valid & pixels
    valid = valid.to(view.depth.dtype)
    depth_l1 = (torch.abs(view.depth - rendered.depth) * valid).sum() / valid.sum().clamp(min=1)
    if pixels is None:
        color_l1 = torch.abs(view.color - rendered.color).mean()
        dissimilarity = 1 - ssim(rendered.color, view.color)
    else:
        drawn = pixels.sum().clamp(min=1)
        color_l1 = (torch.abs(view.color - rendered.color) * pixels[..., None]).sum() / (3 * drawn)
        mixed = torch.where(pixels[..., None], rendered.color, view.color)
        dissimilarity = (1 - ssim(mixed, view.color)) * (pixels.numel() / drawn)
    color = (1 - config.ssim_weight) * color_l1 + config.ssim_weight * dissimilarity
    return config.depth_weight * depth_l1 + config.color_weight * color


def exposure_fit(rendered: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor | None,
                 prior: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Per channel gain g and offset b (3 each) minimising
        sum_mask (g r + b - o)^2 + prior * n ((g - 1)^2 + b^2)
    over the n pixels of `mask` (H x W bool; None: all), r the rendered colour (taken as a
    constant), o the observed one. Identity when the render equals the view or nothing is masked."""
    r = rendered.detach().reshape(-1, 3)
    o = observed.detach().reshape(-1, 3).to(r.dtype)
    if mask is not None:
        w = mask.reshape(-1, 1).to(r.dtype)
        r, o = r * w, o * w
        n = w.sum()
    else:
        n = torch.tensor(float(r.shape[0]), dtype=r.dtype, device=r.device)
    lam = prior * n
    srr, sr, sro, so = (r * r).sum(0), r.sum(0), (r * o).sum(0), o.sum(0)
    a, c, d = srr + lam, sr, n + lam                       # [[a, c], [c, d]] [g, b] = [sro + lam, so]
    det = (a * d - c * c).clamp(min=torch.finfo(r.dtype).tiny)
    gain = (d * (sro + lam) - c * so) / det
    offset = (a * so - c * (sro + lam)) / det
    if float(n) == 0:
        return torch.ones_like(gain), torch.zeros_like(offset)
    return gain, offset


def draw_tiles(intr: Intrinsics, fraction: float, rng: np.random.Generator, min_tiles: int = 0):
    """A random fraction of the image's tiles, but at least min_tiles of them (tiles grid, H x W
    pixel mask), or (None, None) for all."""
    rows, cols = tile_grid(intr)
    count = max(1, round(fraction * rows * cols), min_tiles)
    if count >= rows * cols:
        return None, None
    tiles = np.zeros(rows * cols, dtype=bool)
    tiles[rng.choice(rows * cols, size=count, replace=False)] = True
    tiles = tiles.reshape(rows, cols)
    return tiles, torch.from_numpy(tile_pixels(tiles, intr.width, intr.height))


def prune_mask(m: GaussianMap, config: MappingConfig, scene_radius: float) -> torch.Tensor:
    """True for Gaussians to keep: not nearly transparent and not larger than a fraction of the scene."""
    with torch.no_grad():
        transparent = m.opacities() < config.prune_opacity
        huge = torch.exp(m.log_scales).amax(dim=1) > config.prune_big_ratio * scene_radius
    return ~(transparent | huge)


def optimise_map(m: GaussianMap, window: list[View], intr: Intrinsics, config: MappingConfig,
                 iterations: int, scene_radius: float, rng: np.random.Generator,
                 renderer: Renderer = Renderer(), stop=None) -> dict:
    """Run `iterations` mapping steps on `m` in place; returns counts and the last loss.

    Iteration 0's pruning is the caller's (SplaTAM.prune); this prunes every prune_every steps.
    `stop(done)`, asked after each iteration with the number done: True ends the step there."""
    near = renderer.near
    removed = 0
    if iterations == 0 or len(m) == 0 or not window:
        return {"pruned": removed, "loss": None, "optimised": 0}

    if config.visible_only:
        seen = torch.zeros(len(m), dtype=torch.bool, device=m.device)
        for view in window:
            seen |= frustum_mask(m.means.detach(), m.log_scales.detach(), intr, view.w2c, near)
        index = torch.nonzero(seen).flatten()
    else:
        index = torch.arange(len(m), device=m.device)
    if index.numel() == 0:        # nothing of the map is in view (e.g. after a tracking failure)
        return {"pruned": removed, "loss": None, "optimised": 0}
    optimised = index.clone()
    sub = GaussianMap(*(m.params[n].detach()[index] for n in PARAM_NAMES), m.birth_frame[index.cpu()])
    optimizer = sub.adam(config.lrs)

    # The window's poses go to the device once, not once per iteration (to_device: no host sync).
    w2cs = [to_device(view.w2c, sub.means.dtype, sub.device) for view in window]
    last_loss = None
    for i in range(iterations):
        k = int(rng.integers(len(window)))
        view = window[k]
        tiles, pixels = draw_tiles(intr, config.tile_fraction, rng, config.min_tiles)
        out = renderer.render(sub, intr, w2cs[k], tiles=tiles)
        if config.exposure:
            covered = out.alpha.detach().reshape(view.depth.shape) > 0.5
            if pixels is not None:
                covered = covered & to_device(pixels, torch.bool, covered.device)
            gain, offset = exposure_fit(out.color, view.color, covered, config.exposure_prior)
            out = out._replace(color=out.color * gain + offset)
        loss = mapping_loss(out, view, config, None if pixels is None else to_device(pixels, torch.bool, view.depth.device))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        last_loss = loss.detach()       # read once after the loop: no host sync per iteration
        # Pruning after the step (the original prunes before it and so drops that step's update).
        if 0 < i + 1 <= config.prune_until and (i + 1) % config.prune_every == 0:
            keep = prune_mask(sub, config, scene_radius)
            removed += sub.prune(keep, optimizer)
            index = index[keep]
        if stop is not None and stop(i + 1):
            break

    # Write the optimised subset back; Gaussians pruned from the subset leave the map.
    with torch.no_grad():
        keep_all = torch.ones(len(m), dtype=torch.bool, device=m.device)
        keep_all[optimised] = False
        keep_all[index] = True
        for name in PARAM_NAMES:
            m.params[name].data[index] = sub.params[name].detach()
    m.prune(keep_all)
    return {"pruned": removed, "loss": None if last_loss is None else float(last_loss),
            "optimised": int(optimised.numel())}
