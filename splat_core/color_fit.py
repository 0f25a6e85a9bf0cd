"""The end-of-run colour fit (mapping.final_color_fit): the map's brightness made the run's average
instead of the latest frames'.

A Gaussian's colour follows the frames that saw it last: with auto-exposure (7-Scenes swings by
~40 % within 300 frames) the map ends at the exposure of the run's last stretch, and every other
frame renders too dark or too bright. After the last frame, one gain g and offset b per channel
are fitted by least squares over the pixels of frames kept for it (`FitSamples`),

    min sum_frames sum_pixels (g R + b A - O)^2 + p n ((g - 1)^2 + b^2)
                                     (R, A: the map's render and silhouette at the frame's final pose;
                                      O: its colour; n: the pixels summed; p: final_color_fit_prior)

and applied to every Gaussian (c -> g c + b), which changes each render by exactly g R + b A.

Only if it is borne out on frames it was not fitted to (`ColorFit.held_out_ratio`): the kept frames
split in two (alternate ones), each half's fit scored on the other half, and the fit kept where
those scores' squared error is at most (1 - mapping.final_color_fit_min_improvement) times the
map's own (identity's) on the same frames; else the map is left as it is. The kept frames are not
the map's training views and the evaluated frames are (keyframes fall on them), so the map matches
the kept frames less; least squares answers a small mismatch with a small fit (a lower contrast,
a slight shift) that the evaluated frames do not need: on SUN3D (one exposure) fits that lowered
the kept frames' error by 0.5-4 % lowered the evaluated frames' PSNR by up to 0.16 dB, where
7-Scenes' exposure swings give fits that lower it by far more (docs/history/2026-12-06-7scenes-psnr.md, "Candidate 4").

The frames are held out from the evaluation: render metrics use frame 0 and every eval_every-th
frame (metrics.is_evaluated), and so do the keyframes (keyframes.every, the same rule), so the fit
uses neither: it keeps the frames midway between two evaluated ones (`is_fit_frame`: 2, 7, 12, ...
at eval_every 5), their colour at half the working resolution in 8 bits (57.6 kB a frame at
320x240), at most FIT_FRAMES_MAX of them (past that every other one is let go, evenly over the run).
No evaluated frame's colour enters the fit (with keyframes.every = eval_every, as in the presets,
no keyframe's either, but the second-to-last frame's at some run lengths).
Poses are not touched (tracking has finished), so the trajectory is the run's as without it.
SplaTAM.finish runs it once and publishes the fitted map (slam_checkpoint.py); its checkpoint
keeps the colours from before the fit and the kept frames, so a resumed run fits the same.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from .camera import Intrinsics
from .metrics import is_evaluated

FIT_FRAMES_MAX = 64
FIT_SCALE = 0.5            # the kept colour and the fit's renders: half the working resolution
DEPTH_MM_MAX = 65535      # kept depth: uint16 millimetres


class ColorFit:
    """Normal equations of the per-channel fit, accumulated one view at a time (each view's sums
    kept too, for the held-out test)."""

    def __init__(self):
        self.per_view: list[np.ndarray] = []    # per view, per channel: sum r r, r a, a a, r o, a o, o o; pixels

    @property
    def views(self) -> int:
        return len(self.per_view)

    @property
    def sums(self) -> np.ndarray:
        """3 x 7: the sums over every view."""
        return np.sum(self.per_view, axis=0) if self.per_view else np.zeros((3, 7))

    def add(self, rendered: torch.Tensor, alpha: torch.Tensor, observed: torch.Tensor) -> None:
        """rendered, observed: H x W x 3; alpha: H x W (or H x W x 1)."""
        r = rendered.detach().reshape(-1, 3).double().cpu()
        o = observed.detach().reshape(-1, 3).double().cpu()
        a = alpha.detach().reshape(-1, 1).double().cpu()
        self.per_view.append(torch.stack([(r * r).sum(0), (r * a).sum(0), (a * a).sum(0).expand(3), (r * o).sum(0),
                                          (a * o).sum(0), (o * o).sum(0),
                                          torch.full((3,), float(r.shape[0]), dtype=r.dtype)], dim=1).numpy())

    def solve(self, sums: np.ndarray | None = None, prior: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Gain (3,) and offset (3,) of `sums` (default: every view's), pulled towards identity by
        `prior` per pixel; identity where a channel's system is singular (no views, nothing rendered)."""
        sums = self.sums if sums is None else sums
        gain, offset = np.ones(3), np.zeros(3)
        for c in range(3):
            rr, ra, aa, ro, ao = sums[c, :5]
            weight = prior * sums[c, 6]
            rr, aa, ro = rr + weight, aa + weight, ro + weight
            det = rr * aa - ra * ra
            if rr <= 0 or abs(det) <= 1e-12 * max(rr * aa, 1e-300):
                if rr > 0:                 # a silhouette of all ones or zeros: gain only
                    gain[c] = ro / rr
                continue
            gain[c] = (aa * ro - ra * ao) / det
            offset[c] = (rr * ao - ra * ro) / det
        return gain, offset

    def held_out_ratio(self, prior: float = 0.0) -> float:
        """The fit's squared error on frames it was not fitted to over the map's own there: the
        views split into alternate halves, each half's fit scored on the other half (two-fold);
        1.0 with fewer than two views (nothing to hold out)."""
        if self.views < 2:
            return 1.0
        halves = [np.sum(self.per_view[0::2], axis=0), np.sum(self.per_view[1::2], axis=0)]
        fitted = identity = 0.0
        for fit_on, score_on in ((0, 1), (1, 0)):
            gain, offset = self.solve(halves[fit_on], prior)
            fitted += float(squared_error(halves[score_on], gain, offset).sum())
            identity += float(squared_error(halves[score_on], np.ones(3), np.zeros(3)).sum())
        return fitted / identity if identity > 0 else 1.0


def squared_error(sums: np.ndarray, gain: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Per channel, sum (g r + b a - o)^2 from a view set's sums (3 x 7)."""
    rr, ra, aa, ro, ao, oo = sums.T[:6]
    return gain * gain * rr + 2 * gain * offset * ra + offset * offset * aa - 2 * gain * ro - 2 * offset * ao + oo


def _midway(t: int, eval_every: int) -> tuple[int, int]:
    """(the ordinal of the gap between evaluated frames that frame t falls midway in, and whether it does)."""
    every = max(1, eval_every)
    ordinal, rest = divmod(t + 1 + every // 2, every)
    return ordinal, rest == 0


def is_fit_frame(t: int, eval_every: int) -> bool:
    """Processed frame t is kept for the fit: midway between two evaluated frames, never one."""
    return _midway(t, eval_every)[1] and not is_evaluated(t, eval_every)


class FitSamples:
    """The fit's frames: their processed index and colour (uint8, FIT_SCALE of the working size),
    and with `keep_depth` (mapping.final_hole_fill: final_holes.py) their depth too (uint16
    millimetres, the same size, nearest neighbour; 0: invalid, and so beyond 65.5 m). Offered every
    frame by the tracking side (SplaTAM.track); bounded by thinning: past FIT_FRAMES_MAX, only every
    2nd, then 4th, ... fit frame of the run is kept."""

    def __init__(self, intrinsics: Intrinsics, eval_every: int, keep_depth: bool = False):
        self.intrinsics = intrinsics.fraction(FIT_SCALE)
        self.eval_every = eval_every
        self.keep_depth = keep_depth
        self.kept: list[tuple[int, np.ndarray]] = []     # (frame, colour); replaced, never edited, when thinned
        self.depths: dict[int, np.ndarray] = {}          # frame -> depth (keep_depth), the frames of `kept`
        self.stride = 1

    def __len__(self) -> int:
        return len(self.kept)

    @property
    def frames(self) -> list[int]:
        return [t for t, _ in self.kept]

    def _ordinal(self, t: int) -> int:
        return _midway(t, self.eval_every)[0]

    def offer(self, t: int, color: np.ndarray, depth: np.ndarray | None = None) -> None:
        """Frame t's colour (H x W x 3 in [0, 1], the working resolution) and depth (H x W metres;
        kept with keep_depth), kept if it is a fit frame."""
        if not is_fit_frame(t, self.eval_every) or self._ordinal(t) % self.stride:
            return
        import cv2

        size = (self.intrinsics.width, self.intrinsics.height)
        small = cv2.resize(np.asarray(color, np.float32), size, interpolation=cv2.INTER_AREA)
        kept = self.kept + [(t, np.clip(np.rint(small * 255.0), 0, 255).astype(np.uint8))]
        if self.keep_depth and depth is not None:
            mm = np.rint(cv2.resize(np.asarray(depth, np.float32), size, interpolation=cv2.INTER_NEAREST) * 1000.0)
            self.depths[t] = np.where((mm > 0) & (mm <= DEPTH_MM_MAX), mm, 0).astype(np.uint16)
        if len(kept) > FIT_FRAMES_MAX:
            self.stride *= 2
            kept = [(f, c) for f, c in kept if self._ordinal(f) % self.stride == 0]
        self.kept = kept
        self.depths = {f: self.depths[f] for f, _ in kept if f in self.depths}

    def drop(self, t: int) -> None:
        """Forget frame t (the live engine tracks it again: SplaTAM.retract)."""
        if self.kept and self.kept[-1][0] == t:
            self.kept = self.kept[:-1]
            self.depths.pop(t, None)

    def views(self, w2cs: list, lost) -> list:
        """The kept frames at their poses now (a loop correction moves them); `lost(t)`: a reason
        when frame t's pose was not tracked (left out). `.depth`: metres, or None (not kept)."""
        return [SimpleNamespace(frame_index=t, w2c=w2cs[t], color=c.astype(np.float32) / 255.0,
                                depth=self.depths[t].astype(np.float32) / 1000.0 if t in self.depths else None)
                for t, c in self.kept if t < len(w2cs) and lost(t) is None]

    def to_arrays(self, frames: int) -> dict:
        """The samples of frames 0 .. frames-1 (a checkpoint's; the live mapper's is of an earlier frame)."""
        kept = [(t, c) for t, c in self.kept if t < frames]
        h, w = self.intrinsics.height, self.intrinsics.width
        arrays = dict(fit_frames=np.array([t for t, _ in kept], np.int64), fit_stride=np.array(self.stride),
                      fit_colors=np.stack([c for _, c in kept]) if kept else np.zeros((0, h, w, 3), np.uint8))
        if self.keep_depth:
            with_depth = [t for t, _ in kept if t in self.depths]
            arrays["fit_depth_frames"] = np.array(with_depth, np.int64)
            arrays["fit_depths"] = (np.stack([self.depths[t] for t in with_depth]) if with_depth
                                    else np.zeros((0, h, w), np.uint16))
        return arrays

    def load_arrays(self, arrays: dict) -> None:
        frames = [int(t) for t in arrays.get("fit_frames", ())]
        self.kept = list(zip(frames, np.asarray(arrays["fit_colors"]))) if frames else []
        self.stride = int(arrays.get("fit_stride", 1))
        # a checkpoint without depths (made with final_hole_fill off): the hole fill skips those frames
        with_depth = [int(t) for t in arrays.get("fit_depth_frames", ())] if self.keep_depth else []
        self.depths = dict(zip(with_depth, np.asarray(arrays["fit_depths"]))) if with_depth else {}


def fit_map_colors(gmap, views, intrinsics: Intrinsics, renderer, min_improvement: float | None = None,
                   prior: float = 0.0) -> dict:
    """Fit the gain and offset over `views` (each with .color H x W x 3 at `intrinsics`, .w2c and
    .frame_index; pulled towards identity by `prior`, ColorFit.solve) and apply them to `gmap`'s
    colours in place if, on held-out views, the fit lowers the squared error by at least
    `min_improvement` (a fraction; None or 0: always applied). Returns
    metrics.json's record: gain and offset applied (identity when not kept), fitted_gain and
    fitted_offset, held_out_ratio (ColorFit.held_out_ratio), kept, views (how many) and frames
    (their indices)."""
    fit = ColorFit()
    with torch.no_grad():
        for view in views:
            out = renderer.render_visible(gmap.tensors(detach=True), intrinsics, view.w2c)
            fit.add(out.color, out.alpha, torch.as_tensor(np.asarray(view.color)))
        fitted_gain, fitted_offset = fit.solve(prior=prior)
        ratio = fit.held_out_ratio(prior)
        kept = min_improvement is None or min_improvement <= 0 or ratio <= 1.0 - min_improvement
        gain, offset = (fitted_gain, fitted_offset) if kept else (np.ones(3), np.zeros(3))
        if kept:
            colors = gmap.params["colors"]
            g = torch.as_tensor(gain, dtype=colors.dtype, device=colors.device)
            b = torch.as_tensor(offset, dtype=colors.dtype, device=colors.device)
            colors.data.copy_(colors.data * g + b)
    as_list = lambda x: [float(v) for v in x]  # noqa: E731
    return dict(gain=as_list(gain), offset=as_list(offset), fitted_gain=as_list(fitted_gain),
                fitted_offset=as_list(fitted_offset), held_out_ratio=ratio, kept=bool(kept), views=fit.views,
                frames=[int(v.frame_index) for v in views])
