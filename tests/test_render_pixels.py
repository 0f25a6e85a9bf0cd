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
from test_render import GRAD_NAMES, INTR, NEAR, _assert_close, _gradcheck_scene, _leaves, _pose, _scene


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
