"""Sparse-pixel rendering (render_pixels, cpu_pixels.py) against the dense render at the same pixels.

Values and gradients (every Gaussian parameter and the pose) of a random loss over the chosen
pixels must equal those of the dense CPU render gathered at those pixels; the float64 sparse
path passes gradcheck on its own.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splat_core.camera import w2c_from_quat_trans
from splat_core.gaussians import Gaussians
from splat_core.render import render, render_pixels
from helpers.render_scenes import GRAD_NAMES, INTR, NEAR, _assert_close, _gradcheck_scene, _leaves, _pose, _scene


def _pixels(seed=0, n=60):
    rng = np.random.default_rng(seed)
    px = np.concatenate([rng.integers(0, INTR.width, n), [0, INTR.width - 1, 15, 16, 31]])
    py = np.concatenate([rng.integers(0, INTR.height, n), [0, INTR.height - 1, 15, 16, 47]])
    return np.stack([px, py], axis=1)


def _loss_and_grads(g, dtype, sparse: bool, pixels):
    params, q, t = _leaves(g, dtype)
    w2c = w2c_from_quat_trans(q, t)
    if sparse:
        out = render_pixels(Gaussians(*params), INTR, w2c, pixels, near=NEAR, background=0.25)
    else:
        full = render(Gaussians(*params), INTR, w2c, backend="cpu", near=NEAR, background=0.25)
        x, y = pixels[:, 0], pixels[:, 1]
        out = (full.color[y, x], full.depth[y, x], full.alpha[y, x])
    gen = torch.Generator().manual_seed(3)
    rand = lambda *s: torch.randn(*s, generator=gen, dtype=torch.float64).to(dtype)  # noqa: E731
    P = len(pixels)
    loss = (out[0] * rand(P, 3)).sum() + (out[1] * rand(P)).sum() + (out[2] * rand(P)).sum()
    inputs = params + [q, t]
    grads = torch.autograd.grad(loss, inputs, allow_unused=True)
    return [o.detach() for o in out], [torch.zeros_like(x) if gr is None else gr for x, gr in zip(inputs, grads)]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("case", ["mixed", "aniso", "layers", "ties"])
def test_sparse_pixels_match_the_dense_render(case, dtype):
    g = _scene(case, dtype)
    pixels = _pixels()
    out_s, grads_s = _loss_and_grads(g, dtype, True, pixels)
    out_d, grads_d = _loss_and_grads(g, dtype, False, pixels)
    tol = 1e-10 if dtype == torch.float64 else 2e-6
    for name, a, b in zip(("color", "depth", "alpha"), out_s, out_d):
        _assert_close(a, b, tol, f"{case} {name}")
    assert float(out_d[2].max()) > 0.5, "the chosen pixels must see the scene"
    for name, a, b in zip(GRAD_NAMES, grads_s, grads_d):
        _assert_close(a, b, tol, f"{case} d/d{name}")
    assert float(grads_d[-1].abs().max()) > 0, "the pose gradient must be exercised"


def _every_pixel():
    ys, xs = np.mgrid[0:INTR.height, 0:INTR.width]
    return np.stack([xs.ravel(), ys.ravel()], axis=1)[::-1].copy()     # every pixel, last first


def _crowded_pixels():
    """Many pixels in one 8 x 8 cell of the pixel index, repeated pixels, and cell corners."""
    block = np.array([[x, y] for y in range(16, 24) for x in range(24, 32)])
    return np.concatenate([block, block[::7], [[23, 15], [32, 24], [24, 16], [24, 16]]])


@pytest.mark.parametrize("which", ["every", "crowded"])
def test_sparse_pixels_match_the_dense_render_on_any_pixel_set(which):
    """The per-pixel lists (built through 8 x 8 cells) hold every Gaussian whose box holds the
    pixel, whatever the pixels: all of them, many in one cell, the same pixel twice."""
    dtype = torch.float64
    g = _scene("layers", dtype)
    pixels = _every_pixel() if which == "every" else _crowded_pixels()
    out_s, grads_s = _loss_and_grads(g, dtype, True, pixels)
    out_d, grads_d = _loss_and_grads(g, dtype, False, pixels)
    for name, a, b in zip(("color", "depth", "alpha"), out_s, out_d):
        _assert_close(a, b, 1e-10, f"{which} {name}")
    assert float(out_d[2].max()) > 0.5
    for name, a, b in zip(GRAD_NAMES, grads_s, grads_d):
        _assert_close(a, b, 1e-10, f"{which} d/d{name}")


def test_sparse_gradcheck_float64():
    g = _gradcheck_scene(False)
    pixels = _pixels(seed=5, n=40)
    q0, t0 = _pose(torch.float64)
    inputs = [x.clone().requires_grad_() for x in (g.means, g.colors, g.logit_opacities, g.log_scales, q0, t0)]

    def fn(means, colors, logit, log_scales, q, t):
        out = render_pixels(Gaussians(means, colors, g.rotations, logit, log_scales), INTR,
                            w2c_from_quat_trans(q, t), pixels, near=NEAR, background=0.1)
        return out.color, out.depth, out.alpha

    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_pixels_outside_the_image_are_refused():
    g = _scene("mixed", torch.float32)
    with pytest.raises(ValueError, match="inside"):
        render_pixels(g, INTR, np.eye(4), np.array([[INTR.width, 0]]))


# ----------------------------------------------------------------------------- tile masks (mapping)

def _tiles_loss_and_grads(g, dtype, backend, tiles):
    """Colour, depth and alpha of a render with `tiles` (None: all), and the gradients of a random
    loss over the chosen tiles' pixels."""
    from splat_core.render import tile_pixels
    params, q, t = _leaves(g, dtype)
    out = render(Gaussians(*params), INTR, w2c_from_quat_trans(q, t), backend=backend, near=NEAR,
                 background=0.25, tiles=tiles)
    keep = torch.as_tensor(tile_pixels(TILES, INTR.width, INTR.height), dtype=dtype)
    gen = torch.Generator().manual_seed(4)
    rand = lambda *s: torch.randn(*s, generator=gen, dtype=torch.float64).to(dtype)  # noqa: E731
    H, W = INTR.height, INTR.width
    loss = (((out.color * rand(H, W, 3)).sum(-1) + out.depth * rand(H, W) + out.alpha * rand(H, W)) * keep).sum()
    inputs = params + [q, t]
    grads = torch.autograd.grad(loss, inputs, allow_unused=True)
    return [o.detach() for o in out], [torch.zeros_like(x) if gr is None else gr for x, gr in zip(inputs, grads)]


TILES = np.array([[1, 0, 0, 1], [0, 1, 1, 0], [1, 0, 1, 0]], dtype=bool)   # INTR is 4 x 3 tiles


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("case", ["mixed", "layers"])
def test_tile_mask_draws_the_chosen_tiles_as_the_full_render_does(case, backend):
    """Chosen tiles equal the full render there (values and the gradient of a loss over them);
    the others come back empty (background, depth 0, alpha 0)."""
    from splat_core.render import tile_pixels
    dtype = torch.float64
    g = _scene(case, dtype)
    out_t, grads_t = _tiles_loss_and_grads(g, dtype, backend, TILES)
    out_f, grads_f = _tiles_loss_and_grads(g, dtype, backend, None)
    keep = torch.as_tensor(tile_pixels(TILES, INTR.width, INTR.height))
    assert 0 < int(keep.sum()) < keep.numel()
    for name, a, b in zip(("color", "depth", "alpha"), out_t, out_f):
        _assert_close(a[keep], b[keep], 1e-10, f"{case} {name} in the chosen tiles")
    assert float(out_f[2][~keep].max()) > 0.5, "the scene must reach the tiles left out"
    assert float(out_t[2][~keep].abs().max()) == 0 and float(out_t[1][~keep].abs().max()) == 0
    assert torch.allclose(out_t[0][~keep], torch.full_like(out_t[0][~keep], 0.25))
    for name, a, b in zip(GRAD_NAMES, grads_t, grads_f):
        _assert_close(a, b, 1e-10, f"{case} d/d{name}")
    assert float(grads_t[-1].abs().max()) > 0


def test_tile_mask_of_the_wrong_shape_is_refused():
    g = _scene("mixed", torch.float32)
    with pytest.raises(ValueError, match="tiles"):
        render(g, INTR, np.eye(4), backend="cpu", tiles=np.ones((2, 2), dtype=bool))
