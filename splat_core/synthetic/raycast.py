"""The synthetic scene's ray caster: one Numba pass over the pixels (`SyntheticScene.render`).

Per pixel: the ray through it, its nearest hit (the room's six faces, then the objects in their
order: boxes by slabs, spheres by the quadratic), the surface normal and the surface's procedural
texture (scene.py describes the textures). It computes what the numpy ray caster it replaced did,
operation for operation and in the same order, so the frames are those of before: the numpy
matrix products (OpenBLAS: one chain of fused multiply-adds per output) are written as that
chain (`_fma`); the lighting's matrix-vector product stays in numpy (scene.py). numpy's tanh is
its own SIMD code, ~1 ulp from libm's in a quarter of the values, which the float32 output almost
never shows (tests/synthetic: the frames against the numpy caster).

Why: the numpy caster took ~36 ms a frame at 320 x 240 in many small array operations, each
taking Python's lock, so reading the synthetic sequence slowed the tracker and mapper threads
beside it (a live run's CPU per frame 0.57 s, 0.45 with the frames read beforehand;
docs/benchmarks.md, "Live rate"). This kernel releases the lock and runs on both cores.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir

from ..parallel import numba_lock  # noqa: F401  (first: the vector width is set before any kernel compiles)
from numba import njit, prange, types  # noqa: E402
from numba.core import cgutils
from numba.extending import intrinsic

# Surface ids (scene.py): 0..5 the room's faces, 6.. the objects.
FLOOR, CEILING, WALL_XN, WALL_XP, WALL_ZN, WALL_ZP = range(6)
N_ROOM_FACES = 6
BOX, SPHERE = 0, 1
_EPS = 1e-9


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c rounded once (llvm.fma), as OpenBLAS's matrix products compute each term."""
    if not (a == b == c == types.float64):
        return None

    def codegen(context, builder, sig, args):
        d = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(d, [d, d, d]), "llvm.fma.f64")
        return builder.call(fn, args)

    return types.float64(types.float64, types.float64, types.float64), codegen


@njit(cache=True, nogil=True)
def _smoothstep(x):
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, nogil=True)
def _value_noise(a, b, lattice, cell):
    n0, n1 = lattice.shape
    x, y = a / cell, b / cell
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = _smoothstep(x - x0), _smoothstep(y - y0)
    i0 = np.int64(x0) % n0
    j0 = np.int64(y0) % n1
    i1, j1 = (i0 + 1) % n0, (j0 + 1) % n1
    top = lattice[i0, j0] * (1 - fx) + lattice[i1, j0] * fx
    bottom = lattice[i0, j1] * (1 - fx) + lattice[i1, j1] * fx
    return top * (1 - fy) + bottom * fy


@njit(cache=True, nogil=True)
def _fractal_noise(a, b, lattices, cell):
    """Three octaves (cell, cell / 2, cell / 4) weighted 1, 1/2, 1/4, normalised to [0, 1]."""
    total = 0.0 + 1.0 * _value_noise(a, b, lattices[0], cell)
    total = total + 0.5 * _value_noise(a, b, lattices[1], cell / 2)
    total = total + 0.25 * _value_noise(a, b, lattices[2], cell / 4)
    return total / 1.75


@njit(cache=True, nogil=True)
def _soft_checker(a, b, size):
    s = np.sin(np.pi * a / size) * np.sin(np.pi * b / size)
    return 0.5 + 0.5 * np.tanh(6.0 * s)


@njit(cache=True, nogil=True)
def _mix(out, c0, c1, t):
    """out[c] = c0[c] (1 - t) + c1[c] t with t clipped to [0, 1]."""
    t = min(max(t, 0.0), 1.0)
    for c in range(3):
        out[c] = c0[c] * (1 - t) + c1[c] * t


@njit(cache=True, nogil=True)
def _albedo(out, tmp, sid, x, y, z, lattices, palette, solid_df, solid_phases):
    """The surface's colour at world point (x, y, z) into out (3); tmp: 3 values of scratch."""
    pal, lat = palette[sid], lattices[sid]
    if sid == FLOOR:
        pattern = 0.65 * _soft_checker(x, z, 0.5) + 0.35 * _fractal_noise(x, z, lat, 0.4)
        _mix(out, pal[0], pal[1], pattern)
        g = 0.8 + 0.2 * _value_noise(x, z, lat[2], 0.05)
        for c in range(3):
            out[c] = out[c] * g
    elif sid == CEILING:
        _mix(out, pal[0], pal[1], _fractal_noise(x, z, lat, 0.8))
    elif sid == WALL_XN:
        stripes = 0.5 + 0.5 * np.sin(2 * np.pi * z / 0.35)
        _mix(out, pal[0], pal[1], 0.6 * stripes + 0.4 * _fractal_noise(z, y, lat, 0.5))
    elif sid == WALL_XP:
        plaid = 0.5 + 0.25 * np.sin(2 * np.pi * z / 0.6) + 0.25 * np.sin(2 * np.pi * y / 0.45 + 1.0)
        _mix(out, pal[0], pal[2], plaid)
        g = 0.75 + 0.25 * _fractal_noise(z, y, lat, 0.3)
        for c in range(3):
            out[c] = out[c] * g
    elif sid == WALL_ZN:
        _mix(tmp, pal[0], pal[1], _fractal_noise(x, y, lat, 0.6))
        v = _value_noise(x, y, lat[1], 0.25)
        _mix(out, tmp, pal[2], v * v)
    elif sid == WALL_ZP:
        diag = 0.5 + 0.5 * np.sin(2 * np.pi * (x + y) / 0.5)
        _mix(out, pal[0], pal[1], 0.5 * diag + 0.5 * _fractal_noise(x, y, lat, 0.4))
    else:                          # objects: a solid texture (mean of six 3D sinusoids)
        df, ph = solid_df[sid], solid_phases[sid]
        k = df.shape[0]
        acc = 0.0
        for j in range(k):
            acc += np.sin(_fma(z, df[j, 2], _fma(y, df[j, 1], x * df[j, 0])) + ph[j])
        _mix(out, pal[0], pal[1], 0.5 + 0.5 * (acc / k) * math.sqrt(2.0))
        if (sid - N_ROOM_FACES) % 2 == 0:      # every other object: a 3D checker for hard edges
            ch = _soft_checker(x + z, y, 0.2) * 0.5 + 0.5 * _soft_checker(x - z, y + 0.1, 0.2)
            tmp[:] = out
            _mix(out, tmp, pal[2], 0.5 * ch)


@njit(parallel=True, cache=True, nogil=True)
def cast(origin, rot, fx, fy, cx, cy, width, height, lo, hi, kinds, obj_a, obj_b, obj_c,
         lattices, palette, solid_df, solid_phases, depth, normal, albedo):
    """Fill depth (H x W: the ray parameter, camera z), normal (H W x 3) and albedo (H W x 3).

    rot: the camera-to-world rotation; objects i: kinds[i] BOX (obj_a, obj_b: its corners) or
    SPHERE (obj_a: centre, obj_b[0]: radius, obj_c: |origin - centre|^2 - radius^2)."""
    faces = np.array([[WALL_XN, WALL_XP], [CEILING, FLOOR], [WALL_ZN, WALL_ZP]])
    for v in prange(height):
        dw = np.empty(3)
        d = np.empty(3)
        inv = np.empty(3)
        p = np.empty(3)
        col = np.empty(3)
        tmp = np.empty(3)
        for u in range(width):
            dc0 = (u - cx) / fx
            dc1 = (v - cy) / fy
            for k in range(3):        # d_cam @ rot.T (gemm: one fma chain per output)
                dw[k] = _fma(1.0, rot[k, 2], _fma(dc1, rot[k, 1], dc0 * rot[k, 0]))
                d[k] = _EPS if abs(dw[k]) < _EPS else dw[k]
                inv[k] = 1.0 / d[k]
            t_best = 0.0
            surf = 0
            for k in range(3):        # the room: the face each axis's travel reaches first
                pos = d[k] > 0
                t_k = ((hi[k] if pos else lo[k]) - origin[k]) * inv[k]
                s_k = faces[k, 1] if pos else faces[k, 0]
                if k == 0 or t_k < t_best:
                    t_best, surf = t_k, s_k
            box_axis = 0
            for j in range(kinds.shape[0]):
                if kinds[j] == BOX:
                    t_near = t_far = 0.0
                    axis = 0
                    for k in range(3):
                        t1 = (obj_a[j, k] - origin[k]) * inv[k]
                        t2 = (obj_b[j, k] - origin[k]) * inv[k]
                        tl, th = min(t1, t2), max(t1, t2)
                        if k == 0:
                            t_near, t_far = tl, th
                        else:
                            if tl > t_near:
                                axis = k
                            t_near, t_far = max(t_near, tl), min(t_far, th)
                    hit = t_near <= t_far and t_near > 1e-6 and t_near < t_best
                    t_hit = t_near
                    if hit:
                        box_axis = axis
                else:
                    oc0, oc1, oc2 = origin[0] - obj_a[j, 0], origin[1] - obj_a[j, 1], origin[2] - obj_a[j, 2]
                    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    b = d[0] * oc0 + d[1] * oc1 + d[2] * oc2
                    disc = b * b - a * obj_c[j]
                    ok = disc >= 0
                    t_hit = (-b - np.sqrt(disc if ok else 0.0)) / a
                    hit = ok and t_hit > 1e-6 and t_hit < t_best
                if hit:
                    t_best, surf = t_hit, N_ROOM_FACES + j
            i = v * width + u
            depth[v, u] = t_best
            for k in range(3):
                normal[i, k] = 0.0
            if surf < N_ROOM_FACES:    # room faces: normals point into the room
                axis_k = 0 if surf in (WALL_XN, WALL_XP) else (1 if surf in (CEILING, FLOOR) else 2)
                normal[i, axis_k] = 1.0 if surf in (WALL_XN, CEILING, WALL_ZN) else -1.0
            elif kinds[surf - N_ROOM_FACES] == BOX:
                normal[i, box_axis] = -np.sign(d[box_axis])
            else:
                j = surf - N_ROOM_FACES
                for k in range(3):
                    normal[i, k] = (origin[k] + t_best * d[k] - obj_a[j, k]) / obj_b[j, 0]
            for k in range(3):        # the textures see the ray's own direction, not the safe one
                p[k] = origin[k] + t_best * dw[k]
            _albedo(col, tmp, surf, p[0], p[1], p[2], lattices, palette, solid_df, solid_phases)
            for c in range(3):
                albedo[i, c] = col[c]
