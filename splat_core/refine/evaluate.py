"""Held-out image metrics of a map: PSNR, SSIM and depth L1 (cm), means over the given views."""

from __future__ import annotations

from typing import Iterable

import numpy as np
import torch

from .. import metrics as M
from ..camera import Intrinsics
from ..gaussians import Gaussians
from ..mapping import View
from ..render import Renderer


def heldout_metrics(gaussians: Gaussians, views: Iterable[View], intr: Intrinsics, renderer: Renderer) -> dict:
    psnrs, ssims, depth_l1s = [], [], []
    for view in views:
        with torch.no_grad():
            out = renderer.render_visible(gaussians, intr, view.w2c)
        psnrs.append(M.psnr(out.color, view.color))
        ssims.append(M.ssim_metric(out.color, view.color))
        depth_l1s.append(M.depth_l1(out.depth, view.depth))
    if not psnrs:
        return dict(frames=0, psnr=None, ssim=None, depth_l1_cm=None)
    return dict(frames=len(psnrs), psnr=float(np.mean(psnrs)), ssim=float(np.mean(ssims)),
                depth_l1_cm=100.0 * float(np.nanmean(depth_l1s)))
