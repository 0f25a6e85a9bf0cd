"""One refinement of a run folder: set up, step (checkpointing), finish (held-out metrics, outputs).

    job = RefineJob("run", RefineSettings(iterations=1000), resolution="capture")
    while not job.done:
        job.step()
    section = job.finish()    # map_refined.ply beside map.ply, metrics.json's "refine" section

Used by `splatam refine` (with a progress bar) and by the viewer's Refine button (a background
thread). The held-out metrics of the SLAM map are computed before the first step and kept in the
checkpoint (`RUN/refine_checkpoint/`, written atomically every `checkpoint_every` iterations and
on `save_checkpoint()`); a job whose checkpoint has the same settings resumes from it, and the
checkpoint is removed once the outputs are written.
"""

from __future__ import annotations

import json
import platform
import shutil
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import checkpoint
from ..run.run_folder import REFINED_MAP, RunFolder
from ..render import Renderer
from .evaluate import heldout_metrics
from .refiner import Refiner, RefineSettings
from .run_data import frame_views, load_run_data, open_run_capture, training_views

OUTPUT = REFINED_MAP


class RefineJob:
    def __init__(self, run_dir, settings: RefineSettings = RefineSettings(), resolution: str = "capture",
                 capture=None, restart: bool = False, device="cpu", checkpoint_every: int = 100):
        if settings.iterations < 1:
            raise InputError(f"--iterations {settings.iterations}: expected a positive number")
        self.run = load_run_data(run_dir, device)
        self.run_dir = self.run.run_dir
        self.source = open_run_capture(self.run, capture)
        self.intrinsics, views = training_views(self.run, self.source, resolution)
        self.resolution = resolution
        config = self.run.config
        self.renderer = Renderer(near=config.near_plane)
        self.refiner = Refiner(self.run.map, views, self.intrinsics, config.mapping, settings,
                               self.run.scene_radius, self.renderer)
        self.settings = self.refiner.settings
        self.checkpoint_every = checkpoint_every
        self.gaussians_before = len(self.run.map)
        self.before: dict | None = None     # held-out metrics of the SLAM map
        self.seconds = 0.0                  # optimisation time (iterations only)
        self.resumed_from = 0
        self.folder = RunFolder(self.run_dir)
        directory = self.folder.refine_checkpoint_dir
        if restart and directory.exists():
            shutil.rmtree(directory)
        elif checkpoint.exists(directory):
            self._resume(directory)

    # ------------------------------------------------------------------ the run
    @property
    def total(self) -> int:
        return self.settings.iterations

    @property
    def iteration(self) -> int:
        return self.refiner.iteration

    @property
    def done(self) -> bool:
        return self.iteration >= self.total

    def heldout_views(self):
        """The held-out frames at the refine resolution, read one at a time (none without a capture)."""
        if self.source is None:
            return
        for k in self.run.heldout_indices:
            yield from frame_views(self.run, self.source, self.intrinsics, [k])

    def evaluate(self) -> dict:
        return heldout_metrics(self.refiner.map.tensors(detach=True), self.heldout_views(), self.intrinsics,
                               self.renderer)

    def step(self) -> float:
        if self.before is None:
            self.before = self.evaluate()
        start = time.perf_counter()
        loss = self.refiner.step()
        self.seconds += time.perf_counter() - start
        if self.checkpoint_every and self.iteration % self.checkpoint_every == 0 and not self.done:
            self.save_checkpoint()
        return loss

    def finish(self) -> dict:
        """Write map_refined.ply and metrics.json's refine section (both atomically); returns that section."""
        from ..io.ply import write_ply

        if self.before is None:
            self.before = self.evaluate()
        after = self.evaluate()
        write_ply(self.folder.refined_map, self.refiner.map.to_numpy())
        gain = None if after["psnr"] is None else after["psnr"] - self.before["psnr"]
        section = dict(
            output=OUTPUT, resolution=self.resolution, size=[self.intrinsics.width, self.intrinsics.height],
            iterations=self.iteration, keyframes=len(self.refiner.views), heldout_frames=self.run.heldout_indices
            if self.source is not None else [], before=self.before, after=after, psnr_gain_db=gain,
            seconds=self.seconds, seconds_per_iteration=self.seconds / max(1, self.iteration),
            resumed_from=self.resumed_from, num_gaussians_before=self.gaussians_before,
            num_gaussians_after=len(self.refiner.map), densification=self.refiner.density_log,
            settings=self.settings.to_dict(), device=str(self.refiner.map.device),
            machine=platform.processor() or platform.machine())
        if self.source is None:
            section["note"] = "the run does not record its capture: no held-out frames to evaluate on"
        self.folder.add_metrics_section("refine", section)
        shutil.rmtree(self.folder.refine_checkpoint_dir, ignore_errors=True)
        return section

    # ------------------------------------------------------------------ checkpoints
    def _key(self) -> dict:
        """What a checkpoint must share with this job to be resumed."""
        return dict(settings=self.settings.to_dict(), resolution=self.resolution,
                    intrinsics=self.intrinsics.to_dict(), keyframes=self.run.keyframe_indices)

    def save_checkpoint(self) -> None:
        meta = dict(self._key(), iteration=self.iteration, before=self.before, seconds=self.seconds,
                    density_log=self.refiner.density_log)
        checkpoint.save(self.folder.refine_checkpoint_dir, self.refiner.state_arrays(), meta)

    def _resume(self, directory: Path) -> None:
        try:
            meta = json.loads((directory / checkpoint.META).read_text())
            with np.load(directory / checkpoint.STATE, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise InputError(f"{directory}: unreadable refine checkpoint ({e}); pass --restart") from None
        if int(arrays.get("iteration", -1)) != meta.get("iteration"):
            raise InputError(f"{directory}: checkpoint arrays and {checkpoint.META} disagree; pass --restart")
        if {k: meta.get(k) for k in self._key()} != json.loads(json.dumps(self._key())):
            raise InputError(f"{directory}: made with other settings (--iterations/--resolution); "
                             "pass --restart to discard it")
        self.refiner.load_state_arrays(arrays, meta.get("density_log"))
        self.before, self.seconds = meta.get("before"), float(meta.get("seconds", 0.0))
        self.resumed_from = self.iteration
