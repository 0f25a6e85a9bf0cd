"""The fused CPU projection of isotropic Gaussians (render/project_cpu.py) against the torch
projection (`project_gaussians_torch`, the definition).

Errors are relative to max(1, largest |expected value|) of each output, as in test_render.py.
Values: float64 within 1e-12, float32 within 1e-5, radii identical in float64. Gradients of a
random linear loss over all four differentiable outputs, to means, log_scales, logit_opacities and
a pose (quaternion + translation, or a 4 x 4 leaf): within 1e-10 in float64; float32 as close to
the float64 truth as torch's float32. Scenes: test_render.py's isotropic ones, points far off-axis
(the Jacobian's clamp active) and points exactly on the clamp limits (torch passes the gradient
there). gradcheck in float64, and a full CPU render with either projection.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics, quat_to_rotmat_np, w2c_from_quat_trans
from splat_core.gaussians import Gaussians
from splat_core.render import project as project_mod
from splat_core.render.project import clamp_limits, project_gaussians, project_gaussians_torch
from helpers.render_scenes import (INTR, NEAR, _camera_to_world, _gradcheck_scene, _pose, _render_with_grads,
                         _scene)

VALUE_TOL = {torch.float64: 1e-12, torch.float32: 1e-5}
OUTPUTS = ("means2d", "conics", "depths", "opacities")
FUSED = "_ProjectIsotropicCPUBackward"


def _offaxis(dtype, seed: int = 3) -> Gaussians:
    """Camera-space points far outside the frustum (x/z, y/z past the clamp limits) and inside it,
    some behind the camera, mapped to world coordinates for the pose of `_pose`."""
    rng = np.random.default_rng(seed)
    W, H = INTR.width, INTR.height
    # 40 far off-axis, 16 in view, 16 past the clamp limits (0.3 W, 0.3 H beyond the image) but
    # large enough to reach into the image, 4 behind the camera, 4 just past the near plane.
    n = 80
    z = np.concatenate([rng.uniform(0.3, 4.0, n - 8), np.full(4, -0.5), np.full(4, NEAR * 1.5)])
    side = rng.choice([-1.0, 1.0], 16)
    u = np.concatenate([rng.uniform(-6 * W, 7 * W, 40), rng.uniform(0, W, 16),
                        np.where(side > 0, W + rng.uniform(0.35, 0.55, 16) * W,
                                 -rng.uniform(0.35, 0.55, 16) * W),
                        rng.uniform(-6 * W, 7 * W, 8)])
    v = np.concatenate([rng.uniform(-6 * H, 7 * H, 40), rng.uniform(0, H, 16),
                        np.where(rng.uniform(size=16) > 0.5, H + rng.uniform(0.35, 0.55, 16) * H,
                                 rng.uniform(0, H, 16)),
                        rng.uniform(-6 * H, 7 * H, 8)])
    p_cam = np.stack([(u - INTR.cx) / INTR.fx * np.abs(z), (v - INTR.cy) / INTR.fy * np.abs(z), z], -1)
    sig = np.concatenate([rng.uniform(0.5, 8.0, 56), rng.uniform(12.0, 25.0, 16),
                          rng.uniform(0.5, 8.0, 8)]) * np.abs(z) / INTR.fx
    o = rng.uniform(0.05, 0.95, n)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    rot = np.tile([1.0, 0, 0, 0], (n, 1))
    return Gaussians(t(_camera_to_world(p_cam, dtype)), t(rng.uniform(0, 1, (n, 3))), t(rot),
                     t(np.log(o / (1 - o))), t(np.log(sig)[:, None]))


def _boundary(dtype) -> Gaussians:
    """For the identity pose: x/z and y/z exactly at the clamp limits (z = 1 in front of the camera,
    z = -1 behind it, where z_safe = 1), just inside and just outside them."""
    lxn, lxp, lyn, lyp = (float(torch.tensor(v, dtype=dtype)) for v in clamp_limits(INTR))
    pts = []
    for z in (1.0, -1.0):
        pts += [(lxp, lyp, z), (-lxn, -lyn, z), (lxp, -lyn, z), (-lxn, lyp, z),
                (0.98 * lxp, 1.02 * lyp, z), (-1.02 * lxn, -0.98 * lyn, z), (0.1, 0.2, z)]
    n = len(pts)
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype)  # noqa: E731
    return Gaussians(t(pts), t(np.full((n, 3), 0.5)), t(np.tile([1.0, 0, 0, 0], (n, 1))),
                     t(np.linspace(-1, 1, n)), t(np.log(np.linspace(0.01, 0.05, n))[:, None]))


def _get_scene(case, dtype):
    if case == "offaxis":
        return _offaxis(dtype)
    if case == "boundary":
        return _boundary(dtype)
    return _scene(case, dtype)


def _get_pose(case, dtype):
    if case == "boundary":
        return torch.tensor([1.0, 0, 0, 0], dtype=dtype), torch.zeros(3, dtype=dtype)
    return _pose(dtype)


CASES = ["mixed", "layers", "ties", "offaxis", "boundary"]


def _rel_err(actual, expected) -> float:
    actual, expected = actual.detach(), expected.detach()
    scale = max(1.0, float(expected.abs().max()))
    return float((actual.double() - expected.double()).abs().max()) / scale


def _project_with_grads(fn, g: Gaussians, q, t, dtype, wrt=("means", "log_scales", "logit", "q", "t"),
                        seed: int = 5, w2c_leaf: bool = False):
    """fn's outputs and the gradients of a random linear loss over all four differentiable
    outputs to the inputs named in `wrt` (None where not asked)."""
    leaves = {"means": g.means.clone(), "log_scales": g.log_scales.clone(),
              "logit": g.logit_opacities.clone(), "q": q.clone(), "t": t.clone()}
    for name in wrt:
        leaves[name].requires_grad_()
    w2c = w2c_from_quat_trans(leaves["q"], leaves["t"])
    if w2c_leaf:
        w2c = w2c.detach().clone().requires_grad_()
    gg = Gaussians(leaves["means"], g.colors, g.rotations, leaves["logit"], leaves["log_scales"])
    p = fn(gg, INTR, w2c, near=NEAR)
    gen = torch.Generator().manual_seed(seed)
    loss = sum((getattr(p, name) * torch.randn(getattr(p, name).shape, generator=gen,
                                               dtype=torch.float64).to(dtype)).sum()
               for name in OUTPUTS)
    inputs = [w2c] if w2c_leaf else [leaves[name] for name in wrt]
    grads = torch.autograd.grad(loss, inputs) if inputs else []
    return p, grads


# ----------------------------------------------------------------------------- dispatch

def test_dispatch():
    g = _scene("mixed", torch.float32)
    w2c = w2c_from_quat_trans(*_pose(torch.float32))
    means = g.means.clone().requires_grad_()
    p = project_gaussians(Gaussians(means, g.colors, g.rotations, g.logit_opacities, g.log_scales),
                          INTR, w2c, near=NEAR)
    assert type(p.means2d.grad_fn).__name__ == FUSED
    assert p.means2d.dtype == torch.float32 and p.radii.dtype == torch.int32
    g64 = _scene("mixed", torch.float64)
    g64 = Gaussians(g64.means.clone().requires_grad_(), g64.colors, g64.rotations, g64.logit_opacities,
                    g64.log_scales)
    p = project_gaussians(g64, INTR, w2c.double(), near=NEAR)
    assert type(p.means2d.grad_fn).__name__ == FUSED and p.conics.dtype == torch.float64
    # Anisotropic Gaussians go through the torch code.
    ga = _scene("aniso", torch.float32)
    ga = Gaussians(ga.means.clone().requires_grad_(), ga.colors, ga.rotations, ga.logit_opacities,
                   ga.log_scales)
    p = project_gaussians(ga, INTR, w2c, near=NEAR)
    assert p.means2d.grad_fn is not None and type(p.means2d.grad_fn).__name__ != FUSED


def test_scenes_exercise_the_branches():
    """Clamp active (both sides, both axes), behind / at the near plane, and visible Gaussians."""
    lxn, lxp, lyn, lyp = clamp_limits(INTR)
    for case in ("offaxis", "mixed"):
        g = _get_scene(case, torch.float64)
        q, t = _get_pose(case, torch.float64)
        w2c = w2c_from_quat_trans(q, t)
        p = g.means @ w2c[:3, :3].T + w2c[:3, 3]
        vis = p[:, 2] > NEAR
        assert int((~vis).sum()) >= 4 and int(vis.sum()) >= 20
        if case == "offaxis":
            rx, ry = p[vis, 0] / p[vis, 2], p[vis, 1] / p[vis, 2]
            assert bool((rx > lxp).any() and (rx < -lxn).any() and (ry > lyp).any() and (ry < -lyn).any())
            assert bool(((rx > -lxn) & (rx < lxp) & (ry > -lyn) & (ry < lyp)).any())
            pr = project_gaussians(g, INTR, w2c, near=NEAR)
            assert int((pr.radii > 0).sum()) >= 20 and int((pr.radii == 0).sum()) >= 20
            clamped = (rx > lxp) | (rx < -lxn) | (ry > lyp) | (ry < -lyn)
            assert int((clamped & (pr.radii[vis] > 0)).sum()) >= 5   # clamped and drawn


# ----------------------------------------------------------------------------- values

@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("case", CASES)
def test_outputs_match_torch(case, dtype):
    g = _get_scene(case, dtype)
    w2c = w2c_from_quat_trans(*_get_pose(case, dtype))
    a = project_gaussians(g, INTR, w2c, near=NEAR)
    b = project_gaussians_torch(g, INTR, w2c, near=NEAR)
    for name in OUTPUTS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == dtype and x.shape == y.shape
        assert torch.isfinite(x).all()
        err = _rel_err(x, y)
        assert err <= VALUE_TOL[dtype], f"{case}/{name}: {err:.3g}"
    assert a.radii.dtype == torch.int32
    if dtype == torch.float64:
        assert torch.equal(a.radii, b.radii)
    else:   # rounding may move a radius across an integer
        diff = (a.radii - b.radii).abs()
        assert int(diff.max()) <= 1 and int((diff > 0).sum()) <= max(1, len(g) // 100)
        assert torch.equal(a.radii > 0, b.radii > 0)


def test_other_near_and_eps2d():
    g = _scene("mixed", torch.float64)
    w2c = w2c_from_quat_trans(*_pose(torch.float64))
    for near, eps2d in ((0.7, 0.3), (0.01, 0.0), (1.5, 2.0)):
        a = project_gaussians(g, INTR, w2c, near=near, eps2d=eps2d)
        b = project_gaussians_torch(g, INTR, w2c, near=near, eps2d=eps2d)
        for name in OUTPUTS:
            assert _rel_err(getattr(a, name), getattr(b, name)) <= 1e-12, name
        assert torch.equal(a.radii, b.radii)


# ----------------------------------------------------------------------------- gradients

@pytest.mark.parametrize("case", CASES)
def test_gradients_match_torch_f64(case):
    dtype = torch.float64
    g = _get_scene(case, dtype)
    q, t = _get_pose(case, dtype)
    pa, ga = _project_with_grads(project_gaussians, g, q, t, dtype)
    pb, gb = _project_with_grads(project_gaussians_torch, g, q, t, dtype)
    assert type(pa.means2d.grad_fn).__name__ == FUSED
    for name, x, y in zip(("means", "log_scales", "logit", "q", "t"), ga, gb):
        assert x.shape == y.shape and x.dtype == dtype
        err = _rel_err(x, y)
        assert err <= 1e-10, f"{case}/grad {name}: {err:.3g}"
        assert float(y.abs().max()) > 0
    # A 4 x 4 w2c leaf: the same gradient (the bottom row gets zeros).
    _, (wa,) = _project_with_grads(project_gaussians, g, q, t, dtype, wrt=(), w2c_leaf=True)
    _, (wb,) = _project_with_grads(project_gaussians_torch, g, q, t, dtype, wrt=(), w2c_leaf=True)
    assert _rel_err(wa, wb) <= 1e-10 and float(wa[3].abs().max()) == 0.0


@pytest.mark.parametrize("wrt", [("q", "t"), ("means",), ("log_scales", "logit")],
                         ids=["pose", "means", "scales_opacities"])
def test_gradients_of_some_inputs(wrt):
    """Only what needs a gradient gets one (tracking: the pose; mapping: the Gaussians)."""
    dtype = torch.float64
    g = _scene("mixed", dtype)
    q, t = _pose(dtype)
    _, ga = _project_with_grads(project_gaussians, g, q, t, dtype, wrt=wrt)
    _, gb = _project_with_grads(project_gaussians_torch, g, q, t, dtype, wrt=wrt)
    for name, x, y in zip(wrt, ga, gb):
        assert _rel_err(x, y) <= 1e-10, name


@pytest.mark.parametrize("case", ["mixed", "offaxis"])
def test_gradients_match_torch_f32(case):
    dtype = torch.float32
    g = _get_scene(case, dtype)
    q, t = _get_pose(case, dtype)
    _, ga = _project_with_grads(project_gaussians, g, q, t, dtype)
    _, gb = _project_with_grads(project_gaussians_torch, g, q, t, dtype)
    _, truth = _project_with_grads(project_gaussians_torch, _get_scene(case, torch.float64),
                                   *_get_pose(case, torch.float64), torch.float64)
    for name, x, y, z in zip(("means", "log_scales", "logit", "q", "t"), ga, gb, truth):
        assert x.dtype == dtype
        # As close to the float64 truth as torch's float32 is (or within 1e-5 of the scale).
        err_fused, err_torch = _rel_err(x, z), _rel_err(y, z)
        assert err_fused <= 2 * err_torch + 1e-5, f"{case}/grad {name}: {err_fused:.3g} vs {err_torch:.3g}"


def test_gradcheck():
    g = _gradcheck_scene(False)
    extra = _offaxis(torch.float64, seed=9)
    pick = [0, 1, 40, 41, 56, 57, 58, 72, 76]   # far off-axis, in view, clamped, behind, near
    means = torch.cat([g.means, extra.means[pick]])
    log_scales = torch.cat([g.log_scales, extra.log_scales[pick]])
    logit = torch.cat([g.logit_opacities, extra.logit_opacities[pick]])
    q0, t0 = _pose(torch.float64)
    n = len(means)
    colors, rot = torch.zeros(n, 3, dtype=torch.float64), torch.zeros(n, 4, dtype=torch.float64)

    def fn(means, log_scales, logit, q, t):
        p = project_gaussians(Gaussians(means, colors, rot, logit, log_scales), INTR,
                              w2c_from_quat_trans(q, t), near=NEAR)
        assert type(p.means2d.grad_fn).__name__ == FUSED
        return p.means2d, p.conics, p.depths, p.opacities

    inputs = [x.clone().requires_grad_() for x in (means, log_scales, logit, q0, t0)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


# ----------------------------------------------------------------------------- full render

@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("case", ["mixed", "layers", "offaxis"])
def test_render_matches_torch_projection(case, dtype, monkeypatch):
    import splat_core.render as render_pkg
    g = _get_scene(case, dtype)
    out_a, grads_a = _render_with_grads(g, "cpu", dtype, background=0.25)
    monkeypatch.setattr(render_pkg, "project_gaussians", project_mod.project_gaussians_torch)
    out_b, grads_b = _render_with_grads(g, "cpu", dtype, background=0.25)
    tol = 1e-10 if dtype == torch.float64 else 2e-5
    for name, x, y in zip(("color", "depth", "alpha"), out_a, out_b):
        assert _rel_err(x, y) <= tol, f"{case}/{name}"
    assert float(out_a[2].max()) > 0.1
    names = ("means", "colors", "rotations", "logit_opacities", "log_scales", "quat", "trans")
    for name, x, y in zip(names, grads_a, grads_b):
        err = _rel_err(x, y)
        assert err <= tol, f"{case}/grad {name}: {err:.3g}"


def test_render_screen_gradient(monkeypatch):
    """Refinement reads means2d.grad (render(..., screen=[])): the fused output keeps it."""
    import splat_core.render as render_pkg
    from splat_core.render import render
    dtype = torch.float64
    g = _scene("mixed", dtype)
    results = []
    for fn in (project_mod.project_gaussians, project_mod.project_gaussians_torch):
        monkeypatch.setattr(render_pkg, "project_gaussians", fn)
        means = g.means.clone().requires_grad_()
        screen = []
        out = render(Gaussians(means, g.colors, g.rotations, g.logit_opacities, g.log_scales), INTR,
                     w2c_from_quat_trans(*_pose(dtype)), backend="cpu", near=NEAR, screen=screen)
        (out.color.sum() + out.depth.sum()).backward()
        (m2d, radii), = screen
        assert m2d.grad is not None
        results.append((m2d.grad.clone(), radii, means.grad.clone()))
    (ga, ra, ma), (gb, rb, mb) = results
    assert torch.equal(ra, rb)
    assert float(ga.abs().max()) > 0
    assert _rel_err(ga, gb) <= 1e-10 and _rel_err(ma, mb) <= 1e-10


def test_no_grad_and_empty():
    g = _scene("ties", torch.float32)
    w2c = w2c_from_quat_trans(*_pose(torch.float32))
    with torch.no_grad():
        p = project_gaussians(Gaussians(g.means.requires_grad_(), g.colors, g.rotations,
                                        g.logit_opacities, g.log_scales), INTR, w2c, near=NEAR)
    assert p.means2d.grad_fn is None and not p.means2d.requires_grad
    e = lambda *s: torch.zeros(*s, dtype=torch.float64)  # noqa: E731
    p = project_gaussians(Gaussians(e(0, 3), e(0, 3), e(0, 4), e(0), e(0, 1)), INTR,
                          torch.eye(4, dtype=torch.float64), near=NEAR)
    assert p.means2d.shape == (0, 2) and p.conics.shape == (0, 3) and p.radii.shape == (0,)


@pytest.mark.parametrize("scales", [1, 3])
def test_frustum_mask_cpu_equals_torch(scales):
    """The Numba frustum test keeps exactly the Gaussians the torch definition keeps: points in
    front, behind, beside the image and large ones reaching in from outside."""
    from splat_core.render.project import frustum_mask_torch
    from splat_core.render.project_cpu import frustum_mask_cpu
    rng = np.random.default_rng(scales)
    n = 20_000
    means = torch.as_tensor(rng.uniform([-6, -5, -3], [6, 5, 8], (n, 3)), dtype=torch.float32)
    log_scales = torch.as_tensor(rng.uniform(-6, 0.5, (n, scales)), dtype=torch.float32)
    intr = Intrinsics(fx=300.0, fy=290.0, cx=160.0, cy=120.0, width=320, height=240)
    w2c = np.eye(4)
    w2c[:3, :3] = quat_to_rotmat_np(rng.normal(size=4))
    w2c[:3, 3] = rng.normal(size=3)
    for margin in (0.0, 0.1):
        ref = frustum_mask_torch(means, log_scales, intr, w2c, 0.01, margin)
        got = frustum_mask_cpu(means, log_scales, intr, w2c, 0.01, margin)
        assert 0.05 * n < int(ref.sum()) < 0.95 * n
        assert torch.equal(got, ref)
