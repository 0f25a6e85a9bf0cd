"""What both engines (engines.py, live.py) offer besides processing frames: reads of the SplaTAM
they drive, between steps, and its checkpoint (SplaTAM saves and loads its own state)."""

from __future__ import annotations

import numpy as np

from ..keyframes import Keyframe
from ..slam import SplaTAM


class SlamReads:
    """What both engines read of their SplaTAM between steps, and its checkpoint (SplaTAM's own
    state_arrays / load_state_arrays). Called by the thread that calls `process`."""

    slam: SplaTAM

    def keyframes(self) -> list[Keyframe]:
        return list(self.slam.keyframes)

    def trajectory(self) -> list[np.ndarray]:
        """Every frame's w2c so far (a lost frame: held or interpolated; see relocalise.py)."""
        return list(self.slam.w2cs)

    def loop_figures(self) -> dict | None:
        """metrics.json's loop figures (None: loop closure is off)."""
        return self.slam.loop_figures()

    def loops(self) -> tuple | None:
        """The LoopRecords closed so far, oldest first (None: loop closure is off)."""
        return None if self.slam.loop_closure is None else tuple(self.slam.loops)

    def num_gaussians(self) -> int:
        return len(self.slam.map)

    def map_arrays(self) -> dict:
        """The map as numpy arrays (call after drain(): every frame handed over is in it)."""
        return self.slam.map.to_numpy()

    def render(self, w2c: np.ndarray):
        """The map after drain() rendered at w2c (no gradients): evaluation."""
        return self.slam.render_view(w2c)

    def finish_map(self) -> dict:
        """The end of the run (after drain() and close()): SplaTAM.finish, which fills the map's holes
        (mapping.final_hole_fill), fits its colours (mapping.final_color_fit) and publishes the
        finished map, so map_version(), map_arrays(), render() and the checkpoint all give it.
        metrics.json's sections of those passes (empty: off, or nothing to do)."""
        return self.slam.finish()

    def attach_keyframes(self, path) -> None:
        self.slam.keyframes.attach(path)

    def state_arrays(self) -> dict:
        self.drain()               # a consistent state: every tracked frame is in the map
        return self.slam.state_arrays()

    def load_state(self, arrays: dict, keyframe_file) -> None:
        self.slam.load_state_arrays(arrays, keyframe_file)
