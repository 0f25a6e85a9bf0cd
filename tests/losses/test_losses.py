"""Masked L1 and SSIM against hand computations and a slow independent SSIM."""

import numpy as np
import pytest
import torch

from splat_core.losses import gaussian_window, l1, ssim, ssim_map


def slow_ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Per-pixel loop: 11x11 Gaussian (sigma 1.5) weighted statistics, pixels outside the image
    count as 0 (zero padding), C1 = 1e-4, C2 = 9e-4, mean over pixels and channels."""
    x = np.arange(11) - 5
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    g /= g.sum()
    w = np.outer(g, g)
    H, W, C = a.shape
    total = 0.0
    for c in range(C):
        for i in range(H):
            for j in range(W):
                sx = sy = sxx = syy = sxy = 0.0
                for di in range(-5, 6):
                    for dj in range(-5, 6):
                        ii, jj = i + di, j + dj
                        if 0 <= ii < H and 0 <= jj < W:
                            k = w[di + 5, dj + 5]
                            p, q = a[ii, jj, c], b[ii, jj, c]
                            sx += k * p
                            sy += k * q
                            sxx += k * p * p
                            syy += k * q * q
                            sxy += k * p * q
                vx, vy, cxy = sxx - sx * sx, syy - sy * sy, sxy - sx * sy
                total += ((2 * sx * sy + 1e-4) * (2 * cxy + 9e-4)) / (
                    (sx * sx + sy * sy + 1e-4) * (vx + vy + 9e-4))
    return total / (H * W * C)


def test_ssim_matches_slow_reference():
    rng = np.random.default_rng(0)
    a = rng.random((9, 13, 2))
    b = np.clip(a + 0.2 * rng.normal(size=a.shape), 0, 1)
    got = ssim(torch.tensor(a), torch.tensor(b))
    assert got.dtype == torch.float64
    assert float(got) == pytest.approx(slow_ssim(a, b), abs=1e-10)
    # float32 works too, close to the float64 value.
    got32 = ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32))
    assert got32.dtype == torch.float32 and float(got32) == pytest.approx(float(got), abs=1e-5)


def test_ssim_identity_and_constant_images():
    x = torch.rand(20, 24, 3, dtype=torch.float64)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-12)
    # Interior of two constant images: variances vanish, SSIM = (2ab + C1) / (a^2 + b^2 + C1).
    a, b = 0.3, 0.6
    m = ssim_map(torch.full((30, 30), a, dtype=torch.float64), torch.full((30, 30), b, dtype=torch.float64))
    assert m.shape == (1, 1, 30, 30)
    assert float(m[0, 0, 15, 15]) == pytest.approx((2 * a * b + 1e-4) / (a * a + b * b + 1e-4), rel=1e-9)
    assert float(ssim(torch.rand(16, 16), torch.rand(16, 16))) < 0.5


def test_ssim_window():
    w = gaussian_window(dtype=torch.float64)
    assert w.shape == (11, 11) and float(w.sum()) == pytest.approx(1.0)
    assert float(w[5, 5]) == float(w.max()) and torch.allclose(w, w.T)
    assert float(w[5, 6] / w[5, 5]) == pytest.approx(np.exp(-1 / (2 * 1.5 ** 2)))


def test_ssim_gradients_finite():
    target = torch.rand(16, 20, 3, dtype=torch.float64)
    for start in (target.clone(), torch.rand(16, 20, 3, dtype=torch.float64), torch.zeros(16, 20, 3, dtype=torch.float64)):
        x = start.requires_grad_(True)
        (1 - ssim(x, target)).backward()
        assert torch.isfinite(x.grad).all()
    x = torch.rand(6, 7, 2, dtype=torch.float64, requires_grad=True)
    y = torch.rand(6, 7, 2, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: ssim(t, y), (x,))


def test_ssim_rejects_bad_shapes():
    with pytest.raises(ValueError):
        ssim(torch.rand(4, 4, 3), torch.rand(4, 5, 3))
    with pytest.raises(ValueError):
        ssim(torch.rand(1, 4, 4, 3), torch.rand(1, 4, 4, 3))


def test_l1_sum_and_mean_by_hand():
    pred = torch.tensor([[[0.0, 1.0], [2.0, 3.0]], [[4.0, 5.0], [6.0, 7.0]]])   # 2 x 2 x 2
    target = torch.zeros(2, 2, 2)
    assert float(l1(pred, target)) == 28.0
    assert float(l1(pred, target, reduction="mean")) == 3.5
    mask = torch.tensor([[True, False], [False, True]])                         # pixels (0,0), (1,1)
    assert float(l1(pred, target, mask)) == 0 + 1 + 6 + 7
    assert float(l1(pred, target, mask, reduction="mean")) == 14 / 4
    assert l1(pred, target, mask, reduction="none").shape == (2, 2, 2)
    # Float weights.
    wts = torch.tensor([[1.0, 0.0], [0.0, 0.5]])
    assert float(l1(pred, target, wts)) == pytest.approx(1 + 6.5)
    assert float(l1(pred, target, wts, reduction="mean")) == pytest.approx(7.5 / 3)
    # Depth-style H x W inputs.
    d = torch.tensor([[1.0, 2.0], [3.0, 0.0]])
    assert float(l1(d, torch.zeros(2, 2), d > 0, reduction="mean")) == 2.0
    # Empty mask: 0, not NaN.
    assert float(l1(pred, target, torch.zeros(2, 2, dtype=torch.bool), reduction="mean")) == 0.0
    with pytest.raises(ValueError):
        l1(pred, target, reduction="max")


def test_l1_masked_nan_does_not_poison_value_or_gradient():
    pred = torch.rand(5, 6, 3, dtype=torch.float64, requires_grad=True)
    target = torch.rand(5, 6, 3, dtype=torch.float64)
    target[0, 0] = float("nan")
    mask = torch.ones(5, 6, dtype=torch.bool)
    mask[0, 0] = False
    loss = l1(pred, target, mask)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    assert torch.all(pred.grad[0, 0] == 0)
    expected = (pred.detach() - target).abs()[mask].sum()
    assert float(loss.detach()) == pytest.approx(float(expected))


# ----------------------------------------------------------------------------- Numba CPU SSIM
# losses.ssim runs splat_core/ssim_cpu.py for CPU images with a constant target; the torch code
# (ssim_map(...).mean(), F.conv2d and autograd) is the reference it must reproduce.

from splat_core.losses import ssim_cpu  # noqa: E402


def _pair(shape, dtype, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(*shape, generator=g, dtype=dtype)
    y = (x + 0.2 * torch.randn(*shape, generator=g, dtype=dtype)).clamp(0, 1)
    return x, y


def _torch_ssim(x, y):
    return ssim_map(x, y).mean()


def _is_numba_path(value: torch.Tensor) -> bool:
    return value.grad_fn is not None and "SSIMCPU" in type(value.grad_fn).__name__


@pytest.mark.parametrize("shape", [(24, 30, 3), (7, 9, 3), (12, 13), (17, 11, 2), (5, 40, 1)])
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_numba_ssim_value_matches_torch(shape, dtype, tol):
    x, y = _pair(shape, dtype, seed=len(shape) * 100 + shape[0])
    got = ssim_cpu.ssim_cpu(x, y)
    want = _torch_ssim(x, y)
    assert got.dtype == dtype and got.shape == ()
    assert abs(float(got) - float(want)) <= tol
    # The dispatch takes this path for CPU tensors with a constant target.
    xg = x.clone().requires_grad_(True)
    via_ssim = ssim(xg, y)
    assert _is_numba_path(via_ssim)
    assert abs(float(via_ssim.detach()) - float(want)) <= tol


def test_numba_ssim_not_symmetric_images():
    # Images that differ a lot (SSIM far from 1) and a target with structure the input lacks.
    x, _ = _pair((20, 23, 3), torch.float64, seed=3)
    y = torch.zeros(20, 23, 3, dtype=torch.float64)
    y[5:15, 4:12] = 1.0
    assert abs(float(ssim_cpu.ssim_cpu(x, y)) - float(_torch_ssim(x, y))) <= 1e-12
    assert abs(float(ssim_cpu.ssim_cpu(y, x)) - float(_torch_ssim(y, x))) <= 1e-12


@pytest.mark.parametrize("shape", [(24, 30, 3), (7, 9, 3), (12, 13), (9, 14, 2)])
def test_numba_ssim_gradient_matches_torch_autograd(shape):
    x, y = _pair(shape, torch.float64, seed=7 + shape[0])
    x_ref = x.clone().requires_grad_(True)
    (2.5 * _torch_ssim(x_ref, y)).backward()          # a non-unit upstream gradient
    x_new = x.clone().requires_grad_(True)
    value = ssim(x_new, y)
    assert _is_numba_path(value)
    (2.5 * value).backward()
    assert x_new.grad.shape == x.shape and x_new.grad.dtype == torch.float64
    assert float(x_ref.grad.abs().max()) > 1e-4       # the comparison is not between zeros
    assert torch.allclose(x_new.grad, x_ref.grad, rtol=0, atol=1e-10)


def test_numba_ssim_gradient_float32_close_to_torch():
    x, y = _pair((30, 40, 3), torch.float32, seed=11)
    x_ref = x.clone().requires_grad_(True)
    _torch_ssim(x_ref, y).backward()
    x_new = x.clone().requires_grad_(True)
    ssim(x_new, y).backward()
    assert x_new.grad.dtype == torch.float32
    scale = float(x_ref.grad.abs().max())
    assert float((x_new.grad - x_ref.grad).abs().max()) <= 1e-4 * scale


def test_numba_ssim_gradcheck():
    x, y = _pair((12, 13, 2), torch.float64, seed=5)
    x.requires_grad_(True)
    assert _is_numba_path(ssim(x, y))
    assert torch.autograd.gradcheck(lambda t: ssim(t, y), (x,))
    x1, y1 = _pair((8, 9), torch.float64, seed=6)
    x1.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: ssim(t, y1), (x1,))


def test_numba_ssim_non_contiguous_input_and_no_grad():
    x, y = _pair((16, 18, 4), torch.float64, seed=9)
    xs, ys = x[..., :3], y[..., :3]                   # strided views, as a colour slice would be
    assert not xs.is_contiguous()
    want = _torch_ssim(xs, ys)
    assert abs(float(ssim_cpu.ssim_cpu(xs, ys)) - float(want)) <= 1e-12
    with torch.no_grad():
        xg = x.clone().requires_grad_(True)
        assert abs(float(ssim(xg[..., :3], ys)) - float(want)) <= 1e-12


def test_ssim_dispatch_torch_path_when_target_needs_grad():
    x, y = _pair((10, 12, 3), torch.float64, seed=13)
    x.requires_grad_(True)
    y.requires_grad_(True)
    value = ssim(x, y)
    assert not _is_numba_path(value)
    value.backward()
    assert y.grad is not None and float(y.grad.abs().max()) > 0
    assert x.grad is not None
    # Same value as the Numba path computes without the target's gradient.
    assert abs(float(value.detach()) - float(ssim_cpu.ssim_cpu(x.detach(), y.detach()))) <= 1e-12


def test_ssim_dispatch_torch_path_for_mixed_dtypes_and_other_shapes():
    x, y = _pair((10, 12, 3), torch.float64, seed=17)
    assert not _is_numba_path(ssim(x.requires_grad_(True), y.float()))
    with pytest.raises(ValueError):
        ssim_cpu.ssim_cpu(torch.rand(4, 4, 3), torch.rand(4, 5, 3))
    with pytest.raises(ValueError):
        ssim_cpu.ssim_cpu(torch.rand(4, 4, 3), torch.rand(4, 4, 3, requires_grad=True))
