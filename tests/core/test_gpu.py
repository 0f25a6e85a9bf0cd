"""The GPU path (docs/gpu.md): no host synchronisation per iteration in tracking, mapping and the
direct alignment; the torch alignment on CUDA against the CPU; the `gpu` preset live on CUDA.

The sync counts use torch.cuda.set_sync_debug_mode("warn"), which warns at every operation that
makes the host wait for the GPU: a loop that asks the host nothing warns as often with 2
iterations as with 10. The renderer is replaced by a sync-free differentiable stand-in there, so
the count is the loop's own (gsplat's tile intersection reads a count per render, outside our
code). On a CPU the same functions run with the stand-in (count 0), which checks the plumbing.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from splat_core.align import torch_backend as tt
from splat_core.camera import Intrinsics
from splat_core.config import MappingConfig, TrackingConfig, load_config
from splat_core.gaussians import GaussianMap
from splat_core.mapping import View, optimise_map
from splat_core.render import Render
from splat_core.synthetic import SyntheticSource
from splat_core.tracking import Observation, polish

INTR = Intrinsics(60.0, 60.0, 31.5, 23.5, 64, 48)


def needs_cuda():
    from splat_core.render import cuda
    reason = cuda.unavailable_reason()
    if reason is not None:
        pytest.skip(f"CUDA backend unavailable: {reason}")


class SmoothRenderer:
    """A differentiable, sync-free stand-in for the renderer: images that vary smoothly with the
    pose and the Gaussians' parameters (no sorting, no counts read back)."""

    near = 0.01

    def render(self, gaussians, intr, w2c, *, background=0.0, screen=None, tiles=None):
        g = gaussians.tensors() if isinstance(gaussians, GaussianMap) else gaussians
        w2c = w2c if torch.is_tensor(w2c) else torch.as_tensor(np.asarray(w2c), dtype=g.means.dtype).to(g.means.device)
        ramp = torch.linspace(0.0, 1.0, intr.width, dtype=g.means.dtype, device=g.means.device)
        shift = w2c[0, 3] - 0.5 * w2c[1, 3] + 0.25 * w2c[2, 3] + w2c[0, 1]
        depth = (2.0 + shift + g.means[:, 2].mean() + 0.1 * ramp)[None, :].expand(intr.height, intr.width)
        color = torch.sigmoid(g.colors.mean(0) + shift)[None, None, :].expand(intr.height, intr.width, 3)
        alpha = torch.ones(intr.height, intr.width, dtype=g.means.dtype, device=g.means.device)
        return Render(color, depth, alpha)

    def pixels(self, gaussians, intr, w2c, pixels, *, background=0.0):
        out = self.render(gaussians, intr, w2c)
        x, y = torch.as_tensor(pixels[:, 0]), torch.as_tensor(pixels[:, 1])
        return Render(out.color[y, x], out.depth[y, x], out.alpha[y, x])


def _gaussians(device, n=200):
    rng = np.random.default_rng(0)
    return GaussianMap.from_numpy(dict(
        means=rng.uniform(-1, 1, (n, 3)) + [0, 0, 2.5], colors=np.full((n, 3), 0.5),
        rotations=np.tile([1.0, 0, 0, 0], (n, 1)), logit_opacities=np.zeros(n), log_scales=np.full((n, 1), -3.0),
        birth_frame=np.zeros(n, np.int64)), device=device)


def count_syncs(fn) -> int:
    """How many synchronising CUDA operations `fn` makes (0 on a machine without CUDA)."""
    if not torch.cuda.is_available():
        fn()
        return 0
    torch.cuda.synchronize()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            fn()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return sum("synchroniz" in str(w.message) for w in caught)


def _polish_syncs(device, iterations: int) -> int:
    m = _gaussians(device)
    g = m.tensors(detach=True)
    depth = torch.full((INTR.height, INTR.width), 2.4, device=device)
    color = torch.full((INTR.height, INTR.width, 3), 0.6, device=device)
    obs = Observation(INTR, color, depth)
    w2c = np.eye(4)
    w2c[:3, 3] = [0.01, 0.02, -0.03]
    config = TrackingConfig(iterations=iterations)
    polish(SmoothRenderer(), g, obs, w2c, config)          # warm-up (allocator, fused Adam's first step)
    return count_syncs(lambda: polish(SmoothRenderer(), g, obs, w2c, config))


def _mapping_syncs(device, iterations: int) -> int:
    views = [View(torch.full((INTR.height, INTR.width, 3), 0.6, device=device),
                  torch.full((INTR.height, INTR.width), 2.4, device=device), np.eye(4)) for _ in range(3)]
    config = MappingConfig(prune_every=1000, prune_until=0)

    def run():
        optimise_map(_gaussians(device), views, INTR, config, iterations, 5.0, np.random.default_rng(0),
                     renderer=SmoothRenderer())
    run()
    return count_syncs(run)


def _align_syncs(device, iterations: int, monkeypatch) -> int:
    frame = SyntheticSource(n_frames=1, width=64, height=48, seed=0)[0]
    fixed = Render(torch.as_tensor(frame.color).to(device), torch.as_tensor(frame.depth).to(device),
                   torch.ones(48, 64, device=device))
    monkeypatch.setattr(tt, "render", lambda *a, **k: fixed)
    g = _gaussians(device).tensors(detach=True)
    color, depth = torch.as_tensor(frame.color).to(device), torch.as_tensor(frame.depth).to(device)

    def run():
        tt.align_to_map_torch(g, color, depth, frame.intrinsics, np.eye(4), iterations=iterations, passes=2,
                              sync=False)
    run()
    return count_syncs(run)


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)])
def test_no_host_sync_per_iteration_in_tracking_mapping_and_alignment(device, monkeypatch):
    if device == "cuda":
        needs_cuda()
    polish2, polish10 = _polish_syncs(device, 2), _polish_syncs(device, 10)
    map2, map10 = _mapping_syncs(device, 2), _mapping_syncs(device, 10)
    align2, align10 = _align_syncs(device, 2, monkeypatch), _align_syncs(device, 10, monkeypatch)
    print(dict(polish=(polish2, polish10), mapping=(map2, map10), align=(align2, align10)))
    assert polish10 == polish2 and map10 == map2 and align10 == align2


@pytest.mark.cuda
def test_torch_alignment_on_cuda_matches_the_cpu(monkeypatch):
    needs_cuda()
    src = SyntheticSource(n_frames=3, width=160, height=120, seed=0)
    f0, f2 = src[0], src[2]
    fixed = {}

    def same_render(g, intr, w2c, near=0.01):       # both devices see the same 'rendering' (frame 0)
        d = g.means.device
        return fixed.setdefault(str(d), Render(torch.as_tensor(f0.color).to(d), torch.as_tensor(f0.depth).to(d),
                                               torch.ones(120, 160, device=d)))
    monkeypatch.setattr(tt, "render", same_render)
    results = []
    for device in ("cpu", "cuda"):
        g = _gaussians(device).tensors(detach=True)
        results.append(tt.align_to_map_torch(g, f2.color, f2.depth, f2.intrinsics, np.eye(4), iterations=10,
                                             depth_noise=True, live_stride=2))
    cpu, gpu = results
    assert gpu.correspondences == cpu.correspondences > 1000
    assert np.allclose(gpu.w2c, cpu.w2c, rtol=0, atol=1e-7), np.abs(gpu.w2c - cpu.w2c).max()


@pytest.mark.cuda
@pytest.mark.slow
def test_gpu_preset_runs_live_on_cuda_with_a_reader_thread():
    import threading

    from splat_core.run import Pipeline
    needs_cuda()
    config = load_config("gpu", overrides={"resolution": [320, 240], "checkpoint_every": 0})
    pipe = Pipeline(SyntheticSource(n_frames=12, width=320, height=240, seed=0), config, device="cuda", engine="live")
    stop, errors = threading.Event(), []

    def viewer():          # renders the newest version on its own thread, as the viewer does
        from splat_core.render import Renderer
        try:
            while not stop.is_set():
                version = pipe.map_version()
                with torch.no_grad():
                    out = Renderer().render(version.gaussians, INTR, np.eye(4))
                assert torch.isfinite(out.color).all()
        except BaseException as e:    # noqa: BLE001 - reported below
            errors.append(e)
    reader = threading.Thread(target=viewer)
    reader.start()
    try:
        while pipe.step() is not None:
            pass
        metrics = pipe.finish()
    finally:
        stop.set()
        reader.join()
    assert not errors, errors
    assert pipe.engine.slam.map.device.type == "cuda" and metrics["frames"] == 12
    assert metrics["ate_rmse_cm"] < 1.0 and metrics["psnr"] > 25
