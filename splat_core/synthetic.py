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

The camera path (`camera_path`) orbits the objects at about 2 m with a wobbling look-at target and
a small roll, so it rotates about all three axes. Its speed is fixed per frame (independent of
n_frames), like a hand-held capture at 30 fps: about 1.5 cm and 0.5-1 degree per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import Intrinsics
from .frame import Frame
from .io.source import FrameSource

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


# ----------------------------------------------------------------------------- camera path

def look_at_c2w(eye, target, up=(0.0, -1.0, 0.0), roll: float = 0.0) -> np.ndarray:
    """c2w (OpenCV axes) of a camera at `eye` looking at `target`; `up` is the world up (-y here);
    `roll` (radians) rotates the camera about its viewing axis."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)          # camera +x (right) = forward x up for y-down camera axes
    x /= np.linalg.norm(x)
    y = np.cross(z, x)           # camera +y points down
    R = np.stack([x, y, z], axis=1)
    c, s = np.cos(roll), np.sin(roll)
    R = R @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, eye
    return T


ORBIT_CENTRE = np.array([0.0, 0.6, 0.3])


def camera_path(n_frames: int, seed: int = 0, speed: float = 1.0) -> np.ndarray:
    """n_frames x 4 x 4 c2w poses of a smooth hand-held-like orbit around the objects.

    The path depends on the frame index only (not on n_frames); the seed picks the starting phase.
    `speed` scales the per-frame motion (1.0: ~1.5 cm and ~0.5-1 degree per frame).
    """
    rng = np.random.default_rng([seed, 7919])
    phase = rng.uniform(0, 2 * np.pi)
    wob = rng.uniform(0, 2 * np.pi, size=5)
    s = np.arange(n_frames, dtype=np.float64) * speed
    theta = phase + 0.0072 * s                       # ~1.45 cm/frame along a 2 m orbit
    radius = 2.0 + 0.25 * np.sin(0.021 * s + wob[0])
    height = -0.05 + 0.2 * np.sin(0.033 * s + wob[1])  # y (down): eye ~1.55 m above the floor
    eyes = np.stack([ORBIT_CENTRE[0] + radius * np.cos(theta), np.full_like(s, 0.0) + height,
                     ORBIT_CENTRE[2] + radius * np.sin(theta)], axis=1)
    targets = ORBIT_CENTRE + np.stack([0.35 * np.sin(0.045 * s + wob[2]),
                                       0.25 * np.sin(0.06 * s + wob[3]),
                                       0.35 * np.cos(0.04 * s + wob[4])], axis=1)
    roll = 0.1 * np.sin(0.05 * s + phase)
    return np.stack([look_at_c2w(e, t, roll=r) for e, t, r in zip(eyes, targets, roll)])


def default_intrinsics(width: int = 320, height: int = 240, fov_deg: float = 60.0) -> Intrinsics:
    """Square pixels, horizontal field of view `fov_deg`, principal point at the image centre
    (integer pixel centres: the centre is ((W-1)/2, (H-1)/2))."""
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    return Intrinsics(f, f, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))


# ----------------------------------------------------------------------------- sensor effects

def add_depth_noise(depth: np.ndarray, coeff: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with standard deviation coeff * depth^2 (Kinect-like; coeff in 1/m,
    e.g. 0.0015 gives 6 mm at 2 m). Invalid (0) pixels stay 0."""
    if coeff <= 0:
        return depth
    noisy = depth + rng.normal(size=depth.shape) * coeff * depth.astype(np.float64) ** 2
    return np.where(depth > 0, np.maximum(noisy, 1e-3), 0.0).astype(np.float32)


def hole_mask(height: int, width: int, fraction: float, rng: np.random.Generator,
              blob_px: int = 12) -> np.ndarray:
    """Boolean HxW mask of random blobs (about `blob_px` pixels across) covering `fraction` of the
    image: a coarse random field, smoothly upsampled, thresholded at its `fraction` quantile."""
    import cv2

    if fraction <= 0:
        return np.zeros((height, width), dtype=bool)
    gh, gw = max(2, height // blob_px + 2), max(2, width // blob_px + 2)
    field_ = cv2.resize(rng.random((gh, gw)).astype(np.float32), (width, height),
                        interpolation=cv2.INTER_CUBIC)
    return field_ < np.quantile(field_, min(fraction, 1.0))


# ----------------------------------------------------------------------------- the FrameSource

class SyntheticSource(FrameSource):
    """A procedural RGB-D sequence with exact camera-to-world poses (OpenCV axes).

    n_frames, width, height   sequence length and image size
    seed                      textures, path phase and sensor noise (fully deterministic per seed)
    noise                     depth noise coefficient: std = noise * depth^2 (metres; 0 = exact)
    holes                     fraction of pixels set invalid (depth 0) in random blobs (0 = none)
    max_depth                 far-range cutoff: depth beyond it set to 0 (None = no cutoff)
    fov_deg / intrinsics      horizontal field of view, or explicit intrinsics (overrides fov)
    speed                     scales per-frame camera motion (1.0 ~ hand-held at 30 fps)

    Frame i has timestamp i / 30 s and `c2w_ref` = the exact pose used to render it.
    """

    format_name = "synthetic"
    path = None

    def __init__(self, n_frames: int = 60, width: int = 320, height: int = 240, seed: int = 0,
                 noise: float = 0.0, holes: float = 0.0, max_depth: float | None = None,
                 fov_deg: float = 60.0, intrinsics: Intrinsics | None = None, speed: float = 1.0):
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        if not 0.0 <= holes < 1.0:
            raise ValueError(f"holes must be a fraction in [0, 1), got {holes}")
        if noise < 0:
            raise ValueError(f"noise must be >= 0, got {noise}")
        self.n_frames = int(n_frames)
        self.seed = int(seed)
        self.noise = float(noise)
        self.holes = float(holes)
        self.max_depth = max_depth
        if intrinsics is None:
            intrinsics = default_intrinsics(width, height, fov_deg)
        self._intrinsics = intrinsics
        self.scene = SyntheticScene(seed=self.seed)
        self.c2w = camera_path(self.n_frames, self.seed, speed)

    def __len__(self) -> int:
        return self.n_frames

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    @property
    def timestamps(self) -> np.ndarray:
        return np.arange(self.n_frames, dtype=np.float64) / FPS

    @property
    def has_reference_poses(self) -> bool:
        return True

    def reference_c2w(self) -> np.ndarray:
        return self.c2w.copy()

    def render_view(self, c2w: np.ndarray, intrinsics: Intrinsics | None = None):
        """Exact (noise-free, hole-free) colour and depth from any pose inside the room."""
        return self.scene.render(c2w, intrinsics or self._intrinsics)

    def __getitem__(self, i: int) -> Frame:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i} out of range for {self.n_frames} synthetic frames")
        i = i % self.n_frames
        color, depth = self.scene.render(self.c2w[i], self._intrinsics)
        rng = np.random.default_rng([self.seed, i, 1])
        depth = add_depth_noise(depth, self.noise, rng)
        if self.max_depth is not None:
            depth = np.where(depth > self.max_depth, 0.0, depth).astype(np.float32)
        if self.holes > 0:
            depth = np.where(hole_mask(*depth.shape, self.holes, rng), 0.0, depth).astype(np.float32)
        return Frame(index=i, timestamp=i / FPS, color=color, depth=depth,
                     intrinsics=self._intrinsics, c2w_ref=self.c2w[i].copy())

    def describe(self) -> str:
        return (f"synthetic scene (seed {self.seed}, {self.n_frames} frames, "
                f"{self._intrinsics.width}x{self._intrinsics.height})")


def render_view(c2w: np.ndarray, intrinsics: Intrinsics, seed: int = 0):
    """Colour and depth of the synthetic scene with textures from `seed`, at any pose."""
    return SyntheticScene(seed=seed).render(c2w, intrinsics)


# ----------------------------------------------------------------------------- hard captures

HARD_KINDS = ("none", "jump", "covered", "turn")


def turn_away(c2w: np.ndarray, degrees: float) -> np.ndarray:
    """c2w turned by `degrees` about the camera's own vertical axis (a pan, in place)."""
    a = np.radians(degrees)
    pan = np.eye(4)
    pan[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    return c2w @ pan


class HardCapture(FrameSource):
    """The synthetic sequence with one disturbance at frame `at` (issue 13's hard captures):

    none      the undisturbed sequence (the baseline)
    jump      `length` frames (30) missing: frame `at` is followed by frame at+31 of the path, as
              in a recording that dropped a second (indices run on, timestamps jump)
    covered   `length` frames (5) of a covered lens: black colour, no depth (the pipeline skips
              them as bad frames; tracking must pick up after them)
    turn      a fast 90-degree pan away from the objects and back: 90 degrees in 3 frames, held for
              `length` frames (4), 3 frames back; the camera keeps moving along its path

    Reference poses are the poses rendered (`c2w_ref`); the undisturbed path has n_frames frames.
    """

    format_name = "synthetic"
    path = None

    def __init__(self, kind: str = "none", n_frames: int = 60, at: int = 25, length: int | None = None,
                 width: int = 160, height: int = 120, seed: int = 0):
        if kind not in HARD_KINDS:
            raise ValueError(f"kind must be one of {', '.join(HARD_KINDS)}, got {kind!r}")
        self.kind, self.at = kind, int(at)
        self.length = int(length if length is not None else {"jump": 30, "covered": 5, "turn": 4}.get(kind, 0))
        first_undisturbed = at + 1 + {"jump": 0, "covered": self.length, "turn": self.length + 5}.get(kind, 0)
        if not 0 <= at < first_undisturbed < n_frames:
            raise ValueError(f"a '{kind}' at frame {at} does not fit in {n_frames} frames")
        path_frames = n_frames + (self.length if kind == "jump" else 0)
        self.base = SyntheticSource(n_frames=path_frames, width=width, height=height, seed=seed)
        self.path_index = np.arange(path_frames)
        if kind == "jump":
            self.path_index = np.concatenate([self.path_index[: at + 1], self.path_index[at + 1 + self.length:]])
        self.c2w = self.base.c2w[self.path_index].copy()
        if kind == "turn":
            profile = np.concatenate([[30, 60], np.full(self.length + 1, 90), [60, 30]])
            for k, deg in enumerate(profile):
                self.c2w[at + 1 + k] = turn_away(self.c2w[at + 1 + k], deg)

    def __len__(self) -> int:
        return len(self.path_index)

    @property
    def intrinsics(self) -> Intrinsics:
        return self.base.intrinsics

    @property
    def timestamps(self) -> np.ndarray:
        return self.path_index / FPS

    @property
    def has_reference_poses(self) -> bool:
        return True

    def reference_c2w(self) -> np.ndarray:
        return self.c2w.copy()

    def __getitem__(self, i: int) -> Frame:
        color, depth = self.base.scene.render(self.c2w[i], self.intrinsics)
        if self.kind == "covered" and self.at < i <= self.at + self.length:
            color, depth = np.zeros_like(color), np.zeros_like(depth)
        return Frame(index=i, timestamp=float(self.timestamps[i]), color=color, depth=depth,
                     intrinsics=self.intrinsics, c2w_ref=self.c2w[i].copy())

    def describe(self) -> str:
        return f"synthetic hard capture '{self.kind}' at frame {self.at} ({len(self)} frames)"
