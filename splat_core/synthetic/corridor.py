"""A long synthetic capture that keeps exploring: a walk down a 40 m corridor (benchmarks/long_run.py).

The room scene (scene.py) is revisited over and over; this one is not: the camera walks down
the corridor at hand-held speed (1.5 cm per frame: 1,000 frames cover 15 m), panning from side to
side, so new walls and objects keep entering the view while earlier ones leave it, and the map
grows with the run as a house or a corridor scan does. Depth beyond `max_depth` (default 5 m,
like a phone's or a Kinect's range) is invalid, so what is seen is near the camera.

World frame as in scene.py (y down); the corridor runs along +x: x in [-1, 40], y in
[-1.5, 1.5], z in [-1.5, 1.5]. Boxes and spheres stand along both walls every 1.5-2.5 m.
"""

from __future__ import annotations

import numpy as np

from .paths import look_at_c2w
from .scene import Box, Sphere, SyntheticScene
from .source import SyntheticSource

LENGTH = 40.0
CORRIDOR_MIN = np.array([-1.0, -1.5, -1.5])
CORRIDOR_MAX = np.array([LENGTH, 1.5, 1.5])
STEP = 0.015                      # metres per frame at speed 1


def corridor_objects(seed: int) -> list:
    rng = np.random.default_rng([seed, 4242])
    objects, x, side = [], 1.0, 1.0
    while x < LENGTH - 2:
        size = rng.uniform(0.3, 0.7)
        z_wall = side * 1.5
        if rng.random() < 0.6:        # a box against the wall, standing on the floor
            top = 1.5 - rng.uniform(0.4, 1.4)
            objects.append(Box(np.array([x, top, min(z_wall, z_wall - side * size)]),
                               np.array([x + size, 1.5, max(z_wall, z_wall - side * size)])))
        else:                         # a ball near the wall, resting or floating
            r = size / 2
            objects.append(Sphere(np.array([x + r, rng.uniform(0.2, 1.5 - r), z_wall - side * (r + 0.1)]), r))
        x += rng.uniform(1.5, 2.5)
        side = -side
    return objects


PERIOD = 800                      # frames (at speed 1) after which the pan, sway, bob and roll repeat


def corridor_path(n_frames: int, seed: int = 0, speed: float = 1.0) -> np.ndarray:
    """n_frames x 4 x 4 c2w: walking down the corridor, panning +-35 degrees, with a small bob and roll.

    Every motion but the walk repeats after PERIOD frames, so frames 900-1000 move, pan and see as
    far as frames 100-200 do, only 12 m further down the corridor, with other objects around:
    the long-run benchmark compares the two, and any difference in cost is the run's length."""
    rng = np.random.default_rng([seed, 31337])
    wob = rng.uniform(0, 2 * np.pi, size=4)
    s = np.arange(n_frames, dtype=np.float64) * speed
    w = 2 * np.pi / PERIOD
    x = 0.0 + STEP * s
    z = 0.35 * np.sin(w * s + wob[0])
    y = -0.1 + 0.05 * np.sin(8 * w * s + wob[1])
    yaw = np.radians(35.0) * np.sin(2 * w * s + wob[2])
    pitch = 0.1 * np.sin(2 * w * s + wob[3])
    eyes = np.stack([x, y, z], axis=1)
    forward = np.stack([np.cos(yaw), np.sin(pitch), np.sin(yaw)], axis=1)
    roll = 0.05 * np.sin(4 * w * s)
    return np.stack([look_at_c2w(e, e + f, roll=r) for e, f, r in zip(eyes, forward, roll)])


class CorridorSource(SyntheticSource):
    """SyntheticSource in the corridor (same options; n_frames at most what the corridor holds)."""

    format_name = "synthetic-corridor"

    def __init__(self, n_frames: int = 1000, width: int = 320, height: int = 240, seed: int = 0,
                 max_depth: float | None = 5.0, speed: float = 1.0, **options):
        if n_frames * speed * STEP > LENGTH - 3:
            raise ValueError(f"{n_frames} frames at speed {speed} walk beyond the {LENGTH:.0f} m corridor")
        super().__init__(n_frames=n_frames, width=width, height=height, seed=seed, max_depth=max_depth,
                         speed=speed, **options)
        self.scene = SyntheticScene(seed=self.seed, objects=corridor_objects(self.seed),
                                    lo=CORRIDOR_MIN.copy(), hi=CORRIDOR_MAX.copy())
        self.c2w = corridor_path(self.n_frames, self.seed, speed)

    def describe(self) -> str:
        return (f"synthetic corridor (seed {self.seed}, {self.n_frames} frames, "
                f"{self._intrinsics.width}x{self._intrinsics.height})")
