"""A synthetic capture that goes round the room and comes back, and odometry that drifts on it.

    source = LoopSource(n_frames=120)                 # one lap of the orbit and a little more
    odo = DriftingOdometry(source, bias_m=0.001, bias_deg=0.05)
    for t in range(len(source)):
        slam.process(frame, w2c_given=odo.w2c(t, slam.w2cs))   # drifts; loop closure can pull it back

`LoopSource` is the room of synthetic.py seen from a full circle around the objects (plus
`overlap` of a lap, so the last frames see again what the first ones saw), with exact poses.
`DriftingOdometry` stands in for a tracker that drifts: each frame's pose is the previous
*estimated* pose composed with the exact frame-to-frame motion and a constant small error, so a
correction that loop closure makes to the estimate carries forward as it would with real tracking.
`corridor` in corridor.py is the capture that never comes back (no loop may close there).
"""

from __future__ import annotations

import numpy as np

from ..camera import invert_pose
from .paths import ORBIT_CENTRE, look_at_c2w
from .source import SyntheticSource


def loop_path(n_frames: int, seed: int = 0, overlap: float = 0.15, radius: float = 2.0) -> np.ndarray:
    """n_frames x 4 x 4 c2w: (1 + overlap) laps around the objects, looking at them, with a small
    wobble of height and gaze."""
    rng = np.random.default_rng([seed, 4711])
    phase, wob = rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi, size=3)
    s = np.arange(n_frames, dtype=np.float64) / max(1, n_frames - 1)
    theta = phase + 2 * np.pi * (1 + overlap) * s
    eyes = np.stack([ORBIT_CENTRE[0] + radius * np.cos(theta), -0.05 + 0.1 * np.sin(4 * np.pi * s + wob[0]),
                     ORBIT_CENTRE[2] + radius * np.sin(theta)], axis=1)
    targets = ORBIT_CENTRE + np.stack([0.2 * np.sin(6 * np.pi * s + wob[1]), np.zeros_like(s),
                                       0.2 * np.cos(6 * np.pi * s + wob[2])], axis=1)
    return np.stack([look_at_c2w(e, t) for e, t in zip(eyes, targets)])


class LoopSource(SyntheticSource):
    """SyntheticSource on loop_path (same options)."""

    format_name = "synthetic-loop"

    def __init__(self, n_frames: int = 120, overlap: float = 0.15, **options):
        super().__init__(n_frames=n_frames, **options)
        self.c2w = loop_path(self.n_frames, self.seed, overlap)

    def describe(self) -> str:
        return f"synthetic loop (seed {self.seed}, {self.n_frames} frames, {self._intrinsics.width}x{self._intrinsics.height})"


def _bias(bias_m: float, bias_deg: float) -> np.ndarray:
    a = np.radians(bias_deg)
    T = np.eye(4)
    T[:3, :3] = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])   # yaw
    T[:3, 3] = [bias_m, 0.3 * bias_m, 0.0]
    return T


class DriftingOdometry:
    """Poses of a tracker that drifts by a constant error per frame (camera-frame motion bias)."""

    def __init__(self, source, bias_m: float = 0.001, bias_deg: float = 0.05):
        ref = source.reference_c2w()
        self.ref = [invert_pose(ref[0]) @ c for c in ref]        # the SLAM world: frame 0's camera
        self.bias = _bias(bias_m, bias_deg)

    def w2c(self, t: int, estimated_w2cs: list[np.ndarray]) -> np.ndarray:
        """Frame t's pose from the previous estimate (estimated_w2cs[t-1]) and the true motion."""
        if t == 0:
            return np.eye(4)
        step = invert_pose(self.ref[t - 1]) @ self.ref[t] @ self.bias
        return invert_pose(invert_pose(estimated_w2cs[t - 1]) @ step)
