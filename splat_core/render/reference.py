"""Dense pure-torch compositing: the oracle the fast backends are tested against.

Every pixel looks at every Gaussian (N x P memory), so this is for tiny scenes only. It applies
the 3DGS compositing rules literally (docs/design.md, the renderer contract) and lets torch autograd do the backward.
"""

from __future__ import annotations

import torch

from ._constants import ALPHA_MAX, ALPHA_MIN, T_MIN


def rasterize_reference(means2d, conics, opacities, features, depths, radii, width, height):
    """Composite screen-space Gaussians front to back.

    means2d N x 2, conics N x 3, opacities N, features N x C, depths N (sort key), radii N
    (0 = culled). Returns (H x W x C feature image, H x W accumulated alpha).
    """
    dtype, device = means2d.dtype, means2d.device
    C = features.shape[1]
    live = torch.nonzero(radii > 0).flatten()
    if live.numel() == 0:
        return (torch.zeros(height, width, C, dtype=dtype, device=device) + 0 * features.sum(),
                torch.zeros(height, width, dtype=dtype, device=device) + 0 * opacities.sum())
    order = live[torch.argsort(depths.detach()[live], stable=True)]
    m, q, o, f = means2d[order], conics[order], opacities[order], features[order]

    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=device),
                          torch.arange(width, dtype=dtype, device=device), indexing="ij")
    dx = m[:, 0, None] - u.reshape(1, -1)                    # N x P
    dy = m[:, 1, None] - v.reshape(1, -1)
    power = -0.5 * (q[:, 0, None] * dx * dx + q[:, 2, None] * dy * dy) - q[:, 1, None] * dx * dy
    alpha = torch.clamp(o[:, None] * torch.exp(power), max=ALPHA_MAX)
    used = (power <= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(used, alpha, torch.zeros_like(alpha))

    after = torch.cumprod(1.0 - alpha, dim=0)               # transmittance after each Gaussian
    before = torch.cat([torch.ones_like(after[:1]), after[:-1]], dim=0)
    # Compositing stops at the first Gaussian that would push transmittance below T_MIN; since
    # transmittance only decreases, the kept Gaussians are a prefix.
    kept = (after >= T_MIN).to(dtype)
    weights = alpha * before * kept                          # N x P
    image = (weights.T @ f).reshape(height, width, C)
    acc = weights.sum(0).reshape(height, width)
    return image, acc
