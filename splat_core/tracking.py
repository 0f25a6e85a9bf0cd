"""Tracking: one frame's camera pose against the fixed map, as one object (`Tracker`).

    tracker = Tracker(config.tracking, intrinsics, renderer)
    result = tracker.track(map_gaussians, color, depth, w2c_predicted)

Three steps, each start pose a named `Candidate` with its loss and pixel count, compared by one
rule (`beats`):
    align    Gauss-Newton alignment of the frame to the map rendered at the prediction
             (align.align_to_map: Numba on the host, torch on CUDA), optional (tracking.align)
    accept   keep the aligned pose only if SplaTAM's own loss agrees it beats the prediction
    polish   SplaTAM's Adam iterations on the 7 pose numbers (w2c quaternion + translation),
             coarse to fine (a stage with no iterations is skipped)

The loss uses the pixels the map already explains (silhouette > 0.99) with valid depth:
    L = w_d sum |D - D_hat| + w_c sum |C - C_hat|        (sums, as in SplaTAM)
With tracking.pixels != "all" it is evaluated on a few pixels per tile only (pixel_selection.py),
rendered by the sparse-pixel path (render_pixels): the same loss on a subset, at a fraction of the
cost. The best pose is the one with the lowest loss, snapshotted *before* the step that follows it
(the original snapshots after stepping; `compat_post_step_candidate` reproduces that).

A pose beats another with a lower loss per pixel over at least half as many pixels: a sum over
fewer pixels is smaller without being better, and a pose that looks away from the map would
otherwise "win" with a loss of zero.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from .align import align_to_map
from .camera import Intrinsics, invert_pose, pose_matrix, quat_to_rotmat_np, rotmat_to_quat, w2c_from_quat_trans
from .config import TrackingConfig
from .frame import resize_to
from .gaussians import Gaussians
from .pixel_selection import choose_pixels
from .render import Render, Renderer


@dataclass
class Candidate:
    """A pose with its tracking loss (the sum) over `pixels` loss pixels of one observation."""

    name: str             # "prediction", "aligned", "polished"
    w2c: np.ndarray
    loss: float
    pixels: int


def beats(a: Candidate, b: Candidate) -> bool:
    """a beats b with a lower loss per pixel over at least half as many pixels."""
    return 2 * a.pixels >= b.pixels and a.loss * b.pixels <= b.loss * a.pixels


@dataclass
class TrackResult:
    w2c: np.ndarray
    loss: float | None    # best loss (the sum above); None when nothing was evaluated
    iterations: int
    valid_pixels: int     # pixels in the loss mask at the best pose
    start: str = "prediction"   # the candidate the polish started from
    depth_pixels: int = 0       # loss pixels with valid depth, covered by the map or not

    @property
    def coverage(self) -> float | None:
        """The share of the loss's valid-depth pixels the map covered (None: no valid depth)."""
        return self.valid_pixels / self.depth_pixels if self.depth_pixels else None


@dataclass
class Observation:
    """The frame at one resolution, with the pixels the loss uses (None = all)."""

    intr: Intrinsics
    color: torch.Tensor   # H x W x 3, or P x 3 at `pixels`
    depth: torch.Tensor   # H x W, or P
    pixels: np.ndarray | None = None

    def render(self, renderer: Renderer, gaussians: Gaussians, w2c) -> Render:
        if self.pixels is None:
            return renderer.render(gaussians, self.intr, w2c)
        return renderer.pixels(gaussians, self.intr, w2c, self.pixels)

    def gather(self, dense: Render) -> Render:
        """A dense render at `intr` reduced to this observation's pixels."""
        if self.pixels is None:
            return dense
        x, y = self.pixels[:, 0], self.pixels[:, 1]
        return Render(dense.color[y, x], dense.depth[y, x], dense.alpha[y, x])


def tracking_loss(rendered: Render, color: torch.Tensor, depth: torch.Tensor, config: TrackingConfig):
    """(loss, mask, depth term) with mask = valid depth and silhouette above the threshold (detached).
    Works on images (H x W) and on pixel lists (P) alike."""
    mask = (depth > 0) & (rendered.alpha.detach() > config.silhouette_threshold)
    error = torch.abs(depth - rendered.depth)
    if config.outlier_factor is not None and bool(mask.any()):
        # Depth outliers (sensor edges, moving objects) would pull the pose; SplaTAM's optional rule.
        mask = mask & (error.detach() < config.outlier_factor * error.detach()[mask].median())
    m = mask.to(depth.dtype)
    depth_term = (error * m).sum()
    color_term = (torch.abs(color - rendered.color) * m[..., None]).sum()
    return config.depth_weight * depth_term + config.color_weight * color_term, mask, depth_term


def candidate(name: str, w2c: np.ndarray, rendered: Render, obs: Observation, config: TrackingConfig) -> Candidate:
    """The Candidate of a pose from its rendering of `obs` (no gradient)."""
    with torch.no_grad():
        loss, mask, _ = tracking_loss(rendered, obs.color, obs.depth, config)
        return Candidate(name, np.asarray(w2c, dtype=np.float64), float(loss), int(mask.sum()))


def load_optimizer_code() -> None:
    """torch imports its compiler stack (torch._dynamo: about a second on two cores) when the process
    makes its first optimiser. Called when an engine is built, so that second is spent before the
    first frame instead of inside it (frame 1 of a live run waited for it)."""
    torch.optim.Adam([torch.zeros(1, requires_grad=True)])


def pose_adam(q: torch.Tensor, t: torch.Tensor, config: TrackingConfig) -> torch.optim.Adam:
    """Adam on the pose (torch's fused kernel on CUDA: one launch a step instead of a dozen; the
    CPU keeps the per-tensor loop, so its results stay as they were)."""
    groups = [{"params": [q], "lr": config.lr_rotation}, {"params": [t], "lr": config.lr_translation}]
    return torch.optim.Adam(groups, fused=True) if q.device.type == "cuda" else torch.optim.Adam(groups)


def polish(renderer: Renderer, gaussians: Gaussians, obs: Observation, start: Candidate | np.ndarray,
           config: TrackingConfig, rival: Candidate | None = None) -> TrackResult:
    """SplaTAM's Adam iterations on the pose, from `start` (a Candidate or a w2c).

    rival: another start whose loss was computed on `obs` (e.g. the prediction an alignment began
    from). Adam's first iteration evaluates `start` anyway; if it does not beat the rival, the
    optimisation starts from the rival instead, at no extra rendering.

    The best pose so far is kept on the device (torch.where), so an iteration asks the host
    nothing: the loop synchronises only for the rival's test (first iteration), the optional
    early stop (tracking.early_stop_tolerance > 0) and the optional budget extension
    (depth_loss_threshold, once), and the result comes to the host once at the end. The last
    iteration renders and scores its pose but takes no backward pass or step (nothing would
    evaluate the pose it steps to), unless compat_post_step_candidate keeps post-step poses."""
    w2c_start = start.w2c if isinstance(start, Candidate) else np.asarray(start, dtype=np.float64)
    start_name = start.name if isinstance(start, Candidate) else "prediction"
    dtype, device = gaussians.means.dtype, gaussians.means.device
    q = torch.tensor(rotmat_to_quat(w2c_start[:3, :3]), dtype=dtype, device=device, requires_grad=True)
    t = torch.tensor(w2c_start[:3, 3], dtype=dtype, device=device, requires_grad=True)
    optimizer = pose_adam(q, t, config)
    best_loss = torch.full((), float("inf"), dtype=dtype, device=device)
    best_q, best_t = q.detach().clone(), t.detach().clone()
    best_valid = torch.zeros((), dtype=torch.long, device=device)
    min_valid = None
    budget, extended, done = config.iterations, False, 0
    while done < budget:
        out = obs.render(renderer, gaussians, w2c_from_quat_trans(q, t))
        loss, mask, depth_term = tracking_loss(out, obs.color, obs.depth, config)
        value, valid = loss.detach(), mask.sum()
        if rival is not None:
            here = Candidate(start_name, w2c_start, float(value), int(valid))
            if not beats(here, rival):
                start_name = rival.name
                with torch.no_grad():
                    q.copy_(torch.as_tensor(rotmat_to_quat(rival.w2c[:3, :3]), dtype=dtype))
                    t.copy_(torch.as_tensor(rival.w2c[:3, 3], dtype=dtype))
                rival = None
                continue
            rival = None
        if done == 0:
            min_valid = torch.clamp(valid // 2, min=1)
        value = torch.where(valid < min_valid, torch.inf, value)
        if not config.compat_post_step_candidate:
            best_loss, best_q, best_t, best_valid = _keep_better(value, q, t, valid, best_loss, best_q, best_t,
                                                                 best_valid)
        extend = (done + 1 == budget and config.depth_loss_threshold is not None and not extended
                  and float(depth_term) / max(int(mask.sum()), 1) > config.depth_loss_threshold)
        if done + 1 == budget and not extend and not config.compat_post_step_candidate:
            # The last iteration: its pose is evaluated above; the step after it would never be
            # (the best pose is snapshotted before stepping), so its backward pass is skipped.
            done += 1
            break
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if config.early_stop_tolerance > 0:
            q_before, t_before = q.detach().clone(), t.detach().clone()
        optimizer.step()
        if config.compat_post_step_candidate:
            best_loss, best_q, best_t, best_valid = _keep_better(value, q, t, valid, best_loss, best_q, best_t,
                                                                 best_valid)
        done += 1
        if config.early_stop_tolerance > 0:
            step = max(float((t.detach() - t_before).abs().max()), float((q.detach() - q_before).abs().max()))
            if step < config.early_stop_tolerance:
                break
        if extend:
            budget, extended = 2 * budget, True
    packed = torch.cat([best_q.to(torch.float64), best_t.to(torch.float64), best_loss.to(torch.float64).reshape(1),
                        best_valid.to(torch.float64).reshape(1),
                        (obs.depth > 0).sum().to(torch.float64).reshape(1)]).cpu().numpy()
    q_best, t_best = packed[:4], packed[4:7]
    w2c = pose_matrix(quat_to_rotmat_np(q_best), t_best)
    return TrackResult(w2c=w2c, loss=float(packed[7]), iterations=done, valid_pixels=int(packed[8]), start=start_name,
                       depth_pixels=int(packed[9]))


def _keep_better(value, q, t, valid, best_loss, best_q, best_t, best_valid):
    """The best pose so far, on the device: (q, t) where `value` is below the best loss."""
    with torch.no_grad():
        better = value < best_loss
        return (torch.where(better, value, best_loss), torch.where(better, q.detach(), best_q),
                torch.where(better, t.detach(), best_t), torch.where(better, valid, best_valid))


def sparse_step(step: int, intr: Intrinsics, min_count: float) -> int:
    """`step` (a block size or a stride), made smaller where one pixel per step x step block would
    leave fewer than min_count pixels of the image (small working resolutions track densely)."""
    return max(1, min(step, int(np.sqrt(intr.width * intr.height / max(min_count, 1)))))


def align_options(config: TrackingConfig, intr: Intrinsics, near: float, **override) -> dict:
    """Keyword arguments of align.align_to_map (backend included) from the tracking settings
    (`override` wins)."""
    a = config.align
    options = dict(backend=a.backend, levels=a.levels, iterations=a.iterations, passes=a.passes,
                   color_weight=a.color_weight, silhouette=config.silhouette_threshold, near=near,
                   depth_noise=a.depth_noise, exposure=a.exposure, live_stride=sparse_step(a.stride, intr, a.min_points),
                   tolerance=a.tolerance)
    return {**options, **override}


class ReusedRender(NamedTuple):
    """A dense render of one map version kept for the alignment of the next frames
    (tracking.align.reuse_render)."""
    gaussians: Gaussians        # the map version it renders (a newer version renders anew)
    culled: Gaussians           # those Gaussians culled to the view it was made for
    render: object              # the Render
    w2c: np.ndarray             # the pose it was rendered at
    uses: int                   # frames it has served since
    pyramid: tuple | None = None  # the alignment's arrays of that render per level (AlignResult.first_pyramid)


def moved_beyond(w2c_a: np.ndarray, w2c_b: np.ndarray, distance: float) -> bool:
    """The two poses' camera centres more than `distance` apart (0: never)."""
    if not distance > 0:
        return False
    centres = [invert_pose(np.asarray(w2c))[:3, 3] for w2c in (w2c_a, w2c_b)]
    return bool(np.linalg.norm(centres[0] - centres[1]) > distance)


class Tracker:
    """align -> accept -> polish for one frame at a time (see the module docstring)."""

    def __init__(self, config: TrackingConfig, intrinsics: Intrinsics, renderer: Renderer, seed: int = 0,
                 device="cpu", dtype=torch.float32):
        self.config, self.intrinsics, self.renderer = config, intrinsics, renderer
        self.device, self.dtype = torch.device(device), dtype
        self.rng = np.random.default_rng([seed, 1])    # pixel choice; its own stream (resume)
        tc = config
        self.stages = [(intrinsics.fraction(s), dataclasses.replace(tc, iterations=n)) for s, n in
                       ((tc.coarse_scale, tc.coarse_iterations), (tc.resolution_scale, tc.iterations)) if n > 0]
        self._model: ReusedRender | None = None      # tracking.align.reuse_render

    # -------------------------------------------------------------- one frame
    def track(self, gaussians: Gaussians, color: np.ndarray, depth: np.ndarray, w2c_predicted: np.ndarray,
              reuse: bool = False) -> TrackResult:
        """The pose of (colour H x W x 3, depth H x W at the tracker's intrinsics) against the map.
        reuse: the tracking of consecutive frames (SplaTAM.track), where tracking.align.reuse_render
        may serve the alignment a render made for an earlier frame of the same map version."""
        tc = self.config
        model = self._model if reuse and tc.align.reuse_render > 0 and tc.align.iterations > 0 else None
        if model is not None and (model.gaussians is not gaussians or model.uses >= tc.align.reuse_render):
            model = self._model = None
        g = model.culled if model is not None else self.nearby(gaussians, w2c_predicted)
        observations = [self.observe(color, depth, intr) for intr, _ in self.stages]
        start: Candidate | np.ndarray = np.asarray(w2c_predicted, dtype=np.float64)
        rival = None
        if tc.align.iterations > 0:
            aligned = self.align(g, color, depth, start,
                                 None if model is None else (model.render, model.w2c, model.pyramid))
            full = observations[0] if self.stages and self.stages[0][0] == self.intrinsics \
                else self.observe(color, depth, self.intrinsics)
            if model is not None:        # the render is not at the prediction: its loss costs a render of its own
                self._model = model._replace(uses=model.uses + 1)
                if not tc.align.reuse_rival and not moved_beyond(aligned.w2c, start, tc.align.reuse_rival_beyond):
                    prediction = None
                else:
                    with torch.no_grad():
                        prediction = candidate("prediction", start, full.render(self.renderer, g, start), full, tc)
            else:
                if reuse and tc.align.reuse_render > 0:
                    self._model = ReusedRender(gaussians, g, aligned.first_render, start, 0, aligned.first_pyramid)
                prediction = candidate("prediction", start, full.gather(aligned.first_render), full, tc)
            if prediction is None:       # reuse_rival false, within reuse_rival_beyond: the aligned pose, unchallenged
                start = Candidate("aligned", aligned.w2c, float("nan"), 0)
            elif observations and full is observations[0]:
                # Accept rides on the polish's first iteration, which evaluates the aligned pose anyway.
                start, rival = Candidate("aligned", aligned.w2c, float("nan"), 0), prediction
            else:
                with torch.no_grad():
                    at_aligned = candidate("aligned", aligned.w2c, full.render(self.renderer, g, aligned.w2c), full, tc)
                start = at_aligned if beats(at_aligned, prediction) else prediction
        if not self.stages:
            if isinstance(start, Candidate):
                return TrackResult(start.w2c, start.loss, 0, start.pixels, start.name)
            return TrackResult(start, None, 0, 0, "prediction")
        iterations = 0
        for obs, (_, stage_config) in zip(observations, self.stages):
            result = polish(self.renderer, g, obs, start, stage_config, rival)
            iterations += result.iterations
            start, rival = Candidate(result.start, result.w2c, result.loss, result.valid_pixels), None
        return dataclasses.replace(result, iterations=iterations)

    # -------------------------------------------------------------- helpers
    def align(self, g: Gaussians, color: np.ndarray, depth: np.ndarray, w2c: np.ndarray, model=None):
        """The Gauss-Newton alignment (tracking.align) from w2c, by the configured backend (auto:
        torch for a map on CUDA, else Numba); `model`: a render to reuse (align_to_map)."""
        return align_to_map(g, color, depth, self.intrinsics, w2c, model=model,
                            **align_options(self.config, self.intrinsics, self.renderer.near))

    def nearby(self, gaussians: Gaussians, w2c: np.ndarray) -> Gaussians:
        """The Gaussians that can appear in the frame (with a margin for the motion to come)."""
        return self.renderer.visible(gaussians, self.intrinsics, w2c, margin=0.25)

    def observe(self, color: np.ndarray, depth: np.ndarray, intr: Intrinsics) -> Observation:
        """The frame at `intr`, reduced to the configured pixel subset."""
        tc = self.config
        c, d = resize_to(color, intr, False), resize_to(depth, intr, True)
        pixels = choose_pixels(tc.pixels, c, d, sparse_step(tc.pixel_tile, intr, tc.min_pixels / tc.pixels_per_tile),
                               tc.pixels_per_tile, self.rng)
        if pixels is not None:
            c, d = c[pixels[:, 1], pixels[:, 0]], d[pixels[:, 1], pixels[:, 0]]
        device, dtype = self.device, self.dtype
        as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)  # noqa: E731
        return Observation(intr, as_t(c), as_t(d), pixels)

    # -------------------------------------------------------------- checkpoints
    def state(self) -> str:
        return json.dumps(self.rng.bit_generator.state)

    def load_state(self, state: str) -> None:
        self.rng.bit_generator.state = json.loads(state)
