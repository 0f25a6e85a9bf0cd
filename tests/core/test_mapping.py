"""Mapping (mapping.py): pruning, the loss falls, tiles drawn, the frustum test, the CPU loss against torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics
from splat_core.config import (MappingConfig, load_config)
from splat_core.densify import unexposed
from splat_core.gaussians import GaussianMap
from splat_core.mapping import View, frustum_mask, optimise_map, prune_mask
from splat_core.render import render

from helpers.engine import map_from_frame, small_source


def test_pruning_removes_transparent_and_huge_gaussians_and_keeps_adam_state_aligned():
    m = GaussianMap.from_points(np.zeros((5, 3)) + [0, 0, 2], np.full((5, 3), 0.5), np.full(5, 0.01), 0)
    with torch.no_grad():
        m.logit_opacities[1] = -8.0                     # opacity 3e-4 < 0.005
        m.log_scales[3] = np.log(0.5)                   # > 0.1 * scene radius 1.0
    keep = prune_mask(m, MappingConfig(), scene_radius=1.0)
    assert keep.tolist() == [True, False, True, False, True]
    opt = torch.optim.Adam(m.param_groups(MappingConfig().lrs))
    (m.means.sum() + m.colors.sum()).backward()
    opt.step()
    marker = opt.state[m.means]["exp_avg"].clone()
    marker[:, 0] = torch.arange(5.0)
    opt.state[m.means]["exp_avg"] = marker
    assert m.prune(keep, opt) == 2
    assert len(m) == 3 and opt.state[m.means]["exp_avg"][:, 0].tolist() == [0.0, 2.0, 4.0]
    assert opt.param_groups[0]["params"][0] is m.means


@pytest.mark.parametrize("tile_fraction", [1.0, 0.5])
def test_mapping_reduces_the_loss_and_leaves_unseen_gaussians_untouched(tile_fraction):
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    m = map_from_frame(f)
    far = GaussianMap.from_points([[0, 0, -5.0]], [[1, 0, 0]], [0.01], 0)   # behind the camera
    m.append(far)
    with torch.no_grad():
        m.colors[:-1] += 0.2                       # spoil the colours
    view = View(torch.as_tensor(f.color), torch.as_tensor(f.depth), np.eye(4))
    cfg = MappingConfig(tile_fraction=tile_fraction, min_tiles=0)
    from splat_core.mapping import mapping_loss
    before = float(mapping_loss(render(m, f.intrinsics, np.eye(4)), view, cfg))
    far_before = m.means[-1].detach().clone()
    stats = optimise_map(m, [view], f.intrinsics, cfg, round(15 / tile_fraction), scene_radius=2.0,
                         rng=np.random.default_rng(0))
    after = float(mapping_loss(render(m, f.intrinsics, np.eye(4)), view, cfg))
    assert after < 0.8 * before
    assert torch.equal(m.means[-1].detach(), far_before)
    assert stats["optimised"] == len(m) - 1


def test_first_frame_maps_every_tile(monkeypatch):
    """Frame 0 anchors the trajectory: its long first mapping draws every tile; later frames draw
    the configured fraction."""
    import splat_core.slam as slam_module
    seen = []
    monkeypatch.setattr(slam_module, "optimise_map",
                        lambda m, window, intr, config, iterations, *a, **k: seen.append(
                            (config.tile_fraction, iterations)) or {"pruned": 0})
    cfg = load_config("cpu")
    assert cfg.mapping.tile_fraction < 1
    src = small_source(n=2)
    slam = slam_module.SplaTAM(cfg, src.intrinsics)
    slam.optimise([], first=True)
    slam.optimise([], first=False)
    assert seen == [(1.0, cfg.mapping.first_frame_iterations), (cfg.mapping.tile_fraction, cfg.mapping.iterations)]


def test_first_frame_budget_of_the_live_preset(monkeypatch):
    """mapping.first_frame_tile_fraction and first_frame_iterations: the `live` preset's frame 0,
    which its tracker waits for, runs its own (fewer) iterations on its configured share of the
    tiles (cpu: every tile, as above); later frames are unchanged."""
    import splat_core.slam as slam_module
    seen = []
    monkeypatch.setattr(slam_module, "optimise_map",
                        lambda m, window, intr, config, iterations, *a, **k: seen.append(
                            (config.tile_fraction, iterations)) or {"pruned": 0})
    cfg = load_config("live")
    assert cfg.mapping.first_frame_tile_fraction < 1
    assert cfg.mapping.first_frame_iterations < load_config("cpu").mapping.first_frame_iterations
    slam = slam_module.SplaTAM(cfg, small_source(n=2).intrinsics)
    slam.optimise([], first=True)
    slam.optimise([], first=False)
    assert seen == [(cfg.mapping.first_frame_tile_fraction, cfg.mapping.first_frame_iterations),
                    (cfg.mapping.tile_fraction, cfg.mapping.iterations)]


def test_mapping_loss_over_drawn_tiles():
    """Over every pixel the tile loss is the full loss; over some tiles it sees those tiles only."""
    from splat_core.mapping import draw_tiles, mapping_loss
    src = small_source(n=2, w=64, h=48)
    f, g = src[0], src[1]
    rendered = render(map_from_frame(f), f.intrinsics, np.eye(4))
    view = View(torch.as_tensor(g.color), torch.as_tensor(g.depth), np.eye(4))
    cfg = MappingConfig()
    full = float(mapping_loss(rendered, view, cfg))
    everything = torch.ones(f.intrinsics.height, f.intrinsics.width, dtype=torch.bool)
    assert float(mapping_loss(rendered, view, cfg, everything)) == pytest.approx(full, rel=1e-5)
    tiles, pixels = draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0))
    assert tiles.shape == (3, 4) and int(tiles.sum()) == 6 and int(pixels.sum()) == 6 * 16 * 16
    spoilt = rendered._replace(color=torch.where(pixels[..., None], rendered.color, 1 - rendered.color))
    assert float(mapping_loss(spoilt, view, cfg, pixels)) == pytest.approx(float(mapping_loss(rendered, view, cfg, pixels)),
                                                                         rel=1e-2)
    assert float(mapping_loss(spoilt, view, cfg)) > 1.2 * full
    assert draw_tiles(f.intrinsics, 1.0, np.random.default_rng(0)) == (None, None)
    assert int(draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0), min_tiles=8)[0].sum()) == 8
    assert draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0), min_tiles=12) == (None, None)   # small images: all


def test_frustum_mask_is_conservative():
    intr = Intrinsics(60, 60, 31.5, 23.5, 64, 48)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-3, -3, -1], [3, 3, 4], (3000, 3))
    g = GaussianMap.from_points(pts, rng.uniform(0, 1, (3000, 3)), rng.uniform(0.005, 0.05, 3000), 0)
    keep = frustum_mask(g.means.detach(), g.log_scales.detach(), intr, np.eye(4), 0.01)
    out = render(g, intr, np.eye(4))
    g.means.grad = None
    out.color.sum().backward()
    touched = g.means.grad.abs().sum(1) > 0
    assert bool((keep | ~touched).all()) and keep.sum() < 3000


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("drawn", [False, True])
def test_cpu_mapping_loss_equals_the_torch_definition(dtype, drawn):
    """mapping_loss on CPU tensors (mapping_loss_cpu: one autograd step) has the value and the
    gradients of the torch definition, with and without drawn tiles, with pixels without depth
    and residuals that are exactly 0 (|x| has gradient 0 there, as in torch)."""
    from splat_core.mapping import _mapping_loss_torch, draw_tiles, mapping_loss
    from splat_core.render import Render
    g = torch.Generator().manual_seed(0)
    H, W = 48, 64
    view = View(torch.rand(H, W, 3, generator=g, dtype=dtype), 1 + torch.rand(H, W, generator=g, dtype=dtype), np.eye(4))
    view.depth[:10, :20] = 0                                   # no depth here
    color = torch.rand(H, W, 3, generator=g, dtype=dtype)
    depth = 1 + torch.rand(H, W, generator=g, dtype=dtype)
    color[5, 5] = view.color[5, 5]                             # exact matches: zero residuals
    depth[30, 30] = view.depth[30, 30]
    intr = Intrinsics(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=W, height=H)
    pixels = draw_tiles(intr, 0.5, np.random.default_rng(1))[1] if drawn else None
    cfg = MappingConfig()
    results = []
    for loss_fn in (mapping_loss, _mapping_loss_torch):
        c, d = color.clone().requires_grad_(), depth.clone().requires_grad_()
        loss = loss_fn(Render(c, d, torch.ones(H, W, dtype=dtype)), view, cfg, pixels)
        loss.backward()
        results.append((float(loss), c.grad, d.grad))
    (v_cpu, gc_cpu, gd_cpu), (v_ref, gc_ref, gd_ref) = results
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert v_cpu == pytest.approx(v_ref, rel=tol)
    assert torch.allclose(gc_cpu, gc_ref, rtol=tol, atol=tol * float(gc_ref.abs().max()))
    assert torch.equal(gd_cpu, gd_ref) or torch.allclose(gd_cpu, gd_ref, rtol=tol, atol=0)
    assert gd_cpu[30, 30] == 0 and bool((gd_cpu[:10, :20] == 0).all())


def test_exposure_fit_recovers_a_known_gain_and_offset_and_is_the_objectives_minimum():
    from splat_core.mapping import exposure_fit
    rng = np.random.default_rng(0)
    r = torch.as_tensor(rng.uniform(0.1, 0.9, (12, 16, 3)))
    gain_true, offset_true = torch.tensor([1.3, 0.8, 1.1], dtype=r.dtype), torch.tensor([-0.05, 0.02, 0.0], dtype=r.dtype)
    o = r * gain_true + offset_true
    g, b = exposure_fit(r, o, None, prior=0.0)
    assert torch.allclose(g, gain_true, atol=1e-9) and torch.allclose(b, offset_true, atol=1e-9)
    g_same, b_same = exposure_fit(r, r, None, prior=0.05)          # render == view: identity
    assert torch.allclose(g_same, torch.ones(3, dtype=r.dtype)) and torch.allclose(b_same, torch.zeros(3, dtype=r.dtype))

    # With a prior and a mask: the fit is where the objective's finite-difference gradient vanishes
    # (and the objective is larger a step away), and it lies between identity and the free fit.
    mask = torch.as_tensor(rng.uniform(size=(12, 16)) > 0.3)
    noisy = o + torch.as_tensor(rng.normal(0, 0.02, o.shape))
    prior = 0.05
    g, b = exposure_fit(r, noisy, mask, prior)
    n = float(mask.sum())

    def objective(gv, bv):
        res = (r * gv + bv - noisy)[mask]
        return float((res ** 2).sum() + prior * n * (((gv - 1) ** 2).sum() + (bv ** 2).sum()))

    h = 1e-6
    for c in range(3):
        for which in ("gain", "offset"):
            step = torch.zeros(3, dtype=r.dtype)
            step[c] = h
            plus = objective(g + step, b) if which == "gain" else objective(g, b + step)
            minus = objective(g - step, b) if which == "gain" else objective(g, b - step)
            assert abs((plus - minus) / (2 * h)) < 1e-5 * n
            assert plus > objective(g, b) and minus > objective(g, b)
    g_free, _ = exposure_fit(r, noisy, mask, 0.0)
    assert torch.all((g - 1).abs() < (g_free - 1).abs())
    g_none, b_none = exposure_fit(r, noisy, torch.zeros_like(mask), prior)
    assert torch.equal(g_none, torch.ones(3, dtype=r.dtype)) and torch.equal(b_none, torch.zeros(3, dtype=r.dtype))


def _mapped_colours(view_scale: float, exposure: bool, prior: float = 0.01, iterations: int = 15):
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    m = map_from_frame(f)
    view = View(torch.as_tensor(f.color) * view_scale, torch.as_tensor(f.depth), np.eye(4))
    cfg = MappingConfig(exposure=exposure, exposure_prior=prior)
    optimise_map(m, [view], f.intrinsics, cfg, iterations, scene_radius=2.0, rng=np.random.default_rng(0))
    return m, map_from_frame(f)


def test_mapping_exposure_keeps_the_maps_colours_under_a_darker_view():
    """A view that is the map's own frame at 0.7 exposure: without the exposure fit mapping darkens
    the Gaussians' colours; with it they stay near the map's (the fit takes up the change)."""
    plain, start = _mapped_colours(0.7, exposure=False)
    fitted, _ = _mapped_colours(0.7, exposure=True)
    drift_plain = float((plain.colors.detach() - start.colors.detach()).mean())
    drift_fitted = float((fitted.colors.detach() - start.colors.detach()).mean())
    assert drift_plain < -0.02
    assert abs(drift_fitted) < 0.25 * abs(drift_plain)


def test_mapping_exposure_with_an_overwhelming_prior_is_plain_mapping():
    """The fit pulled all the way to identity (gain 1, offset 0) maps as without it."""
    plain, _ = _mapped_colours(0.7, exposure=False)
    pinned, _ = _mapped_colours(0.7, exposure=True, prior=1e12)
    for name in ("means", "colors", "log_scales", "logit_opacities"):
        assert torch.allclose(getattr(plain, name).detach(), getattr(pinned, name).detach(), atol=1e-6), name


def test_densify_under_mapping_exposure_brings_new_colours_to_the_maps_exposure():
    """New Gaussians from a frame seen at 0.7 exposure start at the map's colours (the frame's
    gain fitted against the render, inverted), not at the frame's darker ones."""
    import dataclasses

    from splat_core.render import Renderer
    from splat_core.slam import SplaTAM
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    cfg = load_config("cpu")
    cfg = dataclasses.replace(cfg, mapping=dataclasses.replace(cfg.mapping, exposure=True))
    slam = SplaTAM(cfg, f.intrinsics)
    m = map_from_frame(f)
    with torch.no_grad():
        out = Renderer().render(m, f.intrinsics, np.eye(4))
    covered = out.alpha.numpy() > 0.5
    dark = (f.color * 0.7).astype(np.float32)
    restored = unexposed(dark, out, slam.config.mapping.exposure_prior)
    rendered = out.color.numpy()
    assert np.abs(restored - rendered)[covered].mean() < 0.5 * np.abs(dark - rendered)[covered].mean()
    assert abs(float(restored[covered].mean()) - float(rendered[covered].mean())) < 0.02


def test_a_mapping_step_stopped_after_k_iterations_is_the_k_iteration_step():
    """optimise_map's `stop(done)` (the live engine's hurried keyframe steps) ends the step after
    the iteration it returns True for: the map is exactly that of a step of that many iterations."""
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    view = View(torch.as_tensor(f.color), torch.as_tensor(f.depth), np.eye(4))
    cfg = MappingConfig(tile_fraction=0.5, min_tiles=0)
    maps, asked = [], []
    for iterations, stop in ((3, None), (10, lambda done: asked.append(done) or done == 3)):
        m = map_from_frame(f)
        with torch.no_grad():
            m.colors += 0.2
        optimise_map(m, [view], f.intrinsics, cfg, iterations, scene_radius=2.0, rng=np.random.default_rng(0),
                     stop=stop)
        maps.append(m)
    assert asked == [1, 2, 3]
    for name in ("means", "colors", "log_scales"):
        assert torch.equal(getattr(maps[0], name), getattr(maps[1], name))
