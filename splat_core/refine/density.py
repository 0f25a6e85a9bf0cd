"""Adaptive density control, as the 3D Gaussian splatting paper describes it (Kerbl et al. 2023, §5.2).

Over the iterations between two densification steps, each Gaussian accumulates the norm of its
view-space positional gradient (the gradient of the loss w.r.t. its projected centre, in
normalised device coordinates) in every view where it is drawn. At a densification step, the
Gaussians whose average exceeds `grad_threshold` are in regions the map does not explain yet:
    small ones (largest scale <= percent_dense x scene extent): under-reconstruction, so they are
        cloned (a copy at the same place; the next steps move the two apart);
    large ones: over-reconstruction, so they are split into two, placed by sampling the original
        Gaussian as a probability density, with scales divided by `split_factor` (1.6).
Then nearly transparent and oversized Gaussians are pruned (mapping.prune_mask, as in SLAM).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..camera import quat_to_rotmat
from ..config import MappingConfig
from ..gaussians import PARAM_NAMES, GaussianMap
from ..mapping import prune_mask


@dataclass
class DensitySettings:
    grad_threshold: float = 0.0002    # average view-space gradient norm (NDC units, as 3DGS)
    percent_dense: float = 0.01       # clone below, split above this fraction of the scene extent
    split_factor: float = 1.6         # a split Gaussian's children have scale / split_factor


class GradientStats:
    """Per-Gaussian sum and count of view-space positional gradient norms since the last reset."""

    def __init__(self, n: int, device="cpu"):
        self.grad_sum = torch.zeros(n, dtype=torch.float64, device=device)
        self.count = torch.zeros(n, dtype=torch.int64, device=device)

    def add(self, screen: list, width: int, height: int) -> None:
        """Accumulate from `render(..., screen=...)`'s (means2d, radii) once backward has run."""
        with torch.no_grad():
            for means2d, radii in screen:
                n = self.count.numel()
                grad = means2d.grad.reshape(n, 2)
                drawn = radii.reshape(n, -1).amax(dim=1) > 0
                # Pixels to NDC: u_ndc = 2 u / W - 1, so dL/du_ndc = dL/du * W / 2.
                norm = torch.hypot(grad[:, 0] * (0.5 * width), grad[:, 1] * (0.5 * height)).to(torch.float64)
                self.grad_sum += torch.where(drawn, norm, torch.zeros_like(norm))
                self.count += drawn.to(torch.int64)

    def average(self) -> torch.Tensor:
        return self.grad_sum / self.count.clamp(min=1)

    def to_arrays(self) -> dict:
        return {"grad_sum": self.grad_sum.cpu().numpy(), "grad_count": self.count.cpu().numpy()}

    @classmethod
    def from_arrays(cls, arrays: dict, device="cpu") -> "GradientStats":
        stats = cls(0, device)
        stats.grad_sum = torch.as_tensor(arrays["grad_sum"], device=device)
        stats.count = torch.as_tensor(arrays["grad_count"], device=device)
        return stats


def _subset(m: GaussianMap, index: torch.Tensor, **replace) -> GaussianMap:
    values = [replace.get(n, m.params[n].detach()[index]) for n in PARAM_NAMES]
    return GaussianMap(*values, m.birth_frame[index.cpu()])


def split_children(m: GaussianMap, index: torch.Tensor, factor: float, rng: np.random.Generator) -> GaussianMap:
    """Two children per Gaussian in `index`: centres sampled from it, scales divided by `factor`."""
    index = index.repeat(2)
    scales = torch.exp(m.log_scales.detach()[index]).expand(len(index), 3)
    noise = torch.as_tensor(rng.standard_normal((len(index), 3)), dtype=m.dtype, device=m.device)
    offsets = noise * scales
    if not m.isotropic:    # the anisotropic Gaussian's axes are its rotation's columns
        offsets = (quat_to_rotmat(m.rotations.detach()[index]) @ offsets[:, :, None])[:, :, 0]
    means = m.means.detach()[index] + offsets
    log_scales = m.log_scales.detach()[index] - float(np.log(factor))
    return _subset(m, index, means=means, log_scales=log_scales)


def densify_and_prune(m: GaussianMap, optimizer: torch.optim.Optimizer, stats: GradientStats,
                      settings: DensitySettings, prune: MappingConfig, scene_radius: float,
                      rng: np.random.Generator) -> dict:
    """Clone, split, then prune `m` in place (keeping `optimizer`'s moments aligned); returns counts."""
    with torch.no_grad():
        n = len(m)
        candidates = stats.average() >= settings.grad_threshold
        small = torch.exp(m.log_scales.detach()).amax(dim=1) <= settings.percent_dense * scene_radius
        clone = torch.nonzero(candidates & small).flatten()
        split = torch.nonzero(candidates & ~small).flatten()
        children = split_children(m, split, settings.split_factor, rng)
        m.append(_subset(m, clone), optimizer)
        m.append(children, optimizer)
        parents = torch.zeros(len(m), dtype=torch.bool, device=m.device)
        parents[split] = True
        keep = prune_mask(m, prune, scene_radius) & ~parents
        pruned = m.prune(keep, optimizer) - len(split)
    return {"cloned": int(clone.numel()), "split": int(split.numel()), "pruned": pruned, "before": n,
            "after": len(m)}
