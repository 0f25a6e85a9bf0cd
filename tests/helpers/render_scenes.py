"""Small Gaussian scenes and render helpers the renderer tests share (tiles, culling, anisotropy, gradients)."""

from __future__ import annotations

import numpy as np
import torch

from splat_core.camera import Intrinsics, quat_to_rotmat, w2c_from_quat_trans
from splat_core.gaussians import Gaussians
from splat_core.render import render


INTR = Intrinsics(60.0, 62.0, 31.3, 23.6, 64, 48)   # 4 x 3 tiles of 16 px
NEAR = 0.01
TOL = {torch.float64: 1e-10, torch.float32: 1e-6}
GRAD_TOL = {torch.float64: 1e-10, torch.float32: 2e-6}


def _pose(dtype):
    q = torch.tensor([1.0, 0.03, -0.02, 0.01], dtype=dtype)
    t = torch.tensor([0.05, -0.03, 0.1], dtype=dtype)
    return q, t


def _camera_to_world(p_cam: np.ndarray, dtype) -> np.ndarray:
    q, t = _pose(torch.float64)
    R = quat_to_rotmat(q).numpy()
    return (p_cam - t.numpy()) @ R        # inverse of x_cam = R x_world + t


def _scene(case: str, dtype, seed: int = 0) -> Gaussians:
    """Camera-space layouts mapped to world coordinates for the pose of `_pose`."""
    rng = np.random.default_rng(seed)
    W, H, f = INTR.width, INTR.height, INTR.fx
    pts, px_sigma, opac = [], [], []

    def add(z, u, v, sigma_px, o):
        z, u, v = np.broadcast_arrays(np.asarray(z, float), np.asarray(u, float), np.asarray(v, float))
        pts.append(np.stack([(u - INTR.cx) / INTR.fx * z, (v - INTR.cy) / INTR.fy * z, z], -1).reshape(-1, 3))
        px_sigma.append(np.broadcast_to(np.asarray(sigma_px, float), z.shape).reshape(-1))
        opac.append(np.broadcast_to(np.asarray(o, float), z.shape).reshape(-1))

    if case in ("mixed", "aniso"):
        n = 150
        # Spread past the image edges so Gaussians straddle image and tile borders.
        add(rng.uniform(0.5, 4.0, n), rng.uniform(-8, W + 8, n), rng.uniform(-8, H + 8, n),
            rng.uniform(0.3, 5.0, n), rng.uniform(0.05, 0.95, n))
        add(rng.uniform(1, 3, 12), np.repeat([15.5, 16.0, 31.7, 47.9], 3), rng.uniform(0, H, 12),
            2.0, 0.8)                                                   # on tile borders
        add(rng.uniform(1, 3, 6), rng.uniform(0, W, 6), rng.uniform(0, H, 6), 1.5, 0.9975)  # clamp
        add(-1.0, rng.uniform(0, W, 4), rng.uniform(0, H, 4), 3.0, 0.9)           # behind
        add(NEAR * np.array([0.999, 1.02, 1.1]), [20, 30, 40], [20, 25, 30], 4.0, 0.6)  # near plane
        add(2.0, 30.0, 22.0, 60.0, 0.3)                                 # huge: covers the image
        add(rng.uniform(1, 3, 5), rng.uniform(0, W, 5), rng.uniform(0, H, 5), 1e-4, 0.9)  # tiny
    elif case == "layers":
        # Many opaque layers over the same pixels: transmittance drops below 1e-4 mid-list.
        n = 120
        add(np.linspace(1.0, 3.0, n), rng.uniform(10, 54, n), rng.uniform(8, 40, n),
            rng.uniform(4.0, 9.0, n), rng.uniform(0.5, 0.99, n))
    elif case == "transparent":
        add(rng.uniform(1, 3, 40), rng.uniform(0, W, 40), rng.uniform(0, H, 40), 3.0, 1e-3)
    elif case == "ties":
        # Equal depths: the stable sort must order them by index, like the reference.
        add(np.full(30, 2.0), rng.uniform(0, W, 30), rng.uniform(0, H, 30), 4.0, 0.7)
    else:
        raise ValueError(case)

    p_cam = np.concatenate(pts)
    sigma = np.concatenate(px_sigma) * np.abs(p_cam[:, 2]) / f
    n = len(p_cam)
    logit = np.log(np.concatenate(opac)) - np.log1p(-np.concatenate(opac))
    rot = np.zeros((n, 4))
    rot[:, 0] = 1.0
    log_scales = np.log(sigma)[:, None]
    if case == "aniso":
        rot = rng.normal(size=(n, 4))
        log_scales = log_scales + rng.uniform(-1.0, 0.7, (n, 3))
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    return Gaussians(means=t(_camera_to_world(p_cam, dtype)), colors=t(rng.uniform(0, 1, (n, 3))),
                     rotations=t(rot), logit_opacities=t(logit), log_scales=t(log_scales))


def _leaves(g: Gaussians, dtype):
    params = [x.detach().clone().requires_grad_() for x in
              (g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales)]
    q, t = (x.clone().requires_grad_() for x in _pose(dtype))
    return params, q, t


def _render_with_grads(g: Gaussians, backend: str, dtype, seed: int = 1, background=0.0):
    params, q, t = _leaves(g, dtype)
    out = render(Gaussians(*params), INTR, w2c_from_quat_trans(q, t), backend=backend,
                 near=NEAR, background=background)
    gen = torch.Generator().manual_seed(seed)
    H, W = INTR.height, INTR.width
    rand = lambda *s: torch.randn(*s, generator=gen, dtype=torch.float64).to(dtype)  # noqa: E731
    loss = ((out.color * rand(H, W, 3)).sum() + (out.depth * rand(H, W)).sum()
            + (out.alpha * rand(H, W)).sum())
    inputs = params + [q, t]
    grads = torch.autograd.grad(loss, inputs, allow_unused=True)
    grads = [torch.zeros_like(x) if gr is None else gr for x, gr in zip(inputs, grads)]
    return [o.detach() for o in out], grads


def _assert_close(actual, expected, tol, what):
    actual, expected = actual.detach(), expected.detach()
    scale = max(1.0, float(expected.abs().max())) if expected.numel() else 1.0
    err = float((actual - expected).abs().max()) if expected.numel() else 0.0
    assert torch.isfinite(actual).all(), f"{what}: non-finite values"
    assert err <= tol * scale, f"{what}: max error {err:.3g} > {tol:g} x scale {scale:.3g}"


GRAD_NAMES = ("means", "colors", "rotations", "logit_opacities", "log_scales", "quat", "trans")


def _gradcheck_scene(aniso: bool) -> Gaussians:
    rng = np.random.default_rng(7 if aniso else 5)
    n = 14
    z = rng.uniform(1.0, 3.0, n)
    u = rng.uniform(0, INTR.width, n)
    v = rng.uniform(0, INTR.height, n)
    p_cam = np.stack([(u - INTR.cx) / INTR.fx * z, (v - INTR.cy) / INTR.fy * z, z], -1)
    sig = rng.uniform(2.0, 6.0, n) * z / INTR.fx
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    o = np.concatenate([rng.uniform(0.3, 0.9, n - 2), [0.9975, 0.9975]])
    rot = rng.normal(size=(n, 4)) if aniso else np.tile([1.0, 0, 0, 0], (n, 1))
    ls = np.log(sig)[:, None] + (rng.uniform(-0.6, 0.6, (n, 3)) if aniso else 0)
    return Gaussians(t(_camera_to_world(p_cam, torch.float64)), t(rng.uniform(0, 1, (n, 3))),
                     t(rot), t(np.log(o / (1 - o))), t(ls))
