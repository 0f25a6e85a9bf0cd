"""Tracking: optimise one frame's camera pose against the fixed map.

Only the 7 pose numbers (w2c quaternion + translation) are optimised, with a small Adam. The
loss uses the pixels the map already explains (silhouette > 0.99) with valid depth:
    L = w_d sum |D - D_hat| + w_c sum |C - C_hat|        (sums, as in SplaTAM)
The best pose is the one with the lowest loss, snapshotted *before* the step that follows it
(the original snapshots after stepping; `compat_post_step_candidate` reproduces that). A pose
qualifies only if it still sees at least half as many loss pixels as the starting pose: a sum
over fewer pixels is smaller without being better, and a pose that looks away from the map
would otherwise "win" with a loss of zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .camera import Intrinsics, pose_matrix, quat_to_rotmat_np, rotmat_to_quat, w2c_from_quat_trans
from .config import TrackingConfig
from .gaussians import Gaussians
from .render import render


@dataclass
class TrackResult:
    w2c: np.ndarray
    loss: float           # best loss (the sum above)
    iterations: int
    valid_pixels: int     # pixels in the loss mask at the best pose


def tracking_loss(rendered, color: torch.Tensor, depth: torch.Tensor, config: TrackingConfig):
    """(loss, mask) with mask = valid depth and silhouette above the threshold (detached)."""
    mask = (depth > 0) & (rendered.alpha.detach() > config.silhouette_threshold)
    error = torch.abs(depth - rendered.depth)
    if config.outlier_factor is not None and bool(mask.any()):
        # Depth outliers (sensor edges, moving objects) would pull the pose; SplaTAM's optional rule.
        mask = mask & (error.detach() < config.outlier_factor * error.detach()[mask].median())
    m = mask.to(depth.dtype)
    depth_term = (error * m).sum()
    color_term = (torch.abs(color - rendered.color) * m[..., None]).sum()
    return config.depth_weight * depth_term + config.color_weight * color_term, mask, depth_term


def loss_and_pixels(rendered, color: torch.Tensor, depth: torch.Tensor, config: TrackingConfig) -> tuple[float, int]:
    """The tracking loss of a rendering (no gradient) and the number of pixels in it."""
    with torch.no_grad():
        loss, mask, _ = tracking_loss(rendered, color, depth, config)
        return float(loss), int(mask.sum())


def evaluate_loss(gaussians: Gaussians, color: torch.Tensor, depth: torch.Tensor, intr: Intrinsics,
                  w2c: np.ndarray, config: TrackingConfig, near: float = 0.01) -> tuple[float, int]:
    """The tracking loss of one pose (no optimisation) and the number of pixels in it."""
    with torch.no_grad():
        return loss_and_pixels(render(gaussians, intr, w2c, near=near), color, depth, config)


def beats(loss: float, pixels: int, loss_ref: float, pixels_ref: int) -> bool:
    """A pose beats a reference pose with a lower loss per pixel over at least half as many pixels."""
    return 2 * pixels >= pixels_ref and loss * pixels_ref <= loss_ref * pixels


def track(gaussians: Gaussians, color: torch.Tensor, depth: torch.Tensor, intr: Intrinsics,
          w2c_init: np.ndarray, config: TrackingConfig, near: float = 0.01,
          fallback: tuple[np.ndarray, float, int] | None = None) -> TrackResult:
    """Optimise the w2c pose of an observation (colour H x W x 3, depth H x W at `intr`).

    fallback: (w2c, loss, pixels) of another start, its loss computed at `intr` (e.g. the
    prediction that an alignment produced w2c_init from). If w2c_init does not beat it (`beats`),
    the optimisation starts from the fallback instead; the check costs no extra rendering."""
    dtype, device = gaussians.means.dtype, gaussians.means.device
    q = torch.tensor(rotmat_to_quat(w2c_init[:3, :3]), dtype=dtype, device=device, requires_grad=True)
    t = torch.tensor(w2c_init[:3, 3], dtype=dtype, device=device, requires_grad=True)
    optimizer = torch.optim.Adam([{"params": [q], "lr": config.lr_rotation},
                                  {"params": [t], "lr": config.lr_translation}])
    best = (float("inf"), q.detach().clone(), t.detach().clone(), 0)
    budget, extended, done = config.iterations, False, 0
    while done < budget:
        w2c = w2c_from_quat_trans(q, t)
        out = render(gaussians, intr, w2c, near=near)
        loss, mask, depth_term = tracking_loss(out, color, depth, config)
        value, valid = float(loss.detach()), int(mask.sum())
        if fallback is not None:
            w2c_fb, loss_fb, valid_fb = fallback
            fallback = None
            if not beats(value, valid, loss_fb, valid_fb):
                with torch.no_grad():
                    q.copy_(torch.as_tensor(rotmat_to_quat(w2c_fb[:3, :3]), dtype=dtype))
                    t.copy_(torch.as_tensor(w2c_fb[:3, 3], dtype=dtype))
                continue
        if done == 0:
            min_valid = max(1, valid // 2)
        if valid < min_valid:
            value = float("inf")
        if not config.compat_post_step_candidate and value < best[0]:
            best = (value, q.detach().clone(), t.detach().clone(), valid)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        q_before, t_before = q.detach().clone(), t.detach().clone()
        optimizer.step()
        if config.compat_post_step_candidate and value < best[0]:
            best = (value, q.detach().clone(), t.detach().clone(), valid)
        done += 1
        if config.early_stop_tolerance > 0:
            step = max(float((t.detach() - t_before).abs().max()), float((q.detach() - q_before).abs().max()))
            if step < config.early_stop_tolerance:
                break
        if done == budget and config.depth_loss_threshold is not None and not extended:
            per_pixel = float(depth_term) / max(int(mask.sum()), 1)
            if per_pixel > config.depth_loss_threshold:
                budget, extended = 2 * budget, True
    _, q_best, t_best, valid = best
    w2c = pose_matrix(quat_to_rotmat_np(q_best.cpu().numpy().astype(np.float64)),
                      t_best.cpu().numpy().astype(np.float64))
    return TrackResult(w2c=w2c, loss=best[0], iterations=done, valid_pixels=valid)
