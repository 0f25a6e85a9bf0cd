"""SplaTAM's own state as arrays (checkpoints) and its end of run: the part of SplaTAM (slam.py)
that saves, loads and finishes what its steps made. A mixin: SplaTAM stays the only writer.

    arrays = slam.state_arrays()          everything a resume needs (map, keyframes, poses, rng, ...)
    slam.load_state_arrays(arrays, file)  restore it (the keyframe images are records of `file`)
    record = slam.finish()                the end-of-run steps on the map (mapping.final_color_fit)

After `finish` the map is the fitted one (published as a new version, and in the checkpoint's map,
which browsing, refinement and renders read); the checkpoint also keeps the colours from before the
fit (`fit_colors_before`) and the frames kept for the fit (`fit_frames`, `fit_colors`), and loading
it restores those: a resumed run is in the state before its end, goes on with any frames left, and
fits again when it finishes (the same fit: tests/core/test_color_fit.py).
"""

from __future__ import annotations

import json

import numpy as np
import torch

from .color_fit import fit_map_colors
from .gaussians import GaussianMap
from .loop.records import LoopRecord


class SlamState:
    """SplaTAM's checkpoint and finish (its attributes: slam.py)."""

    color_fit: dict | None = None                 # the end-of-run fit's record, once finish() made it
    _colors_before_fit: torch.Tensor | None = None

    def finish(self) -> dict | None:
        """The end of the run, after its last frame was mapped: mapping.final_color_fit, the map's
        colours given the gain and offset per channel that best fit its renders to the frames kept
        for it, none of them evaluated (color_fit.py), and the fitted map published. Returns the
        fit's record (None: off, or no frame kept or no Gaussian); a second call returns the first's."""
        if self.color_fit is not None or self.fit_samples is None or not len(self.map):
            return self.color_fit
        views = self.fit_samples.views(self.w2cs, self.lost_tracking.reason)
        if not views:
            return None
        self._colors_before_fit = self.map.params["colors"].detach().clone()
        self.color_fit = fit_map_colors(self.map, views, self.fit_samples.intrinsics, self.renderer)
        self.publish(self.frames_tracked - 1)
        return self.color_fit

    def tracking_state(self) -> tuple[str, str]:
        """The tracking side's state (the tracker's pixel choice, the lost-tracking watch) as text."""
        return self.tracker.state(), self.lost_tracking.state()

    def state_arrays(self, w2cs: list | None = None, tracking_state: tuple[str, str] | None = None) -> dict:
        """Everything a resume needs. The live engine's mapper saves the state at the newest frame
        it mapped: `w2cs` up to that frame and the tracking state saved right after it was tracked."""
        arrays = {f"map_{k}": v for k, v in self.map.to_numpy().items()}
        if self._colors_before_fit is not None:
            arrays["fit_colors_before"] = self._colors_before_fit.cpu().numpy()
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
        finished run's map is restored as it was before finish() (its colours before the fit)."""
        gaussians = {k[4:]: v for k, v in arrays.items() if k.startswith("map_")}
        if "fit_colors_before" in arrays:
            gaussians["colors"] = arrays["fit_colors_before"]
        self.map = GaussianMap.from_numpy(gaussians, device=self.device, dtype=self.dtype)
        self.color_fit, self._colors_before_fit = None, None
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
