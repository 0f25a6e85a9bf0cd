"""The end-of-run colour fit (mapping.final_color_fit): the map's brightness made the keyframes'
average instead of the latest frames'.

A Gaussian's colour follows the frames that saw it last: with auto-exposure (7-Scenes swings by
~40 % within 300 frames) the map ends at the exposure of the run's last stretch, and every other
frame renders too dark or too bright. After the last frame, one gain g and offset b per channel
are fitted by least squares over every keyframe's pixels,

    min sum_keyframes sum_pixels (g R + b A - O)^2        (R, A: the map's render and silhouette at
                                                           the keyframe's pose; O: its colour)

and applied to every Gaussian (c -> g c + b), which changes each render by exactly g R + b A.
Three numbers per map from the keyframes only: no frame's own exposure enters its evaluation.
Poses are not touched (tracking has finished), so the trajectory is the run's as without it.
"""

from __future__ import annotations

import numpy as np
import torch

from .camera import Intrinsics


class ColorFit:
    """Normal equations of the per-channel fit, accumulated one view at a time."""

    def __init__(self):
        self.sums = np.zeros((3, 5))     # per channel: sum r r, r a, a a, r o, a o
        self.views = 0

    def add(self, rendered: torch.Tensor, alpha: torch.Tensor, observed: torch.Tensor) -> None:
        """rendered, observed: H x W x 3; alpha: H x W (or H x W x 1)."""
        r = rendered.detach().reshape(-1, 3).double().cpu()
        o = observed.detach().reshape(-1, 3).double().cpu()
        a = alpha.detach().reshape(-1, 1).double().cpu()
        self.sums += torch.stack([(r * r).sum(0), (r * a).sum(0), (a * a).sum(0).expand(3), (r * o).sum(0),
                                  (a * o).sum(0)], dim=1).numpy()
        self.views += 1

    def solve(self) -> tuple[np.ndarray, np.ndarray]:
        """Gain (3,) and offset (3,); identity where a channel's system is singular (no views,
        nothing rendered)."""
        gain, offset = np.ones(3), np.zeros(3)
        for c in range(3):
            rr, ra, aa, ro, ao = self.sums[c]
            det = rr * aa - ra * ra
            if self.views == 0 or rr <= 0 or abs(det) <= 1e-12 * max(rr * aa, 1e-300):
                if rr > 0:                 # a silhouette of all ones or zeros: gain only
                    gain[c] = ro / rr
                continue
            gain[c] = (aa * ro - ra * ao) / det
            offset[c] = (rr * ao - ra * ro) / det
        return gain, offset


def fit_map_colors(gmap, views, intrinsics: Intrinsics, renderer) -> dict:
    """Fit the gain and offset over `views` (each with .color H x W x 3 and .w2c) and apply them to
    `gmap`'s colours in place. Returns metrics.json's record: gain, offset, keyframes."""
    fit = ColorFit()
    with torch.no_grad():
        for view in views:
            out = renderer.render_visible(gmap.tensors(detach=True), intrinsics, view.w2c)
            fit.add(out.color, out.alpha, torch.as_tensor(np.asarray(view.color)))
        gain, offset = fit.solve()
        colors = gmap.params["colors"]
        g = torch.as_tensor(gain, dtype=colors.dtype, device=colors.device)
        b = torch.as_tensor(offset, dtype=colors.dtype, device=colors.device)
        colors.data.copy_(colors.data * g + b)
    return dict(gain=[float(x) for x in gain], offset=[float(x) for x in offset], keyframes=fit.views)
