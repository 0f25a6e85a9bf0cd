"""The synthetic scene's numpy ray caster: the oracle of splat_core/synthetic/raycast.py.

The scene was ray-cast by this code (array operations over all pixels) until the Numba caster
replaced it; `render_numpy` is kept here as the definition the Numba caster must reproduce
(tests/synthetic/test_synthetic.py compares their frames).
"""

import numpy as np

from splat_core.synthetic.raycast import (CEILING, FLOOR, N_ROOM_FACES, WALL_XN, WALL_XP, WALL_ZN,
                                          WALL_ZP)
from splat_core.synthetic.scene import Box

_EPS = 1e-9


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


def _solid(points, dirs, freqs, phases):
    """Solid texture in [0, 1]: normalised sum of 3D sinusoids of the world point."""
    s = np.sin(points @ (dirs * freqs[:, None]).T + phases)
    return 0.5 + 0.5 * s.mean(axis=-1) * np.sqrt(2.0)


def intersect(scene, origin: np.ndarray, dirs: np.ndarray):
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
        t_k = (np.where(pos, scene.hi[k], scene.lo[k]) - origin[k]) * inv[k]
        s_k = np.where(pos, faces[k][1], faces[k][0])
        if t_best is None:
            t_best, surf = t_k, s_k
        else:
            closer = t_k < t_best
            t_best = np.where(closer, t_k, t_best)
            surf = np.where(closer, s_k, surf)
    box_axis = np.zeros(len(t_best), dtype=np.int8)   # hit face axis, for box normals

    for j, obj in enumerate(scene.objects):
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
        obj = scene.objects[sid - N_ROOM_FACES]
        if isinstance(obj, Box):
            idx = np.flatnonzero(m)
            ax = box_axis[idx].astype(np.int64)
            normal[idx, ax] = -np.sign(dirs_safe[idx, ax])
        else:
            normal[m] = (points[m] - obj.centre) / obj.radius
    return t_best, surf, normal



def albedo(scene, points: np.ndarray, surf: np.ndarray) -> np.ndarray:
    """View-independent surface colour (N x 3) at world points on surfaces `surf`."""
    out = np.zeros_like(points)
    tex = scene.tex
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



def render_numpy(scene, c2w, intrinsics):
    """`SyntheticScene.render` as numpy array operations."""
    c2w = np.asarray(c2w, dtype=np.float64)
    origin = c2w[:3, 3]
    K = intrinsics
    u, v = np.meshgrid(np.arange(K.width, dtype=np.float64), np.arange(K.height, dtype=np.float64))
    d_cam = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
    d_world = d_cam @ c2w[:3, :3].T
    t, surf, normal = intersect(scene, origin, d_world)
    points = origin + t[:, None] * d_world
    color = scene.shade(albedo(scene, points, surf), normal)
    return (color.reshape(K.height, K.width, 3).astype(np.float32),
            t.reshape(K.height, K.width).astype(np.float32))
