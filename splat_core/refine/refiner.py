"""Refinement: optimise a finished map over all keyframes, poses fixed, with adaptive density control.

    refiner = Refiner(map, views, intrinsics, loss_config, settings, scene_radius)
    while refiner.iteration < settings.iterations:
        refiner.step()

Each iteration renders one keyframe (3DGS's one image per iteration; the order is a fresh
permutation of the keyframes per pass, drawn from (seed, pass) so a resumed refine draws the same
views), minimises SLAM's mapping loss (mapping.mapping_loss: depth L1 + colour L1 and SSIM) with
Adam, and accumulates view-space positional gradients; every `densify_every` iterations from
`densify_from` until `densify_until` it clones, splits and prunes (density.py). All state (map,
Adam moments and step counts, gradient statistics, iteration) is in `state_arrays()`, so a refine
resumed from a checkpoint continues bit for bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from ..camera import Intrinsics
from ..config import MappingConfig
from ..gaussians import PARAM_NAMES, GaussianMap
from ..final_refine import REFINE_LRS, keyframe_order
from ..mapping import View, mapping_loss
from ..render import Renderer
from ..slam_state import MapVersion, snapshot_version
from .density import DensitySettings, GradientStats, densify_and_prune


@dataclass
class RefineSettings:
    iterations: int = 1000
    densify_from: int | None = None    # first densification step (after a warm-up); None = iterations / 10
    densify_every: int | None = None   # None = iterations / 10
    densify_until: int | None = None   # last iteration that may densify; None = 3/4 of `iterations`
    density: DensitySettings = field(default_factory=DensitySettings)
    lrs: dict | None = None            # Adam learning rates per parameter; None = the run's mapping rates
                                       # with REFINE_LRS over them
    anisotropic: bool = False          # give an isotropic map 3 scales and a rotation to optimise
    seed: int = 0

    def resolved(self, mapping: MappingConfig) -> "RefineSettings":
        """These settings with the defaults that depend on the run filled in."""
        tenth = max(1, self.iterations // 10)
        pick = lambda value, default: default if value is None else value  # noqa: E731
        return dataclasses.replace(
            self, densify_from=pick(self.densify_from, tenth), densify_every=pick(self.densify_every, tenth),
            densify_until=pick(self.densify_until, self.iterations * 3 // 4),
            lrs=dict(pick(self.lrs, {**mapping.lrs, **REFINE_LRS})))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Refiner:
    def __init__(self, gmap: GaussianMap, views: list[View], intrinsics: Intrinsics, loss: MappingConfig,
                 settings: RefineSettings, scene_radius: float, renderer: Renderer = Renderer()):
        if not views:
            raise ValueError("refinement needs at least one view")
        self.loss_config, self.settings = loss, settings.resolved(loss)
        if self.settings.anisotropic and gmap.isotropic:
            gmap = gmap.anisotropic()
        self.map, self.views, self.intrinsics = gmap, views, intrinsics
        self.scene_radius, self.renderer = scene_radius, renderer
        self.optimizer = gmap.adam(self.settings.lrs)
        self.stats = GradientStats(len(gmap), gmap.device)
        self.iteration = 0
        self.last_loss: float | None = None
        self.density_log: list[dict] = []

    def view_at(self, iteration: int) -> View:
        return self.views[keyframe_order(len(self.views), iteration, self.settings.seed)]

    def step(self) -> float:
        view = self.view_at(self.iteration)
        screen: list = []
        out = self.renderer.render(self.map.tensors(), self.intrinsics, view.w2c, screen=screen)
        loss = mapping_loss(out, view, self.loss_config)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.stats.add(screen, self.intrinsics.width, self.intrinsics.height)
        self.optimizer.step()
        self.iteration += 1
        s = self.settings
        if s.densify_from <= self.iteration <= s.densify_until and self.iteration % s.densify_every == 0:
            rng = np.random.default_rng([s.seed, self.iteration])
            counts = densify_and_prune(self.map, self.optimizer, self.stats, s.density, self.loss_config,
                                       self.scene_radius, rng)
            self.density_log.append(dict(iteration=self.iteration, **counts))
            self.stats = GradientStats(len(self.map), self.map.device)
        self.last_loss = float(loss.detach())
        return self.last_loss

    # ------------------------------------------------------------------ state (checkpoints)
    def publish(self) -> MapVersion:
        """The map as it stands, as an immutable MapVersion (the type SLAM publishes; numbered by iteration)."""
        return snapshot_version(self.map, self.iteration, -1)

    def state_arrays(self) -> dict:
        arrays = {f"map_{k}": v for k, v in self.map.to_numpy().items()}
        arrays.update(self.stats.to_arrays())
        for name in PARAM_NAMES:
            state = self.optimizer.state.get(self.map.params[name])
            if state:
                arrays[f"adam_{name}_step"] = np.array(float(state["step"]))
                arrays[f"adam_{name}_exp_avg"] = state["exp_avg"].cpu().numpy()
                arrays[f"adam_{name}_exp_avg_sq"] = state["exp_avg_sq"].cpu().numpy()
        arrays["iteration"] = np.array(self.iteration)
        return arrays

    def load_state_arrays(self, arrays: dict, density_log: list[dict] | None = None) -> None:
        device, dtype = self.map.device, self.map.dtype
        self.map = GaussianMap.from_numpy({k[4:]: v for k, v in arrays.items() if k.startswith("map_")},
                                          device=device, dtype=dtype)
        self.optimizer = self.map.adam(self.settings.lrs)
        for name in PARAM_NAMES:
            if f"adam_{name}_step" in arrays:
                t = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype, device=device)  # noqa: E731
                self.optimizer.state[self.map.params[name]] = dict(
                    step=torch.tensor(float(arrays[f"adam_{name}_step"]), dtype=torch.float32),
                    exp_avg=t(arrays[f"adam_{name}_exp_avg"]), exp_avg_sq=t(arrays[f"adam_{name}_exp_avg_sq"]))
        self.stats = GradientStats.from_arrays(arrays, device)
        self.iteration = int(arrays["iteration"])
        self.density_log = list(density_log or [])
