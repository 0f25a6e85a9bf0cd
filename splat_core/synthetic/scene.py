"""Procedural RGB-D scenes with exact poses: the demo scene, test fixtures and benchmark input.

The scene is ray-cast analytically (no Gaussian renderer involved, so tests that use it to check
tracking or rendering are not circular; `raycast.py`: one Numba pass over the pixels):

- a closed room (6 x 3 x 6 m box) whose floor, ceiling and four walls each carry a different
  procedural texture (soft checkers, stripes, plaids, multi-octave value noise: bilinear
  interpolation of a periodic 32 x 32 random lattice, octaves of 1, 1/2 and 1/4 the cell), so that
  photometric tracking has structure at several scales to lock on to;
- a few objects (axis-aligned boxes, spheres) with solid (3D) textures (the mean of six 3D
  sinusoids of the world point; every other object also a 3D soft checker);
- baked Lambertian lighting from a fixed direction plus ambient: colour varies with surface
  orientation but not with the viewpoint, so every view of a point has the same colour.

World frame: x right, y DOWN (gravity is +y, as OpenCV camera axes with a level camera), z forward.
The floor is the plane y = +1.5, the ceiling y = -1.5, walls at x = +-3 and z = +-3.

Depth is the camera z of the first surface hit (not the ray length), metres, float32; colour is
float32 in [0, 1]. Pixel centres sit at integer coordinates (camera.py conventions).

The camera path (`paths.camera_path`) orbits the objects at about 2 m with a wobbling look-at target and
a small roll, so it rotates about all three axes. Its speed is fixed per frame (independent of
n_frames), like a hand-held capture at 30 fps: about 1.5 cm and 0.5-1 degree per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Intrinsics
from ..parallel import numba_lock
from . import raycast

ROOM_MIN = np.array([-3.0, -1.5, -3.0])
ROOM_MAX = np.array([3.0, 1.5, 3.0])
FPS = 30.0
LIGHT_DIR = np.array([0.35, -1.0, 0.25]) / np.linalg.norm([0.35, -1.0, 0.25])  # towards the light (up, -y)
AMBIENT = 0.4


@dataclass
class _Textures:
    """Random material parameters drawn once from the seed."""

    lattices: np.ndarray      # per surface: 3 octave lattices (n_surf x 3 x 32 x 32)
    solid_dirs: np.ndarray    # per object: K x 3 sinusoid directions
    solid_freqs: np.ndarray   # per object: K spatial frequencies (rad / m)
    solid_phases: np.ndarray  # per object: K phases
    palette: np.ndarray       # per surface: 3 colours (3 x 3)


@dataclass
class Box:
    lo: np.ndarray
    hi: np.ndarray


@dataclass
class Sphere:
    centre: np.ndarray
    radius: float


def _default_objects():
    return [
        Box(np.array([-0.4, 0.7, 0.2]), np.array([0.6, 1.5, 0.8])),       # table-sized block on the floor
        Sphere(np.array([-0.9, 1.1, -0.2]), 0.4),                         # ball resting on the floor
        Box(np.array([0.7, 0.2, -0.9]), np.array([1.2, 1.5, -0.4])),      # tall pillar
        Sphere(np.array([0.3, 0.25, 1.3]), 0.25),                         # floating ball
        Box(np.array([-1.3, 1.1, 0.9]), np.array([-0.8, 1.5, 1.4])),      # low crate
    ]


@dataclass
class SyntheticScene:
    """The room and its objects with seed-dependent textures. `render(c2w, intrinsics)` ray-casts.
    `lo` / `hi`: the room's corners (default the 6 x 3 x 6 m room)."""

    seed: int = 0
    objects: list = field(default_factory=_default_objects)
    lo: np.ndarray = field(default_factory=lambda: ROOM_MIN.copy())
    hi: np.ndarray = field(default_factory=lambda: ROOM_MAX.copy())

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        n_surf = raycast.N_ROOM_FACES + len(self.objects)
        lattices = np.array([[rng.random((32, 32)) for _ in range(3)] for _ in range(n_surf)]).reshape(n_surf, 3, 32, 32)
        k = 6
        dirs = rng.normal(size=(n_surf, k, 3))
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        self.tex = _Textures(
            lattices=lattices,
            solid_dirs=dirs,
            solid_freqs=rng.uniform(10.0, 40.0, size=(n_surf, k)),
            solid_phases=rng.uniform(0, 2 * np.pi, size=(n_surf, k)),
            palette=np.clip(rng.uniform(0.1, 0.95, size=(n_surf, 3, 3)), 0, 1),
        )
        # The objects as the ray caster reads them: kind, then corners (box) or centre and radius (sphere).
        n = len(self.objects)
        self._kinds = np.array([raycast.BOX if isinstance(o, Box) else raycast.SPHERE for o in self.objects],
                               dtype=np.int64)
        self._obj_a, self._obj_b = np.zeros((n, 3)), np.zeros((n, 3))
        for j, o in enumerate(self.objects):
            if isinstance(o, Box):
                self._obj_a[j], self._obj_b[j] = o.lo, o.hi
            else:
                self._obj_a[j], self._obj_b[j, 0] = o.centre, o.radius
        self._solid_df = self.tex.solid_dirs * self.tex.solid_freqs[:, :, None]   # K x 3 per surface

    def shade(self, albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Baked Lambertian lighting: ambient + diffuse from LIGHT_DIR (view-independent)."""
        lambert = np.clip(normal @ LIGHT_DIR, 0.0, None)
        return np.clip(albedo * (AMBIENT + (1.0 - AMBIENT) * lambert)[:, None], 0.0, 1.0)

    def render(self, c2w: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Colour (HxWx3 float32 in [0, 1]) and depth (HxW float32, camera z in metres) seen by a
        camera at `c2w` (4x4, OpenCV axes). The camera centre must be inside the room."""
        c2w = np.asarray(c2w, dtype=np.float64)
        origin = np.ascontiguousarray(c2w[:3, 3])
        if np.any(origin <= self.lo) or np.any(origin >= self.hi):
            raise ValueError(f"camera centre {origin} is outside the synthetic room")
        K = intrinsics
        # |origin - centre|^2 - r^2 per sphere (numpy's dot, as the caster it replaced computed it)
        sphere_c = np.array([(origin - o.centre) @ (origin - o.centre) - o.radius ** 2 if isinstance(o, Sphere)
                             else 0.0 for o in self.objects])
        depth = np.empty((K.height, K.width))
        normal = np.empty((K.height * K.width, 3))
        albedo = np.empty((K.height * K.width, 3))
        with numba_lock():
            raycast.cast(origin, np.ascontiguousarray(c2w[:3, :3]), float(K.fx), float(K.fy), float(K.cx),
                         float(K.cy), K.width, K.height, np.asarray(self.lo, np.float64), np.asarray(self.hi, np.float64),
                         self._kinds, self._obj_a, self._obj_b, sphere_c, self.tex.lattices, self.tex.palette,
                         self._solid_df, self.tex.solid_phases, depth, normal, albedo)
        color = self.shade(albedo, normal)
        return color.reshape(K.height, K.width, 3).astype(np.float32), depth.astype(np.float32)
