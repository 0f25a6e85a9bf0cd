"""The end-of-run refinement (mapping.final_refine): the finished map optimised over all keyframes.

During the run a Gaussian is optimised only while its part of the scene is in the mapping window
(the current frame and a few overlapping keyframes), so each part of the map ends fitted to the
frames that saw it last. After the last frame, with tracking finished (no pose moves), the map is
optimised over every keyframe at its final pose: `final_refine` passes, each a fresh permutation of
the keyframes drawn from (seed, pass), one keyframe per Adam step, the mapping loss
(mapping.mapping_loss) on the whole image, every Gaussian parameter at the refine rates
(REFINE_LRS over the mapping rates), no densification.

Kept only if frames it did not train on bear it out: the frames kept midway between evaluated ones
(color_fit.FitSamples: never a keyframe or an evaluated frame) are rendered before and after, and
the refined map is kept only where their mean squared colour error is lower; else every parameter
is put back. One pass: PSNR +1.9 / +2.5 dB on 7-Scenes 300 / 600, +0.2 / +0.6 on the SUN3D
fragments, +1.1 on the synthetic scene, the held-out frames rising with it (docs/benchmarks.md,
"The end-of-run refinement"). The keyframes are read one at a time (`view_of`): a long run's
hundreds of keyframes are not all decoded at once.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch

from .camera import Intrinsics
from .gaussians import GaussianMap
from .mapping import View, mapping_loss

# Higher than SLAM's mapping rates: a refine has hundreds of steps, not 3DGS's 30k, to move colours
# and sizes (100 iterations on SUN3D fragment 1 at 640x480: +1.6 dB with these and density control,
# +0.9 dB with the mapping rates and none; docs/refine.md). `splatam refine` uses them too.
REFINE_LRS = dict(means=2e-4, colors=1e-2, log_scales=5e-3)


def keyframe_order(count: int, iteration: int, seed: int) -> int:
    """The keyframe of step `iteration`: a fresh permutation of `count` keyframes per pass, drawn
    from (seed, pass), so a resumed refine draws the same."""
    passes, position = divmod(iteration, count)
    return int(np.random.default_rng([seed, passes]).permutation(count)[position])


def held_out_error(gmap: GaussianMap, views, intrinsics: Intrinsics, renderer) -> float:
    """Mean squared colour error of `gmap` rendered at the held-out `views` (.color H x W x 3, .w2c)."""
    errors = []
    with torch.no_grad():
        for view in views:
            out = renderer.render_visible(gmap.tensors(detach=True), intrinsics, view.w2c)
            observed = torch.as_tensor(np.asarray(view.color), dtype=out.color.dtype, device=out.color.device)
            errors.append(float(torch.mean((out.color - observed) ** 2)))
    return float(np.mean(errors))


def refine_final_map(gmap: GaussianMap, keyframes: list, view_of: Callable[..., View],
                     intrinsics: Intrinsics, held_out_views, held_out_intrinsics: Intrinsics, renderer,
                     config) -> dict:
    """The refinement above on `gmap` in place (`view_of(keyframe)`: its View at its final pose;
    `config`: the run's Config); metrics.json's record: steps, keyframes, held-out PSNR before and
    after, kept, held_out_frames, seconds."""
    start = time.perf_counter()
    mapping = config.mapping
    steps = int(round(mapping.final_refine * len(keyframes)))
    before = held_out_error(gmap, held_out_views, held_out_intrinsics, renderer)
    saved = {name: p.detach().clone() for name, p in gmap.params.items()}
    optimizer = gmap.adam({**mapping.lrs, **REFINE_LRS})
    for step in range(steps):
        view = view_of(keyframes[keyframe_order(len(keyframes), step, config.seed)])
        loss = mapping_loss(renderer.render(gmap.tensors(), intrinsics, view.w2c), view, mapping)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    after = held_out_error(gmap, held_out_views, held_out_intrinsics, renderer)
    kept = after < before
    if not kept:
        with torch.no_grad():
            for name, p in gmap.params.items():
                p.copy_(saved[name])
    psnr = lambda mse: float(-10.0 * np.log10(max(mse, 1e-12)))  # noqa: E731
    return dict(steps=steps, keyframes=len(keyframes), held_out_psnr_before=psnr(before),
                held_out_psnr_after=psnr(after), kept=bool(kept), held_out_frames=len(held_out_views),
                seconds=time.perf_counter() - start)
