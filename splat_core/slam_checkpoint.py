"""SplaTAM's own state as arrays (checkpoints) and its end of run: the part of SplaTAM (slam.py)
that saves, loads and finishes what its steps made. A mixin: SplaTAM stays the only writer.

    arrays = slam.state_arrays()          everything a resume needs (map, keyframes, poses, rng, ...)
    slam.load_state_arrays(arrays, file)  restore it (the keyframe images are records of `file`)
    sections = slam.finish()              the end-of-run passes on the map (mapping.final_refine,
                                          final_hole_fill, final_color_fit): metrics.json's sections

After `finish` the map is the finished one (published as a new version, and in the checkpoint's
map, which browsing, refinement and renders read); the checkpoint also keeps the map from before
it (`before_finish_*`, every parameter: the refinement moves them all) and the frames kept for the
passes (`fit_frames`, `fit_colors`, `fit_depths`), and loading it restores those: a resumed run is
in the state before its end, goes on with any frames left, and finishes again when it ends (the
same passes: tests/core/). Checkpoints written before the refinement kept only the colours from
before (`fit_colors_before`) and the size (`finish_map_size`: the hole fill appends after it).
"""

from __future__ import annotations

import json
import time

import numpy as np
import torch

from .color_fit import fit_map_colors
from .final_holes import fill_final_holes
from .final_refine import refine_final_map
from .gaussians import GaussianMap
from .loop.records import LoopRecord


def map_before_finish(arrays: dict) -> dict | None:
    """A checkpoint's map as it was before finish() (GaussianMap.to_numpy's arrays), or None where
    finish() had not run: the whole map kept (`before_finish_*`), or, in checkpoints from before the
    refinement, the finished map's first `finish_map_size` Gaussians with `fit_colors_before`."""
    before = {k[len("before_finish_"):]: v for k, v in arrays.items() if k.startswith("before_finish_")}
    if before or "fit_colors_before" not in arrays:
        return before or None
    size = int(arrays.get("finish_map_size", len(arrays["fit_colors_before"])))
    gaussians = {k[4:]: np.asarray(v)[:size] for k, v in arrays.items() if k.startswith("map_")}
    gaussians["colors"] = arrays["fit_colors_before"]
    return gaussians


class SlamState:
    """SplaTAM's checkpoint and finish (its attributes: slam.py)."""

    finished: dict | None = None                  # finish()'s sections, once it ran
    _before_finish: dict | None = None            # the map before finish(), as numpy arrays

    def finish(self) -> dict:
        """The end of the run, after its last frame was mapped, over the frames kept for it (none of
        them evaluated: color_fit.FitSamples) at their final poses; no pose moves:
          - mapping.final_refine: the whole map optimised over every keyframe, kept only where
            those frames bear it out (final_refine.py);
          - mapping.final_hole_fill: Gaussians where those frames have no depth and the map is empty
            (with final_hole_fill_iterations, then only they optimised: final_holes.py);
          - mapping.final_color_fit: the map's colours given the gain and offset per channel that
            best fit its renders to those frames (color_fit.py);
        and the finished map published. Returns metrics.json's sections, `final_refine`,
        `final_hole_fill` and `final_color_fit` (each where it ran; empty: all off, or no frame kept
        or no Gaussian); a second call returns the first's."""
        if self.finished is not None:
            return self.finished
        if self.fit_samples is None or not len(self.map):
            return {}
        views = self.fit_samples.views(self.w2cs, self.lost_tracking.reason)
        if not views:
            return {}
        mapping, intrinsics = self.config.mapping, self.fit_samples.intrinsics
        self._before_finish = self.map.to_numpy()
        sections = {}
        if mapping.final_refine > 0 and len(self.keyframes):
            sections["final_refine"] = refine_final_map(self.map, list(self.keyframes), self.keyframe_view,
                                                        self.intrinsics, views, intrinsics, self.renderer, self.config)
        if mapping.final_hole_fill > 0:
            sections["final_hole_fill"] = fill_final_holes(self.map, views, intrinsics, self.renderer, self.config)
        if mapping.final_color_fit:
            start = time.perf_counter()
            record = fit_map_colors(self.map, views, intrinsics, self.renderer,
                                    mapping.final_color_fit_min_improvement, mapping.final_color_fit_prior)
            sections["final_color_fit"] = dict(record, seconds=time.perf_counter() - start)
        self.finished = sections
        self.publish(self.frames_tracked - 1)
        return sections

    def tracking_state(self) -> tuple[str, str]:
        """The tracking side's state (the tracker's pixel choice, the lost-tracking watch) as text."""
        return self.tracker.state(), self.lost_tracking.state()

    def state_arrays(self, w2cs: list | None = None, tracking_state: tuple[str, str] | None = None) -> dict:
        """Everything a resume needs. The live engine's mapper saves the state at the newest frame
        it mapped: `w2cs` up to that frame and the tracking state saved right after it was tracked."""
        arrays = {f"map_{k}": v for k, v in self.map.to_numpy().items()}
        if self._before_finish is not None:
            arrays.update({f"before_finish_{k}": v for k, v in self._before_finish.items()})
        arrays.update(self.keyframes.to_arrays())
        arrays["w2cs"] = np.array(self.w2cs if w2cs is None else w2cs).reshape(-1, 4, 4)
        if self.fit_samples is not None:
            arrays.update(self.fit_samples.to_arrays(len(arrays["w2cs"])))
        arrays["source_indices"] = np.array(self.sources[:len(arrays["w2cs"])], dtype=np.int64)
        arrays["keyframe_marks"] = np.array(self.keyframe_marks[:len(arrays["w2cs"])], dtype=np.int8)
        arrays["scene_radius"] = np.array(np.nan if self.scene_radius is None else self.scene_radius)
        arrays["rng_state"] = np.array(json.dumps(self.rng.bit_generator.state))
        tracker_state, lost_state = self.tracking_state() if tracking_state is None else tracking_state
        arrays["tracker_state"] = np.array(tracker_state)
        arrays["lost_state"] = np.array(lost_state)
        if self.loop_closure is not None:
            arrays["loop_state"] = np.array(self.loop_closure.state())
            arrays["loops"] = np.array(json.dumps([r.to_dict() for r in self.loops]))
        return arrays

    def load_state_arrays(self, arrays: dict, keyframe_file=None) -> None:
        """Restore a checkpoint; the keyframe images are the first records of `keyframe_file`. A
        finished run's map is restored as it was before finish() (its Gaussians and colours before)."""
        gaussians = map_before_finish(arrays) or {k[4:]: v for k, v in arrays.items() if k.startswith("map_")}
        self.map = GaussianMap.from_numpy(gaussians, device=self.device, dtype=self.dtype)
        self.finished, self._before_finish = None, None
        self.keyframes.load_arrays(arrays, keyframe_file)
        if self.fit_samples is not None:
            self.fit_samples.load_arrays(arrays)
        self.w2cs = [w for w in np.asarray(arrays["w2cs"], dtype=np.float64)]
        # a checkpoint from before capture indices were kept: every stride-th frame, none dropped
        self.sources = [int(i) for i in arrays["source_indices"]] if "source_indices" in arrays \
            else [k * self.stride for k in range(len(self.w2cs))]
        radius = float(arrays["scene_radius"])
        self.scene_radius = None if np.isnan(radius) else radius
        self.rng.bit_generator.state = json.loads(str(arrays["rng_state"]))
        if "tracker_state" in arrays:
            self.tracker.load_state(str(arrays["tracker_state"]))
        if "lost_state" in arrays:
            self.lost_tracking.load_state(str(arrays["lost_state"]))
        if "keyframe_marks" in arrays:
            self.keyframe_marks = [int(k) for k in arrays["keyframe_marks"]]
        else:       # a checkpoint from before the decisions were kept: the rule, nothing deferred
            self.keyframe_marks = []
            for t in range(len(self.w2cs)):
                self._mark_keyframe(t, defer=False)
        if self.loop_closure is not None and "loop_state" in arrays:
            self.loop_closure.load_state(str(arrays["loop_state"]))
            self.loops = [LoopRecord.from_dict(r) for r in json.loads(str(arrays.get("loops", "[]")))]
