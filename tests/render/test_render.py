"""The CPU (Numba) and CUDA (gsplat) renderers against the dense torch oracle (reference.py).

Tolerances, relative to the scale of the compared quantity (max |reference|, at least 1):
float64 agrees to 1e-10 for images and for gradients of a random scalar loss w.r.t. every
Gaussian parameter and the pose; float32 to 1e-6 for images and 2e-6 for gradients. A float32
gradient sums hundreds of per-pixel terms and the reference (a matmul) sums them in another order:
each float32 result is itself ~1e-5 from the float64 truth, so `test_float32_accuracy` also checks
that the CPU backend is as close to that truth as the float32 reference is.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics, w2c_from_quat_trans
from splat_core.gaussians import GaussianMap, Gaussians
from splat_core.render import render
from splat_core.render import cpu as cpu_backend
from splat_core.render.cpu import count_intersections, rasterize_cpu
from splat_core.render.project import project_gaussians
from splat_core.render.reference import rasterize_reference
from helpers.render_scenes import (GRAD_NAMES, GRAD_TOL, INTR, NEAR, TOL, _assert_close, _gradcheck_scene, _leaves, _pose, _render_with_grads, _scene)



# ----------------------------------------------------------------------------- scenes















# ----------------------------------------------------------------------------- cpu == reference

@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("case", ["mixed", "aniso", "layers", "transparent", "ties"])
def test_cpu_matches_reference(case, dtype):
    g = _scene(case, dtype)
    out_c, grads_c = _render_with_grads(g, "cpu", dtype, background=0.25)
    out_r, grads_r = _render_with_grads(g, "reference", dtype, background=0.25)
    for name, a, b in zip(("color", "depth", "alpha"), out_c, out_r):
        _assert_close(a, b, TOL[dtype], f"{case}/{name}")
    for name, a, b in zip(GRAD_NAMES, grads_c, grads_r):
        _assert_close(a, b, GRAD_TOL[dtype], f"{case}/grad {name}")
    if case == "transparent":
        assert float(out_c[2].abs().max()) == 0.0
    else:
        assert float(out_c[2].max()) > 0.5       # the scene is actually visible


@pytest.mark.parametrize("case", ["mixed", "aniso", "layers"])
def test_float32_accuracy(case):
    """float32 CPU results are as close to the float64 truth as the float32 reference is."""
    truth_out, truth_grads = _render_with_grads(_scene(case, torch.float64), "reference", torch.float64)
    g32 = _scene(case, torch.float32)
    cpu_out, cpu_grads = _render_with_grads(g32, "cpu", torch.float32)
    ref_out, ref_grads = _render_with_grads(g32, "reference", torch.float32)
    names = ("color", "depth", "alpha") + GRAD_NAMES
    for name, c, r, t in zip(names, cpu_out + cpu_grads, ref_out + ref_grads, truth_out + truth_grads):
        scale = max(1.0, float(t.abs().max()))
        err_cpu = float((c.double() - t).abs().max()) / scale
        err_ref = float((r.double() - t).abs().max()) / scale
        assert err_cpu <= 2 * err_ref + 1e-6, f"{case}/{name}: {err_cpu:.3g} vs reference {err_ref:.3g}"


def test_scene_features_exercised():
    """The scenes above do hit what they claim: clamp, transmittance stop, culling, borders."""
    g = _scene("layers", torch.float64)
    p = project_gaussians(g, INTR, w2c_from_quat_trans(*_pose(torch.float64)), near=NEAR)
    feats = torch.cat([g.colors, p.depths[:, None]], 1)
    image, alpha = rasterize_cpu(p.means2d, p.conics, p.opacities, feats, p.depths, p.radii,
                                 INTR.width, INTR.height)
    assert float(alpha.max()) > 1 - 1e-3                        # saturated pixels
    b = cpu_backend._forward(p.means2d, p.conics, p.opacities, feats, p.depths, p.radii,
                             INTR.width, INTR.height)[2]
    # The stop: some pixel's last contributor is before the end of its tile list.
    assert (b.tile_last < np.diff(b.tile_offsets)).any()

    g = _scene("mixed", torch.float64)
    p = project_gaussians(g, INTR, w2c_from_quat_trans(*_pose(torch.float64)), near=NEAR)
    assert int((p.radii == 0).sum()) >= 5                      # behind / before the near plane
    assert int(p.radii.max()) > max(INTR.width, INTR.height)   # the huge one
    assert float(p.opacities.max()) > 0.99                     # alpha clamp at 0.99 reached
    m = p.means2d[p.radii > 0]
    assert bool(((m[:, 0] < 0) | (m[:, 0] > INTR.width - 1)).any())   # straddling image borders


def test_exactly_at_near_plane_is_culled():
    z = torch.tensor([NEAR, NEAR * 1.5], dtype=torch.float64)
    means = torch.stack([torch.zeros(2, dtype=torch.float64), torch.zeros(2, dtype=torch.float64), z], 1)
    g = Gaussians(means, torch.ones(2, 3, dtype=torch.float64),
                  torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64),
                  torch.zeros(2, dtype=torch.float64), torch.log(z * 0.05)[:, None])
    p = project_gaussians(g, INTR, torch.eye(4, dtype=torch.float64), near=NEAR)
    assert p.radii.tolist()[0] == 0 and p.radii.tolist()[1] > 0
    a = render(g, INTR, torch.eye(4, dtype=torch.float64), backend="cpu", near=NEAR)
    b = render(g, INTR, torch.eye(4, dtype=torch.float64), backend="reference", near=NEAR)
    for x, y in zip(a, b):
        _assert_close(x, y, 1e-10, "near plane")


@pytest.mark.parametrize("nch", [1, 3, 7])
def test_cpu_any_feature_count(nch):
    """Features are composited 4 channels at a time; other counts are padded / split."""
    torch.manual_seed(3)
    n, W, H = 60, 40, 30
    means2d = (torch.rand(n, 2, dtype=torch.float64) * torch.tensor([W, H])).requires_grad_()
    s = torch.rand(n, dtype=torch.float64) * 3 + 0.7
    conics = torch.stack([1 / s**2, 0.1 / s**2, 1.2 / s**2], 1).requires_grad_()
    opac = (torch.rand(n, dtype=torch.float64) * 0.9 + 0.05).requires_grad_()
    feats = torch.rand(n, nch, dtype=torch.float64).requires_grad_()
    depths = torch.rand(n, dtype=torch.float64)
    radii = torch.full((n,), 15, dtype=torch.int32)
    leaves = [means2d, conics, opac, feats]
    out_c = rasterize_cpu(means2d, conics, opac, feats, depths, radii, W, H)
    out_r = rasterize_reference(means2d, conics, opac, feats, depths, radii, W, H)
    gi, ga = torch.randn(H, W, nch, dtype=torch.float64), torch.randn(H, W, dtype=torch.float64)
    gc = torch.autograd.grad((out_c[0] * gi).sum() + (out_c[1] * ga).sum(), leaves)
    gr = torch.autograd.grad((out_r[0] * gi).sum() + (out_r[1] * ga).sum(), leaves)
    for a, b in zip(out_c, out_r):
        _assert_close(a, b, 1e-10, f"C={nch} image")
    for a, b in zip(gc, gr):
        _assert_close(a, b, 1e-10, f"C={nch} grad")


def test_empty_and_all_culled():
    e = lambda *s: torch.zeros(*s, dtype=torch.float32)  # noqa: E731
    g = Gaussians(e(0, 3), e(0, 3), e(0, 4), e(0), e(0, 1))
    out = render(g, INTR, torch.eye(4), backend="cpu", background=0.5)
    assert out.color.shape == (INTR.height, INTR.width, 3)
    assert float(out.alpha.abs().max()) == 0.0 and float((out.color - 0.5).abs().max()) == 0.0

    # Every Gaussian culled (radius 0): zero images, zero (not missing) gradients.
    m = torch.rand(5, 2, requires_grad=True)
    q = torch.tensor([[1.0, 0.0, 1.0]] * 5, requires_grad=True)
    o = torch.full((5,), 0.5, requires_grad=True)
    f = torch.rand(5, 4, requires_grad=True)
    image, alpha = rasterize_cpu(m, q, o, f, torch.rand(5), torch.zeros(5, dtype=torch.int32), 20, 10)
    assert float(image.detach().abs().max()) == 0.0 and float(alpha.detach().abs().max()) == 0.0
    (image.sum() + alpha.sum()).backward()
    for x in (m, q, o, f):
        assert x.grad is not None and float(x.grad.abs().max()) == 0.0


# ----------------------------------------------------------------------------- gradcheck



@pytest.mark.parametrize("aniso", [False, True], ids=["isotropic", "anisotropic"])
def test_gradcheck_full_pipeline(aniso):
    g = _gradcheck_scene(aniso)
    q0, t0 = _pose(torch.float64)
    inputs = [g.means.clone(), g.colors.clone(), g.logit_opacities.clone(), g.log_scales.clone(),
              q0.clone(), t0.clone()]
    if aniso:
        inputs.append(g.rotations.clone())
    inputs = [x.requires_grad_() for x in inputs]

    def fn(means, colors, logit, log_scales, q, t, *rot):
        gg = Gaussians(means, colors, rot[0] if rot else g.rotations, logit, log_scales)
        out = render(gg, INTR, w2c_from_quat_trans(q, t), backend="cpu", near=NEAR, background=0.1)
        return out.color, out.depth, out.alpha

    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


# ----------------------------------------------------------------------------- threads, determinism

def test_deterministic():
    g = _scene("mixed", torch.float32, seed=4)
    out1, grads1 = _render_with_grads(g, "cpu", torch.float32)
    out2, grads2 = _render_with_grads(g, "cpu", torch.float32)
    for a, b in zip(out1 + grads1, out2 + grads2):
        assert torch.equal(a, b)


def test_concurrent_renders_match_serial():
    """The SLAM worker and the viewer render at once: results must equal serial ones bitwise."""
    scenes = [_scene("mixed", torch.float32, seed=s) for s in (11, 12)]
    serial = [_render_with_grads(g, "cpu", torch.float32) for g in scenes]
    results = [[None] * 6 for _ in scenes]
    errors = []
    start = threading.Barrier(len(scenes))

    def work(i):
        try:
            start.wait()
            for k in range(6):
                results[i][k] = _render_with_grads(scenes[i], "cpu", torch.float32)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(scenes))]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=300)
    assert not errors, errors
    for i, (out_s, grads_s) in enumerate(serial):
        for out, grads in results[i]:
            for a, b in zip(out + grads, out_s + grads_s):
                assert torch.equal(a, b)


_WORKQUEUE_SCRIPT = """
import sys, threading, torch
sys.path.insert(0, {tests!r})
from helpers.render_scenes import _scene, _render_with_grads
scenes = [_scene("mixed", torch.float32, seed=s) for s in (21, 22)]
serial = [_render_with_grads(g, "cpu", torch.float32) for g in scenes]
bad = []
def work(i):
    for _ in range(8):
        out, grads = _render_with_grads(scenes[i], "cpu", torch.float32)
        if not all(torch.equal(a, b) for a, b in zip(out + grads, serial[i][0] + serial[i][1])):
            bad.append(i)
threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
[t.start() for t in threads]
[t.join() for t in threads]
import numba
print("layer", numba.threading_layer(), "bad", bad)
sys.exit(1 if bad else 0)
"""


def test_concurrent_renders_with_unsafe_threading_layer():
    """Numba's workqueue layer aborts the process on concurrent entry: the lock must prevent it.

    (With the OpenMP or TBB layers concurrent entry happens to work, so only this layer shows
    a missing lock.)
    """
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue")
    script = _WORKQUEUE_SCRIPT.format(tests=str(Path(__file__).parents[1]))
    res = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, f"exit {res.returncode}: {res.stdout[-2000:]} {res.stderr[-2000:]}"
    assert "layer workqueue" in res.stdout


def test_count_intersections_matches_stats():
    g = _scene("mixed", torch.float32)
    p = project_gaussians(g, INTR, w2c_from_quat_trans(*_pose(torch.float32)), near=NEAR)
    n = count_intersections(p.means2d, p.conics, p.opacities, p.radii, INTR.width, INTR.height)
    feats = torch.cat([g.colors, p.depths[:, None]], 1)
    rasterize_cpu(p.means2d, p.conics, p.opacities, feats, p.depths, p.radii, INTR.width, INTR.height)
    assert n == cpu_backend.last_stats["intersections"] > 0


@pytest.mark.parametrize("threads", [2, 3, 7])
def test_tile_binning_in_chunks_equals_one_pass(threads):
    """_bin_to_tiles splits the Gaussians into one chunk per thread: the lists must be those of a
    single pass (every tile's Gaussians in order, each Gaussian's slots), whatever the split."""
    rng = np.random.default_rng(threads)
    ntx, nty, L = 20, 15, 5000
    x0, y0 = rng.integers(0, 320, L), rng.integers(0, 240, L)
    boxes = np.stack([x0, np.minimum(x0 + rng.integers(0, 40, L), 319), y0,
                      np.minimum(y0 + rng.integers(0, 40, L), 239)], axis=1).astype(np.int64)
    boxes[::13, 1] = boxes[::13, 0] - 1                 # boxes that cover nothing
    mask = (rng.random(ntx * nty) < 0.5).astype(np.uint8)
    one = cpu_backend._bin_to_tiles(boxes, ntx, nty, mask, 1)
    split = cpu_backend._bin_to_tiles(boxes, ntx, nty, mask, threads)
    assert one[0][-1] > L
    for a, b in zip(one, split):
        np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------------- CUDA (gsplat)

def _needs_cuda():
    from splat_core.render import cuda
    reason = cuda.unavailable_reason()
    if reason is not None:
        pytest.skip(f"CUDA backend unavailable: {reason}")


def _to_cuda(g: Gaussians) -> Gaussians:
    return Gaussians(*(x.cuda() for x in (g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales)))


@pytest.mark.cuda
def test_gsplat_matches_cpu():
    _needs_cuda()
    g = _scene("mixed", torch.float32, seed=2)
    q, t = _pose(torch.float32)
    out_cpu = render(g, INTR, w2c_from_quat_trans(q, t), backend="cpu", near=NEAR)
    out_gpu = render(_to_cuda(g), INTR, w2c_from_quat_trans(q.cuda(), t.cuda()), backend="cuda", near=NEAR)
    # gsplat uses the full EWA covariance, culls per axis at 3.33 sigma and evaluates pixels
    # outside a Gaussian's box in touched tiles: differences sit at alphas in [1/255, ~0.004].
    for name, a, b, scale in (("color", out_gpu.color, out_cpu.color, 1.0),
                              ("depth", out_gpu.depth, out_cpu.depth, 4.0),
                              ("alpha", out_gpu.alpha, out_cpu.alpha, 1.0)):
        diff = (a.cpu() - b).abs()
        assert float(diff.mean()) < 2e-3 * scale, f"{name}: mean abs diff {float(diff.mean()):.3g}"
        assert float(diff.max()) < 5e-2 * scale, f"{name}: max abs diff {float(diff.max()):.3g}"


@pytest.mark.cuda
@pytest.mark.parametrize("u, v", [(20.0, 20.0), (31.3, 23.6), (40.5, 17.25)])
def test_gsplat_places_a_gaussian_where_the_cpu_backend_does(u, v):
    # A half-pixel convention error (gsplat's pixel centres sit at +0.5) shows as a 0.5 px shift
    # of the alpha centroid; the tolerance is a tenth of that.
    _needs_cuda()
    z, sigma = 2.0, 1.5 * 2.0 / INTR.fx
    mean = torch.tensor([[(u - INTR.cx) / INTR.fx * z, (v - INTR.cy) / INTR.fy * z, z]])
    g = Gaussians(mean, torch.ones(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([2.0]),
                  torch.log(torch.tensor([[sigma]])))
    eye = torch.eye(4)
    centroids = []
    for gg, w2c, backend in ((g, eye, "cpu"), (_to_cuda(g), eye.cuda(), "cuda")):
        a = render(gg, INTR, w2c, backend=backend, near=NEAR).alpha.detach().cpu().double()
        vv, uu = torch.meshgrid(torch.arange(INTR.height, dtype=torch.float64),
                                torch.arange(INTR.width, dtype=torch.float64), indexing="ij")
        centroids.append(((a * uu).sum() / a.sum(), (a * vv).sum() / a.sum()))
    (uc, vc), (ug, vg) = centroids
    assert abs(float(uc) - u) < 0.05 and abs(float(vc) - v) < 0.05
    assert abs(float(ug - uc)) < 0.05 and abs(float(vg - vc)) < 0.05, (centroids, u, v)


@pytest.mark.cuda
@pytest.mark.parametrize("case", ["mixed", "aniso", "layers"])
def test_gsplat_gradients_agree_with_the_cpu_backend(case):
    # Not bitwise (different 2D covariance and culling, see render/cuda.py), so each gradient is
    # compared by direction (cosine) and length; a wrong sign or convention fails both.
    _needs_cuda()
    g = _scene(case, torch.float32, seed=2)
    _, grads_cpu = _render_with_grads(g, "cpu", torch.float32)

    params, _, _ = _leaves(_to_cuda(g), torch.float32)
    q, t = (x.detach().cuda().requires_grad_() for x in _pose(torch.float32))
    out = render(Gaussians(*params), INTR, w2c_from_quat_trans(q, t), backend="cuda", near=NEAR)
    gen = torch.Generator().manual_seed(1)
    H, W = INTR.height, INTR.width
    rand = lambda *s: torch.randn(*s, generator=gen, dtype=torch.float64).float().cuda()  # noqa: E731
    loss = ((out.color * rand(H, W, 3)).sum() + (out.depth * rand(H, W)).sum()
            + (out.alpha * rand(H, W)).sum())
    inputs = params + [q, t]
    grads_gpu = [torch.zeros_like(x) if gr is None else gr
                 for x, gr in zip(inputs, torch.autograd.grad(loss, inputs, allow_unused=True))]
    for name, a, b in zip(GRAD_NAMES, grads_gpu, grads_cpu):
        a, b = a.detach().cpu().double().reshape(-1), b.detach().double().reshape(-1)
        if float(b.norm()) < 1e-6:          # e.g. rotations of isotropic Gaussians
            assert float(a.norm()) < 1e-3, f"{name}: gsplat gradient {float(a.norm()):.3g}, cpu ~0"
            continue
        cos = float(a @ b / (a.norm() * b.norm()))
        ratio = float(a.norm() / b.norm())
        assert cos > 0.97 and 0.85 < ratio < 1.15, f"{name}: cosine {cos:.4f}, norm ratio {ratio:.3f}"


def test_render_visible_equals_render_of_the_whole_map():
    # Culling to the view before rendering changes nothing in the image, only what it costs.
    from splat_core.render import Renderer
    from splat_core.camera import pose_matrix, quat_to_rotmat_np
    rng = np.random.default_rng(5)
    intr = Intrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)
    pts = rng.uniform([-6, -4, -3], [6, 4, 8], (4000, 3))
    g = GaussianMap.from_points(pts, rng.uniform(0, 1, (4000, 3)), rng.uniform(0.01, 0.2, 4000), 0).tensors(detach=True)
    renderer = Renderer()
    w2c = pose_matrix(quat_to_rotmat_np([np.cos(0.2), 0.1, np.sin(0.2), 0]), [0.1, 0, 0.3])
    visible = renderer.visible(g, intr, w2c)
    assert 0 < len(visible) < len(g) // 2
    full, culled = renderer.render(g, intr, w2c), renderer.render_visible(g, intr, w2c)
    for a, b in zip(full, culled):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=0)


@pytest.mark.parametrize("n", [0, 1, 2, 1000, 70_000])
def test_depth_radix_sort_is_numpys_stable_argsort(n):
    """The rasterizer's depth order (a radix sort of float32 bit patterns) equals numpy's stable
    argsort of the depths: front to back, ties by index (many ties here, and depths over several
    binades, so every digit pass runs)."""
    rng = np.random.default_rng(n)
    depth = rng.choice(np.exp(rng.uniform(-4, 4, max(1, n // 3))), size=n).astype(np.float32)
    order = cpu_backend._radix_argsort(depth.view(np.int32))
    assert np.array_equal(order, np.argsort(depth, kind="stable"))


def test_one_feature_block_reduces_as_several_do_bit_for_bit():
    """With one 4-channel block the backward sums each Gaussian's rows straight into its gradients;
    with more blocks it adds each block's sums to zeros. Four channels, and the same four plus four
    whose gradient is zero (a second block adding nothing), give the same gradients bit for bit."""
    g = _scene("mixed", torch.float32, seed=5)
    p = project_gaussians(g, INTR, w2c_from_quat_trans(*_pose(torch.float32)), near=NEAR)
    feats = torch.cat([g.colors, p.depths[:, None]], 1).detach()
    weight = torch.randn(INTR.height, INTR.width, 4, generator=torch.Generator().manual_seed(0))
    grads = []
    for extra in (0, 4):
        leaves = [x.detach().clone().requires_grad_() for x in (p.means2d, p.conics, p.opacities)]
        f = torch.cat([feats, torch.rand(len(feats), extra)], 1).requires_grad_()
        image, alpha = rasterize_cpu(*leaves, f, p.depths.detach(), p.radii, INTR.width, INTR.height)
        ((image[..., :4] * weight).sum() + alpha.sum()).backward()
        grads.append([x.grad for x in leaves] + [f.grad[:, :4]])
    assert float(grads[0][0].abs().max()) > 0
    for a, b in zip(*grads):
        assert torch.equal(a, b)
