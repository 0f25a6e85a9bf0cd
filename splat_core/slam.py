"""SplaTAM: dense RGB-D SLAM with 3D Gaussians. `process(frame)` is one step of the paper:

    w2c0   = predict(previous poses)            constant velocity
    w2c    = track(frame, map, w2c0)            silhouette-masked L1, keep the best pose
    new    = densify(frame, map, w2c)           silhouette < 0.5 or new geometry in front
    window = keyframes.select(frame, w2c)       current + latest keyframe + overlapping ones
    optimise_map(map, window)                   L1 + SSIM, prune transparent / huge
    keyframes.add(frame, w2c)                   every n-th frame
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from .camera import Intrinsics, invert_pose, predict_constant_velocity
from .config import Config
from .direct_align import align_to_map
from .densify import gaussians_from_pixels, new_pixel_mask
from .frame import Frame, resize_to
from .gaussians import GaussianMap, Gaussians
from .keyframes import KeyframeStore, is_keyframe_time
from .mapping import View, frustum_mask, optimise_map
from .render import render
from .tracking import beats, evaluate_loss, loss_and_pixels, track


@dataclass
class FrameResult:
    index: int                    # processed-frame number (0 = first frame, the world origin)
    timestamp: float
    w2c: np.ndarray               # estimated pose, 4 x 4
    is_keyframe: bool
    num_gaussians: int
    num_added: int
    num_pruned: int
    tracking_seconds: float
    mapping_seconds: float
    tracking_loss: float | None
    tracking_iterations: int = 0
    source_index: int = 0         # frame number in the capture
    frame: Frame | None = field(default=None, repr=False)   # the frame at working resolution

    @property
    def c2w(self) -> np.ndarray:
        return invert_pose(self.w2c)


class SplaTAM:
    def __init__(self, config: Config, intrinsics: Intrinsics, device="cpu", dtype=torch.float32):
        self.config = config
        self.intrinsics = intrinsics
        self.device, self.dtype = torch.device(device), dtype
        self.track_intrinsics = self._scaled(config.tracking.resolution_scale)
        self.densify_intrinsics = self._scaled(config.densify.resolution_scale)
        self.map = GaussianMap.empty(config.isotropic, device=self.device, dtype=dtype)
        self.keyframes = KeyframeStore(config.keyframes, intrinsics)
        self.w2cs: list[np.ndarray] = []
        self.scene_radius: float | None = None
        self.rng = np.random.default_rng(config.seed)
        self.total_frames: int | None = None     # lets the second-to-last frame become a keyframe

    def _scaled(self, s: float) -> Intrinsics:
        i = self.intrinsics
        return i if s == 1 else i.scaled(max(1, round(i.width * s)), max(1, round(i.height * s)))

    def _tensor(self, a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

    # ------------------------------------------------------------------ one SLAM step
    def process(self, frame: Frame, w2c_given: np.ndarray | None = None) -> FrameResult:
        """Track, densify, map and maybe keep `frame` (at the working resolution).

        `w2c_given` skips tracking and uses that pose (mapping with known poses)."""
        t = len(self.w2cs)
        color, depth = frame.color, frame.depth
        t0 = time.perf_counter()
        track_loss, track_iters = None, 0
        if t == 0:
            w2c = np.eye(4)
            self.scene_radius = float(depth.max()) / self.config.scene_radius_depth_ratio
        elif w2c_given is not None:
            w2c = np.asarray(w2c_given, dtype=np.float64)
        else:
            w2c_init = predict_constant_velocity(self.w2cs[-1], self.w2cs[-2] if t > 1 else None)
            w2c, track_loss, track_iters = self._track(color, depth, w2c_init)
        t1 = time.perf_counter()

        added = self._densify(color, depth, w2c, t)
        pruned = 0
        if t % self.config.mapping.map_every == 0:
            pruned = self._map(color, depth, w2c, t)
        keyframe = is_keyframe_time(t, self.total_frames, self.config.keyframes.every)
        if keyframe:
            self.keyframes.add(t, w2c, color, depth)
        self.w2cs.append(w2c)
        t2 = time.perf_counter()
        return FrameResult(index=t, timestamp=frame.timestamp, w2c=w2c, is_keyframe=keyframe,
                           num_gaussians=len(self.map), num_added=added, num_pruned=pruned,
                           tracking_seconds=t1 - t0, mapping_seconds=t2 - t1, tracking_loss=track_loss,
                           tracking_iterations=track_iters, source_index=frame.index)

    # ------------------------------------------------------------------ steps
    def _track(self, color, depth, w2c_init):
        """Optional Gauss-Newton alignment to the rendered map, then SplaTAM's Adam iterations,
        coarse to fine (a stage with no iterations is skipped)."""
        tc = self.config.tracking
        nearby = frustum_mask(self.map.means.detach(), self.map.log_scales.detach(), self.intrinsics, w2c_init,
                              self.config.near_plane, margin=0.25)
        g = self.map.tensors(detach=True)
        g = Gaussians(*(x[nearby] for x in (g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales)))
        color_t, depth_t = self._tensor(color), self._tensor(depth)
        stages = [(intr, cfg) for intr, cfg in
                  ((self._scaled(tc.coarse_scale), dataclasses.replace(tc, iterations=tc.coarse_iterations)),
                   (self.track_intrinsics, tc)) if cfg.iterations > 0]
        w2c, loss, fallback = w2c_init, None, None
        if tc.align_iterations > 0:
            near = self.config.near_plane
            aligned = align_to_map(g, color, depth, self.intrinsics, w2c, levels=tc.align_levels,
                                   iterations=tc.align_iterations, passes=tc.align_passes,
                                   color_weight=tc.align_color_weight, silhouette=tc.silhouette_threshold,
                                   near=near, depth_noise=tc.align_depth_noise)
            # Keep the alignment only if SplaTAM's own loss agrees (tracking.beats). The first Adam
            # iteration evaluates the aligned pose anyway, so the check rides on it when it can.
            fallback = (w2c_init, *loss_and_pixels(aligned.first_render, color_t, depth_t, tc))
            w2c = aligned.w2c
            if not stages or stages[0][0] != self.intrinsics:
                loss_aligned, valid = evaluate_loss(g, color_t, depth_t, self.intrinsics, w2c, tc, near)
                if beats(loss_aligned, valid, *fallback[1:]):
                    loss = loss_aligned
                else:
                    w2c, loss = w2c_init, fallback[1]
                fallback = None
        iterations = 0
        for intr, stage_config in stages:
            result = track(g, self._tensor(resize_to(color, intr, False)), self._tensor(resize_to(depth, intr, True)),
                           intr, w2c, stage_config, near=self.config.near_plane, fallback=fallback)
            w2c, loss, iterations, fallback = result.w2c, result.loss, iterations + result.iterations, None
        return w2c, loss, iterations

    def _densify(self, color, depth, w2c, t) -> int:
        intr = self.densify_intrinsics
        color_d, depth_d = resize_to(color, intr, False), resize_to(depth, intr, True)
        if t == 0 or len(self.map) == 0:
            mask = depth_d > 0
        else:
            with torch.no_grad():
                out = render(self.map.tensors(detach=True), intr, w2c, near=self.config.near_plane)
            mask = new_pixel_mask(depth_d, out.depth.cpu().numpy(), out.alpha.cpu().numpy(), self.config.densify)
        new = gaussians_from_pixels(color_d, depth_d, mask, intr, w2c, t, self.config.densify,
                                    self.config.isotropic, device=self.device, dtype=self.dtype)
        self.map.append(new)
        return len(new)

    def _map(self, color, depth, w2c, t) -> int:
        mc = self.config.mapping
        iterations = mc.first_frame_iterations if (t == 0 and mc.first_frame_iterations is not None) else mc.iterations
        views = [View(self._tensor(color), self._tensor(depth), w2c)]
        for kf in self.keyframes.select(depth, w2c, mc.window_size - 1, self.rng):
            views.append(View(self._tensor(kf.color), self._tensor(kf.depth), kf.w2c))
        stats = optimise_map(self.map, views, self.intrinsics, mc, iterations, self.scene_radius, self.rng,
                             near=self.config.near_plane)
        return stats["pruned"]

    # ------------------------------------------------------------------ state (checkpoints)
    def state_arrays(self) -> dict:
        arrays = {f"map_{k}": v for k, v in self.map.to_numpy().items()}
        arrays.update(self.keyframes.to_arrays())
        arrays["w2cs"] = np.array(self.w2cs).reshape(-1, 4, 4)
        arrays["scene_radius"] = np.array(np.nan if self.scene_radius is None else self.scene_radius)
        arrays["rng_state"] = np.array(json.dumps(self.rng.bit_generator.state))
        return arrays

    def load_state_arrays(self, arrays: dict) -> None:
        self.map = GaussianMap.from_numpy({k[4:]: v for k, v in arrays.items() if k.startswith("map_")},
                                          device=self.device, dtype=self.dtype)
        self.keyframes.load_arrays(arrays)
        self.w2cs = [w for w in np.asarray(arrays["w2cs"], dtype=np.float64)]
        radius = float(arrays["scene_radius"])
        self.scene_radius = None if np.isnan(radius) else radius
        self.rng.bit_generator.state = json.loads(str(arrays["rng_state"]))
