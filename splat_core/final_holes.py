"""The end-of-run hole fill (mapping.final_hole_fill): Gaussians where the frames kept for the
end-of-run fits have no valid depth and the finished map is empty, so a screen or a dark, shiny
patch the depth camera misses does not render black.

After the last frame, over the frames kept midway between evaluated ones (color_fit.FitSamples,
which keeps their depth too when this is on; never an evaluated frame), at their final poses:
  1. each frame in turn: the map rendered; pixels without valid depth, with a valid depth within
     final_hole_fill x the image width, where the silhouette is below densify.silhouette_threshold
     (densify.hole_pixel_mask) get a Gaussian at the farthest such depth (densify.filled_depth),
     with the frame's colour and opacity final_hole_fill_opacity (densify.gaussians_from_pixels);
     the next frame sees them, so two frames of one hole do not both fill it;
  2. only those new Gaussians optimised (colour, opacity and scale; positions and every other
     Gaussian frozen) for final_hole_fill_iterations passes over the same frames, L1 colour
     against each frame's render of the map, in frame order (deterministic: no sampling), over the
     part of the frame the new Gaussians reach (its own crop: what they change, at its cost);
  3. new Gaussians left nearly transparent (mapping.prune_opacity) removed.
New Gaussians are appended after the map's, so the map before the pass is its first n Gaussians
(SplaTAM.finish keeps n in the checkpoint). Tracking has finished: no pose moves, and a frame
without holes in front of an empty map adds nothing.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from .camera import Intrinsics
from .densify import filled_depth, gaussians_from_pixels, hole_pixel_mask
from .gaussians import PARAM_NAMES, Gaussians, GaussianMap
from .render.project import frustum_mask

OPTIMISED = ("colors", "logit_opacities", "log_scales")


def add_hole_gaussians(gmap: GaussianMap, views, intrinsics: Intrinsics, renderer, fraction: float, densify,
                       isotropic: bool) -> list[int]:
    """Step 1 on `gmap` in place (views: .color H x W x 3, .depth H x W in metres or None, .w2c,
    .frame_index at `intrinsics`). Returns the number added per view."""
    added = []
    for view in views:
        if view.depth is None:
            added.append(0)
            continue
        depth = np.asarray(view.depth, np.float32)
        filled = filled_depth(depth, fraction)
        if not ((depth <= 0) & (filled > 0)).any():
            added.append(0)
            continue
        silhouette = None
        if len(gmap):
            with torch.no_grad():
                silhouette = renderer.render_visible(gmap.tensors(detach=True), intrinsics, view.w2c).alpha
            silhouette = silhouette.reshape(depth.shape).cpu().numpy()
        mask = hole_pixel_mask(depth, filled, silhouette, densify)
        if mask.any():
            gmap.append(gaussians_from_pixels(np.asarray(view.color, np.float32), filled, mask, intrinsics,
                                              view.w2c, int(view.frame_index), densify, isotropic,
                                              device=gmap.device, dtype=gmap.dtype))
        added.append(int(mask.sum()))
    return added


def _crop(new: Gaussians, intrinsics: Intrinsics, w2c, renderer, margin: int) -> Intrinsics | None:
    """The part of the image that `new` (rendered alone) reaches at w2c, `margin` pixels wider, as
    intrinsics of its own (pixel (r, c) of the crop is pixel (r + top, c + left) of the image)."""
    with torch.no_grad():
        alpha = renderer.render(new, intrinsics, w2c).alpha.reshape(intrinsics.height, intrinsics.width)
    rows, cols = torch.nonzero(alpha > 1.0 / 255.0, as_tuple=True)
    if rows.numel() == 0:
        return None
    top, left = max(0, int(rows.min()) - margin), max(0, int(cols.min()) - margin)
    bottom = min(intrinsics.height, int(rows.max()) + 1 + margin)
    right = min(intrinsics.width, int(cols.max()) + 1 + margin)
    return Intrinsics(intrinsics.fx, intrinsics.fy, intrinsics.cx - left, intrinsics.cy - top, right - left,
                      bottom - top)


def optimise_new(gmap: GaussianMap, first: int, views, intrinsics: Intrinsics, renderer, passes: int,
                 lrs: dict, margin: int = 8) -> int:
    """Step 2: Gaussians first.. of `gmap` optimised over `views` (`passes` times each, in order),
    the others frozen. Each view renders only the part of its image the new Gaussians reach (with
    `margin` pixels around) and the map's Gaussians in front of or behind that part: the same pixels
    as the whole image's render there, at the cost of that part. Returns the optimisation steps."""
    if passes <= 0 or first >= len(gmap) or not views:
        return 0
    near = renderer.near
    old = Gaussians(*(gmap.params[n].detach()[:first] for n in PARAM_NAMES))
    new = GaussianMap(*(gmap.params[n].detach()[first:] for n in PARAM_NAMES), gmap.birth_frame[first:])
    parts = []          # per view that sees new Gaussians: its crop, pose, observed colour, old and new indices
    for view in views:
        seen = torch.nonzero(frustum_mask(new.means.detach(), new.log_scales.detach(), intrinsics, view.w2c,
                                          near)).flatten()
        if seen.numel() == 0:
            continue
        crop = _crop(new.tensors(detach=True).select(seen), intrinsics, view.w2c, renderer, margin)
        if crop is None:
            continue
        top, left = int(round(intrinsics.cy - crop.cy)), int(round(intrinsics.cx - crop.cx))
        observed = np.asarray(view.color)[top:top + crop.height, left:left + crop.width]
        behind = torch.nonzero(frustum_mask(old.means, old.log_scales, crop, view.w2c, near)).flatten()
        parts.append((crop, view.w2c, torch.as_tensor(np.ascontiguousarray(observed), dtype=old.means.dtype), behind,
                      seen))
    optimizer = torch.optim.Adam([{"params": [new.params[n]], "lr": float(lrs[n])} for n in OPTIMISED], eps=1e-15)
    steps = 0
    for _ in range(passes):
        for crop, w2c, observed, behind, seen in parts:
            scene = Gaussians(*(torch.cat([getattr(old, n).index_select(0, behind), new.params[n][seen]])
                                for n in PARAM_NAMES))
            out = renderer.render(scene, crop, w2c)
            loss = torch.abs(out.color - observed.to(out.color.device)).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            steps += 1
    with torch.no_grad():
        for n in OPTIMISED:
            gmap.params[n].data[first:] = new.params[n].detach()
    return steps


def fill_final_holes(gmap: GaussianMap, views, intrinsics: Intrinsics, renderer, config) -> dict:
    """Steps 1-3 (`config`: the run's Config) on `gmap` in place; metrics.json's record: added (after
    pruning), pruned, per_view (added per frame), frames, steps, seconds."""
    start = time.perf_counter()
    mapping = config.mapping
    views = [v for v in views if getattr(v, "depth", None) is not None]
    first = len(gmap)
    densify = dataclasses.replace(config.densify, initial_opacity=mapping.final_hole_fill_opacity)
    per_view = add_hole_gaussians(gmap, views, intrinsics, renderer, mapping.final_hole_fill, densify,
                                  config.isotropic)
    steps = optimise_new(gmap, first, views, intrinsics, renderer, mapping.final_hole_fill_iterations, mapping.lrs)
    keep = torch.ones(len(gmap), dtype=torch.bool, device=gmap.device)
    with torch.no_grad():
        keep[first:] = gmap.opacities()[first:] >= mapping.prune_opacity
    pruned = gmap.prune(keep) if not bool(keep.all()) else 0
    return dict(added=len(gmap) - first, pruned=int(pruned), per_view=per_view,
                frames=[int(v.frame_index) for v in views], steps=steps, seconds=time.perf_counter() - start)
