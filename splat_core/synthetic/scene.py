"""Procedural RGB-D scenes with exact poses: the demo scene, test fixtures and benchmark input.

The scene is ray-cast analytically in numpy (no Gaussian renderer involved, so tests that use it
to check tracking or rendering are not circular):

- a closed room (6 x 3 x 6 m box) whose floor, ceiling and four walls each carry a different
  procedural texture (soft checkers, stripes, plaids, multi-octave value noise), so that photometric
  tracking has structure at several scales to lock on to;
- a few objects (axis-aligned boxes, spheres) with solid (3D) textures;
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

ROOM_MIN = np.array([-3.0, -1.5, -3.0])
ROOM_MAX = np.array([3.0, 1.5, 3.0])
FPS = 30.0
LIGHT_DIR = np.array([0.35, -1.0, 0.25]) / np.linalg.norm([0.35, -1.0, 0.25])  # towards the light (up, -y)
AMBIENT = 0.4
_EPS = 1e-9


# ----------------------------------------------------------------------------- texture primitives

def _smoothstep(x):
    return x * x * (3.0 - 2.0 * x)


def _value_noise(a, b, lattice, cell):
    """Smooth 2D value noise in [0, 1] at surface coordinates (a, b) metres; `lattice` is a periodic
    random grid, `cell` the lattice spacing in metres."""
    n0, n1 = lattice.shape
    x, y = a / cell, b / cell
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = _smoothstep(x - x0), _smoothstep(y - y0)
    i0 = x0.astype(np.int64) % n0
    j0 = y0.astype(np.int64) % n1
    i1, j1 = (i0 + 1) % n0, (j0 + 1) % n1
    top = lattice[i0, j0] * (1 - fx) + lattice[i1, j0] * fx
    bottom = lattice[i0, j1] * (1 - fx) + lattice[i1, j1] * fx
    return top * (1 - fy) + bottom * fy


def _fractal_noise(a, b, lattices, cell):
    """Sum of octaves of value noise (cell, cell/2, ...), normalised to [0, 1]."""
    total, weight, w = 0.0, 0.0, 1.0
    for k, lat in enumerate(lattices):
        total = total + w * _value_noise(a, b, lat, cell / 2 ** k)
        weight += w
        w *= 0.5
    return total / weight


def _soft_checker(a, b, size, sharpness=6.0):
    """Checkerboard in [0, 1] with smooth (not pixel-aliased) edges."""
    s = np.sin(np.pi * a / size) * np.sin(np.pi * b / size)
    return 0.5 + 0.5 * np.tanh(sharpness * s)


def _mix(c0, c1, t):
    t = np.clip(t, 0.0, 1.0)[..., None]
    return np.asarray(c0) * (1 - t) + np.asarray(c1) * t


@dataclass
class _Textures:
    """Random material parameters drawn once from the seed."""

    lattices: list            # per surface: a list of 3 octave lattices
    solid_dirs: np.ndarray    # per object: K x 3 sinusoid directions
    solid_freqs: np.ndarray   # per object: K spatial frequencies (rad / m)
    solid_phases: np.ndarray  # per object: K phases
    palette: np.ndarray       # per surface: 3 colours (3 x 3)


def _solid(points, dirs, freqs, phases):
    """Solid texture in [0, 1]: normalised sum of 3D sinusoids of the world point."""
    s = np.sin(points @ (dirs * freqs[:, None]).T + phases)
    return 0.5 + 0.5 * s.mean(axis=-1) * np.sqrt(2.0)


# ----------------------------------------------------------------------------- the scene

@dataclass
class Box:
    lo: np.ndarray
    hi: np.ndarray


@dataclass
class Sphere:
    centre: np.ndarray
    radius: float


# Surface ids: 0..5 room faces, 6.. objects.
FLOOR, CEILING, WALL_XN, WALL_XP, WALL_ZN, WALL_ZP = range(6)
N_ROOM_FACES = 6


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
        n_surf = N_ROOM_FACES + len(self.objects)
        lattices = [[rng.random((32, 32)) for _ in range(3)] for _ in range(n_surf)]
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

    # -- geometry -------------------------------------------------------------------------------

    def intersect(self, origin: np.ndarray, dirs: np.ndarray):
        """Nearest hit of rays origin + t * dirs (dirs N x 3, any length).

        Returns t (N,), surface id (N,) int, unit normal (N x 3) on the side facing the origin.
        Every ray from inside the room hits something (the room is closed).
        """
        d = [np.where(np.abs(c) < _EPS, _EPS, c) for c in dirs.T]   # per-axis components
        inv = [1.0 / c for c in d]
        # Room: the ray exits the box through, per axis, the plane it travels towards.
        t_best, surf = None, None
        faces = [(WALL_XN, WALL_XP), (CEILING, FLOOR), (WALL_ZN, WALL_ZP)]
        for k in range(3):
            pos = d[k] > 0
            t_k = (np.where(pos, self.hi[k], self.lo[k]) - origin[k]) * inv[k]
            s_k = np.where(pos, faces[k][1], faces[k][0])
            if t_best is None:
                t_best, surf = t_k, s_k
            else:
                closer = t_k < t_best
                t_best = np.where(closer, t_k, t_best)
                surf = np.where(closer, s_k, surf)
        box_axis = np.zeros(len(t_best), dtype=np.int8)   # hit face axis, for box normals

        for j, obj in enumerate(self.objects):
            sid = N_ROOM_FACES + j
            if isinstance(obj, Box):
                t_near = t_far = axis = None
                for k in range(3):
                    t1 = (obj.lo[k] - origin[k]) * inv[k]
                    t2 = (obj.hi[k] - origin[k]) * inv[k]
                    lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
                    if t_near is None:
                        t_near, t_far, axis = lo, hi, np.zeros(len(lo), dtype=np.int8)
                    else:
                        axis = np.where(lo > t_near, np.int8(k), axis)
                        t_near, t_far = np.maximum(t_near, lo), np.minimum(t_far, hi)
                hit = (t_near <= t_far) & (t_near > 1e-6) & (t_near < t_best)
                t_hit = t_near
                box_axis = np.where(hit, axis, box_axis)
            else:
                oc = origin - obj.centre
                a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                b = d[0] * oc[0] + d[1] * oc[1] + d[2] * oc[2]
                disc = b * b - a * (oc @ oc - obj.radius ** 2)
                ok = disc >= 0
                t_hit = (-b - np.sqrt(np.where(ok, disc, 0.0))) / a
                hit = ok & (t_hit > 1e-6) & (t_hit < t_best)
            t_best = np.where(hit, t_hit, t_best)
            surf = np.where(hit, sid, surf)

        dirs_safe = np.stack(d, axis=1)
        points = origin + t_best[:, None] * dirs_safe
        normal = np.zeros_like(points)
        for sid in np.unique(surf):
            m = surf == sid
            if sid < N_ROOM_FACES:   # room faces: normals point into the room
                axis_k = {WALL_XN: 0, WALL_XP: 0, CEILING: 1, FLOOR: 1, WALL_ZN: 2, WALL_ZP: 2}[sid]
                sign = 1.0 if sid in (WALL_XN, CEILING, WALL_ZN) else -1.0
                normal[m, axis_k] = sign
                continue
            obj = self.objects[sid - N_ROOM_FACES]
            if isinstance(obj, Box):
                idx = np.flatnonzero(m)
                ax = box_axis[idx].astype(np.int64)
                normal[idx, ax] = -np.sign(dirs_safe[idx, ax])
            else:
                normal[m] = (points[m] - obj.centre) / obj.radius
        return t_best, surf, normal

    # -- appearance -----------------------------------------------------------------------------

    def albedo(self, points: np.ndarray, surf: np.ndarray) -> np.ndarray:
        """View-independent surface colour (N x 3) at world points on surfaces `surf`."""
        out = np.zeros_like(points)
        tex = self.tex
        for sid in np.unique(surf):
            m = surf == sid
            p = points[m]
            x, y, z = p[:, 0], p[:, 1], p[:, 2]
            pal, lat = tex.palette[sid], tex.lattices[sid]
            if sid == FLOOR:       # tiles with grainy noise
                pattern = 0.65 * _soft_checker(x, z, 0.5) + 0.35 * _fractal_noise(x, z, lat, 0.4)
                col = _mix(pal[0], pal[1], pattern) * (0.8 + 0.2 * _value_noise(x, z, lat[2], 0.05))[:, None]
            elif sid == CEILING:   # smooth blotches
                col = _mix(pal[0], pal[1], _fractal_noise(x, z, lat, 0.8))
            elif sid == WALL_XN:   # vertical stripes modulated by noise
                stripes = 0.5 + 0.5 * np.sin(2 * np.pi * z / 0.35)
                col = _mix(pal[0], pal[1], 0.6 * stripes + 0.4 * _fractal_noise(z, y, lat, 0.5))
            elif sid == WALL_XP:   # plaid: sums of sinusoids along both wall axes
                plaid = 0.5 + 0.25 * np.sin(2 * np.pi * z / 0.6) + 0.25 * np.sin(2 * np.pi * y / 0.45 + 1.0)
                col = _mix(pal[0], pal[2], plaid) * (0.75 + 0.25 * _fractal_noise(z, y, lat, 0.3))[:, None]
            elif sid == WALL_ZN:   # three-colour value noise
                col = _mix(_mix(pal[0], pal[1], _fractal_noise(x, y, lat, 0.6)), pal[2],
                           _value_noise(x, y, lat[1], 0.25) ** 2)
            elif sid == WALL_ZP:   # diagonal stripes with noise
                diag = 0.5 + 0.5 * np.sin(2 * np.pi * (x + y) / 0.5)
                col = _mix(pal[0], pal[1], 0.5 * diag + 0.5 * _fractal_noise(x, y, lat, 0.4))
            else:                  # objects: solid textures
                s = _solid(p, tex.solid_dirs[sid], tex.solid_freqs[sid], tex.solid_phases[sid])
                col = _mix(pal[0], pal[1], s)
                if (sid - N_ROOM_FACES) % 2 == 0:  # every other object: a 3D checker for hard edges
                    ch = _soft_checker(x + z, y, 0.2) * 0.5 + 0.5 * _soft_checker(x - z, y + 0.1, 0.2)
                    col = _mix(col, pal[2], 0.5 * ch)
            out[m] = col
        return out

    def shade(self, albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Baked Lambertian lighting: ambient + diffuse from LIGHT_DIR (view-independent)."""
        lambert = np.clip(normal @ LIGHT_DIR, 0.0, None)
        return np.clip(albedo * (AMBIENT + (1.0 - AMBIENT) * lambert)[:, None], 0.0, 1.0)

    # -- rendering ------------------------------------------------------------------------------

    def render(self, c2w: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Colour (HxWx3 float32 in [0, 1]) and depth (HxW float32, camera z in metres) seen by a
        camera at `c2w` (4x4, OpenCV axes). The camera centre must be inside the room."""
        c2w = np.asarray(c2w, dtype=np.float64)
        origin = c2w[:3, 3]
        if np.any(origin <= self.lo) or np.any(origin >= self.hi):
            raise ValueError(f"camera centre {origin} is outside the synthetic room")
        K = intrinsics
        u, v = np.meshgrid(np.arange(K.width, dtype=np.float64), np.arange(K.height, dtype=np.float64))
        # Camera-space ray with z = 1, so the ray parameter t IS the camera depth.
        d_cam = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
        d_world = d_cam @ c2w[:3, :3].T
        t, surf, normal = self.intersect(origin, d_world)
        points = origin + t[:, None] * d_world
        color = self.shade(self.albedo(points, surf), normal)
        return (color.reshape(K.height, K.width, 3).astype(np.float32),
                t.reshape(K.height, K.width).astype(np.float32))
