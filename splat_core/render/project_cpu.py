"""Projection of isotropic Gaussians on the CPU: one Numba forward kernel, one Numba backward kernel.

`project_isotropic_cpu` computes exactly what `project.project_gaussians_torch` computes for
isotropic Gaussians (log_scales N x 1), with the gradients torch autograd would give; the torch
code stays the reference (and serves anisotropic Gaussians and CUDA tensors). On the CPU the torch
version is ~100 small elementwise ops and a bmm per call; here a call is one pass over the
Gaussians forward and one backward.

Per Gaussian (R, t from w2c; near, eps2d, fx, fy, cx, cy and the clamp limits as in project.py):

    p = R m + t = (x, y, z),  visible = z > near,  zs = z if visible else 1
    u = fx x / zs + cx,  v = fy y / zs + cy
    X = clamp(x / zs, -lim_x_neg, lim_x_pos),  Y = clamp(y / zs, -lim_y_neg, lim_y_pos)
    k = exp(2 log_scale) / zs^2
    a = k fx^2 (1 + X^2) + eps2d,  b = k fx fy X Y,  c = k fy^2 (1 + Y^2) + eps2d   (s^2 J J^T)
    det = a c - b^2,  ok = visible & (det > 0),  ds = det if ok else 1
    conic = (c, -b, a) / ds,  depth = z,  opacity = sigmoid(logit),  radius as in project.py

(the forward evaluates a, b, c in project.py's order of operations, through J, so values agree to
rounding). Backward, from the output gradients gu, gv, gA, gB, gC, gz, go:

    dL/dds = -(gA A + gB B + gC C) / ds
    ga = gC / ds + [ok] dL/dds c,  gb = -gB / ds - [ok] 2 dL/dds b,  gc = gA / ds + [ok] dL/dds a
    gk = ga fx^2 (1 + X^2) + gb fx fy X Y + gc fy^2 (1 + Y^2)
    gX = [lo <= x/zs <= hi] (2 k fx^2 X ga + k fx fy Y gb)      (torch's clamp convention)
    gY = [lo <= y/zs <= hi] (2 k fy^2 Y gc + k fx fy X gb)
    dL/dx = (fx gu + gX) / zs,  dL/dy = (fy gv + gY) / zs
    dL/dz = gz + [visible] (-(fx x gu + fy y gv) / zs^2 - (gX x/zs + gY y/zs + 2 k gk) / zs)
    dL/dlog_scale = 2 k gk,  dL/dlogit = go o (1 - o)

and dL/dmeans = R^T dL/dp, dL/dR = sum dL/dp means^T, dL/dt = sum dL/dp (only the top 3 x 4
block of w2c gets a gradient, as with the torch version; the sums per block of BLOCK Gaussians in
the kernel, then over the blocks).

How it is fast: the loop body vectorises (float32: 16 lanes where LLVM picks AVX-512). What that
needed: flat 1-D arrays indexed with compile-time strides (means 3N, means2d 2N, conics 3N; with
2-D arrays the row stride is a run-time value and LLVM's dependence analysis gives up); prange over
blocks of BLOCK Gaussians with a plain inner loop over views of the block (indices provably >= 0,
so no wraparound selects); a branch-free body (selects only, every store unconditional); sqrt as
the LLVM intrinsic (`_sqrt`: Numba's math.sqrt is a call to libm); cpu.py's inlinable float32
`_exp` for exp (float64 keeps libm's exp, so the float64 kernels stay scalar: they are for tests).

Differences from the torch version, all outside any real map: `_exp` (float32) clamps its argument
to [-87, 88], so a scale above e^44 or below e^-43.5 m, or a sigmoid at |logit| > 87, differs
from torch's inf / 0 (opacities by < 1e-37). Radii past the int32 range: torch's
`.to(torch.int32)` is undefined there, here they saturate at 2^31 - 1 (float32: 2147483520); a
footprint that large needs a standard deviation of ~6e8 px.

float32 inputs stay float32 inside the kernels (constants come in an array of the input dtype:
Numba promotes float32 op float64-literal to float64); float64 runs in float64 (gradcheck). Every
kernel call runs inside `parallel.numba_lock()`.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange, types
from numba.extending import intrinsic

from ..camera import Intrinsics
from ..parallel import numba_lock
from .cpu import _exp
from ._constants import RADIUS_SIGMAS
from ._torch_impl import Projected, clamp_limits

# Layout of the `consts` array handed to the kernels (in the working dtype).
(_K_FX, _K_FY, _K_CX, _K_CY, _K_LXN, _K_LXP, _K_LYN, _K_LYP, _K_NEAR, _K_EPS, _K_RSIG, _K_HALF,
 _K_TENTH, _K_ONE, _K_ZERO, _K_TWO, _K_RIGHT, _K_BOTTOM, _K_RMAX) = range(19)
_K_SIZE = 19
BLOCK = 1024     # Gaussians per prange step (a plain inner loop over a block vectorises)


# ----------------------------------------------------------------------------- kernels

@intrinsic
def _sqrt(typingctx, x):
    """IEEE sqrt as the LLVM intrinsic (Numba's math.sqrt calls libm's sqrtf, which keeps the
    loop scalar; both are correctly rounded, so the values are the same)."""
    if not isinstance(x, types.Float):
        return None

    def codegen(context, builder, sig, args):
        fn = builder.module.declare_intrinsic("llvm.sqrt", [args[0].type])
        return builder.call(fn, args)

    return x(x), codegen


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _forward_kernel(means, Rt, log_scales, logits, consts, means2d, conics, depths, opacities, radii):
    """prange over blocks of BLOCK Gaussians, a plain loop over the Gaussians of a block."""
    fx = consts[_K_FX]
    fy = consts[_K_FY]
    cx = consts[_K_CX]
    cy = consts[_K_CY]
    nlxn = -consts[_K_LXN]
    lxp = consts[_K_LXP]
    nlyn = -consts[_K_LYN]
    lyp = consts[_K_LYP]
    near = consts[_K_NEAR]
    eps = consts[_K_EPS]
    rsig = consts[_K_RSIG]
    half = consts[_K_HALF]
    nhalf = -half
    tenth = consts[_K_TENTH]
    one = consts[_K_ONE]
    zero = consts[_K_ZERO]
    two = consts[_K_TWO]
    right = consts[_K_RIGHT]
    bottom = consts[_K_BOTTOM]
    rmax = consts[_K_RMAX]
    nfx = -fx
    nfy = -fy
    r00, r01, r02, t0 = Rt[0, 0], Rt[0, 1], Rt[0, 2], Rt[0, 3]
    r10, r11, r12, t1 = Rt[1, 0], Rt[1, 1], Rt[1, 2], Rt[1, 3]
    r20, r21, r22, t2 = Rt[2, 0], Rt[2, 1], Rt[2, 2], Rt[2, 3]
    n = log_scales.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo = blk * BLOCK
        hi = min(lo + BLOCK, n)
        mb = means[3 * lo:3 * hi]
        lsb = log_scales[lo:hi]
        lgb = logits[lo:hi]
        m2db = means2d[2 * lo:2 * hi]
        conb = conics[3 * lo:3 * hi]
        depb = depths[lo:hi]
        opb = opacities[lo:hi]
        radb = radii[lo:hi]
        for i in range(hi - lo):
            m0 = mb[3 * i]
            m1 = mb[3 * i + 1]
            m2 = mb[3 * i + 2]
            x = r00 * m0 + r01 * m1 + r02 * m2 + t0
            y = r10 * m0 + r11 * m1 + r12 * m2 + t1
            z = r20 * m0 + r21 * m1 + r22 * m2 + t2
            visible = z > near
            zs = z if visible else one
            u = fx * x / zs + cx
            v = fy * y / zs + cy
            X = x / zs                      # clamp as selects: NaN stays NaN, as with torch.clamp
            X = nlxn if X < nlxn else X
            X = lxp if X > lxp else X
            Y = y / zs
            Y = nlyn if Y < nlyn else Y
            Y = lyp if Y > lyp else Y
            # project.py's order of operations: J = [[fx/zs, 0, -fx tx/zs^2], [0, fy/zs, -fy ty/zs^2]]
            tx = X * zs
            ty = Y * zs
            zs2 = zs * zs
            j00 = fx / zs
            j02 = nfx * tx / zs2
            j11 = fy / zs
            j12 = nfy * ty / zs2
            s2 = _exp(two * lsb[i])
            a = s2 * (j00 * j00 + j02 * j02) + eps
            b = s2 * (j02 * j12)
            c = s2 * (j11 * j11 + j12 * j12) + eps
            det = a * c - b * b
            ok = visible & (det > zero)
            ds = det if ok else one
            m2db[2 * i] = u
            m2db[2 * i + 1] = v
            conb[3 * i] = c / ds
            conb[3 * i + 1] = -b / ds
            conb[3 * i + 2] = a / ds
            depb[i] = z
            lg = lgb[i]
            e = _exp(-abs(lg))              # sigmoid without overflow
            opb[i] = (one if lg >= zero else e) / (one + e)
            mid = half * (a + c)
            q = mid * mid - ds
            q = tenth if q < tenth else q   # clamp(min=0.1), NaN stays NaN
            r = np.ceil(rsig * _sqrt(mid + _sqrt(q)))
            on = (u + r > nhalf) & (u - r < right) & (v + r > nhalf) & (v - r < bottom)
            r = rmax if r > rmax else r
            radb[i] = r if ok & on else zero


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _backward_kernel(means, Rt, log_scales, opacities, consts, g_means2d, g_conics, g_depths,
                     g_opacities, want_pose, dldp, g_means, g_log_scales, g_logits, pose_partials):
    """From the output gradients (flat like the forward's outputs): dL/dp (flat 3N), dL/dmeans =
    R^T dL/dp (flat 3N), dL/dlog_scale, dL/dlogit; blocks and branch-free body like the forward.
    With want_pose, pose_partials[block] = (dL/dR row-major, dL/dt) summed over the block's
    Gaussians in index order (a second, scalar loop: a float reduction would keep the first one
    from vectorising); the caller sums the blocks in order, so the result is deterministic."""
    fx = consts[_K_FX]
    fy = consts[_K_FY]
    nlxn = -consts[_K_LXN]
    lxp = consts[_K_LXP]
    nlyn = -consts[_K_LYN]
    lyp = consts[_K_LYP]
    near = consts[_K_NEAR]
    eps = consts[_K_EPS]
    one = consts[_K_ONE]
    zero = consts[_K_ZERO]
    two = consts[_K_TWO]
    fx2 = fx * fx
    fy2 = fy * fy
    fxy = fx * fy
    r00, r01, r02, t0 = Rt[0, 0], Rt[0, 1], Rt[0, 2], Rt[0, 3]
    r10, r11, r12, t1 = Rt[1, 0], Rt[1, 1], Rt[1, 2], Rt[1, 3]
    r20, r21, r22, t2 = Rt[2, 0], Rt[2, 1], Rt[2, 2], Rt[2, 3]
    n = log_scales.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo = blk * BLOCK
        hi = min(lo + BLOCK, n)
        mb = means[3 * lo:3 * hi]
        lsb = log_scales[lo:hi]
        ob = opacities[lo:hi]
        gmb = g_means2d[2 * lo:2 * hi]
        gcb = g_conics[3 * lo:3 * hi]
        gdb = g_depths[lo:hi]
        gob = g_opacities[lo:hi]
        dpb = dldp[3 * lo:3 * hi]
        gmeb = g_means[3 * lo:3 * hi]
        glsb = g_log_scales[lo:hi]
        glgb = g_logits[lo:hi]
        for i in range(hi - lo):
            m0 = mb[3 * i]
            m1 = mb[3 * i + 1]
            m2 = mb[3 * i + 2]
            x = r00 * m0 + r01 * m1 + r02 * m2 + t0
            y = r10 * m0 + r11 * m1 + r12 * m2 + t1
            z = r20 * m0 + r21 * m1 + r22 * m2 + t2
            visible = z > near
            zs = z if visible else one
            rx = x / zs
            ry = y / zs
            # torch.clamp passes the gradient where lo <= value <= hi (not for NaN)
            pass_x = (rx >= nlxn) & (rx <= lxp)
            pass_y = (ry >= nlyn) & (ry <= lyp)
            X = nlxn if rx < nlxn else rx
            X = lxp if X > lxp else X
            Y = nlyn if ry < nlyn else ry
            Y = lyp if Y > lyp else Y
            k = _exp(two * lsb[i]) / (zs * zs)
            ax = one + X * X
            cy_ = one + Y * Y
            XY = X * Y
            a = k * fx2 * ax + eps
            b = k * fxy * XY
            c = k * fy2 * cy_ + eps
            det = a * c - b * b
            ok = visible & (det > zero)
            ds = det if ok else one
            gA = gcb[3 * i]
            gB = gcb[3 * i + 1]
            gC = gcb[3 * i + 2]
            # conic = (c, -b, a) / ds; d(n / ds)/dds = -(n / ds) / ds, as torch's div backward
            gds = -(gA * (c / ds) - gB * (b / ds) + gC * (a / ds)) / ds
            gdet = gds if ok else zero
            ga = gC / ds + gdet * c
            gb = -gB / ds - two * gdet * b
            gc = gA / ds + gdet * a
            gk = ga * fx2 * ax + gb * fxy * XY + gc * fy2 * cy_
            gX = two * k * fx2 * X * ga + k * fxy * Y * gb
            gX = gX if pass_x else zero
            gY = two * k * fy2 * Y * gc + k * fxy * X * gb
            gY = gY if pass_y else zero
            gu = gmb[2 * i]
            gv = gmb[2 * i + 1]
            gks = two * k * gk
            gzs = -(fx * x * gu + fy * y * gv) / (zs * zs) - (gX * rx + gY * ry + gks) / zs
            gx = (fx * gu + gX) / zs
            gy = (fy * gv + gY) / zs
            gz = gdb[i] + (gzs if visible else zero)
            dpb[3 * i] = gx
            dpb[3 * i + 1] = gy
            dpb[3 * i + 2] = gz
            gmeb[3 * i] = r00 * gx + r10 * gy + r20 * gz
            gmeb[3 * i + 1] = r01 * gx + r11 * gy + r21 * gz
            gmeb[3 * i + 2] = r02 * gx + r12 * gy + r22 * gz
            glsb[i] = gks
            o = ob[i]
            glgb[i] = gob[i] * (one - o) * o
        if want_pose:
            a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = b0 = b1 = b2 = zero
            for i in range(hi - lo):
                gx = dpb[3 * i]
                gy = dpb[3 * i + 1]
                gz = dpb[3 * i + 2]
                m0 = mb[3 * i]
                m1 = mb[3 * i + 1]
                m2 = mb[3 * i + 2]
                a00 += gx * m0
                a01 += gx * m1
                a02 += gx * m2
                a10 += gy * m0
                a11 += gy * m1
                a12 += gy * m2
                a20 += gz * m0
                a21 += gz * m1
                a22 += gz * m2
                b0 += gx
                b1 += gy
                b2 += gz
            pp = pose_partials[blk]
            pp[0] = a00
            pp[1] = a01
            pp[2] = a02
            pp[3] = a10
            pp[4] = a11
            pp[5] = a12
            pp[6] = a20
            pp[7] = a21
            pp[8] = a22
            pp[9] = b0
            pp[10] = b1
            pp[11] = b2


# ----------------------------------------------------------------------------- torch glue

def _consts(dtype, intr: Intrinsics, near: float, eps2d: float) -> np.ndarray:
    c = np.zeros(_K_SIZE, dtype=dtype)
    c[_K_FX], c[_K_FY], c[_K_CX], c[_K_CY] = intr.fx, intr.fy, intr.cx, intr.cy
    c[_K_LXN], c[_K_LXP], c[_K_LYN], c[_K_LYP] = clamp_limits(intr)
    c[_K_NEAR] = near
    c[_K_EPS] = eps2d
    c[_K_RSIG] = RADIUS_SIGMAS
    c[_K_HALF] = 0.5
    c[_K_TENTH] = 0.1
    c[_K_ONE] = 1.0
    c[_K_ZERO] = 0.0
    c[_K_TWO] = 2.0
    c[_K_RIGHT] = intr.width - 0.5
    c[_K_BOTTOM] = intr.height - 0.5
    # The largest radius (an int32, below 2^31, representable in the working dtype).
    c[_K_RMAX] = 2.0 ** 31 - 1 if dtype == np.float64 else float(np.nextafter(np.float32(2.0 ** 31), 0))
    return c


def _np(t: torch.Tensor, size: int | None = None) -> np.ndarray:
    """A C-contiguous numpy view (or copy) of t, flattened to `size` values when given."""
    a = np.ascontiguousarray(t.detach().numpy())
    return a if size is None else a.reshape(size)


class _ProjectIsotropicCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, log_scales, logits, w2c, consts):
        n = means.shape[0]
        dtype = consts.dtype
        means2d = np.empty(2 * n, dtype=dtype)
        conics = np.empty(3 * n, dtype=dtype)
        depths = np.empty(n, dtype=dtype)
        opacities = np.empty(n, dtype=dtype)
        radii = np.empty(n, dtype=np.int32)
        with numba_lock():
            _forward_kernel(_np(means, 3 * n), _np(w2c[:3, :4]), _np(log_scales, n), _np(logits, n),
                            consts, means2d, conics, depths, opacities, radii)
        out = (torch.from_numpy(means2d).view(n, 2), torch.from_numpy(conics).view(n, 3),
               torch.from_numpy(depths), torch.from_numpy(opacities), torch.from_numpy(radii))
        ctx.mark_non_differentiable(out[4])
        ctx.set_materialize_grads(False)       # None for unused outputs (radii): no zeros made
        ctx.consts = consts
        ctx.save_for_backward(means, log_scales, w2c, out[3])
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g_means2d, g_conics, g_depths, g_opacities, g_radii):
        need_m, need_ls, need_lg, need_w2c = ctx.needs_input_grad[:4]
        if not (need_m or need_ls or need_lg or need_w2c):
            return None, None, None, None, None
        means, log_scales, w2c, opacities = ctx.saved_tensors
        consts = ctx.consts
        n = means.shape[0]
        dtype = consts.dtype

        def grad(g, size):      # None: the output was not used
            return np.zeros(size, dtype=dtype) if g is None else _np(g, size)

        dldp = np.empty(3 * n, dtype=dtype)
        g_means = np.empty(3 * n, dtype=dtype)
        g_ls = np.empty(n, dtype=dtype)
        g_lg = np.empty(n, dtype=dtype)
        partials = np.zeros(((n + BLOCK - 1) // BLOCK if need_w2c else 0, 12), dtype=dtype)
        with numba_lock():
            _backward_kernel(_np(means, 3 * n), _np(w2c[:3, :4]), _np(log_scales, n), _np(opacities),
                             consts, grad(g_means2d, 2 * n), grad(g_conics, 3 * n), grad(g_depths, n),
                             grad(g_opacities, n), bool(need_w2c), dldp, g_means, g_ls, g_lg, partials)
        grad_means = torch.from_numpy(g_means).view(n, 3) if need_m else None
        grad_ls = torch.from_numpy(g_ls).view(log_scales.shape) if need_ls else None
        grad_lg = torch.from_numpy(g_lg) if need_lg else None
        grad_w2c = None
        if need_w2c:
            pose = partials.sum(axis=0)
            grad_w2c = torch.zeros(4, 4, dtype=w2c.dtype)
            grad_w2c[:3, :3] = torch.from_numpy(pose[:9]).view(3, 3)
            grad_w2c[:3, 3] = torch.from_numpy(pose[9:])
        return grad_means, grad_ls, grad_lg, grad_w2c, None


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _frustum_kernel(means, log_scales, R, t, fx, fy, cx, cy, width, height, near, mx, my, out):
    """`project.frustum_mask` per Gaussian (same formulas, in float64)."""
    for i in prange(means.shape[0]):
        x = R[0, 0] * means[i, 0] + R[0, 1] * means[i, 1] + R[0, 2] * means[i, 2] + t[0]
        y = R[1, 0] * means[i, 0] + R[1, 1] * means[i, 1] + R[1, 2] * means[i, 2] + t[1]
        z = R[2, 0] * means[i, 0] + R[2, 1] * means[i, 1] + R[2, 2] * means[i, 2] + t[2]
        zs = max(z, near)
        s = log_scales[i, 0]
        for k in range(1, log_scales.shape[1]):
            s = max(s, log_scales[i, k])
        extent = 3.5 * np.exp(s)
        X = x / zs
        Y = y / zs
        u = fx * X + cx
        v = fy * Y + cy
        r = extent * max(fx, fy) / zs * np.sqrt(1 + X * X + Y * Y) + 2.0
        out[i] = ((z + extent > near) and u + r > -mx and u - r < width + mx
                  and v + r > -my and v - r < height + my)


def frustum_mask_cpu(means: torch.Tensor, log_scales: torch.Tensor, intr: Intrinsics, w2c: np.ndarray,
                     near: float, margin: float) -> torch.Tensor:
    """`project.frustum_mask` for CPU tensors: one pass (the torch version is ~20 passes over the map)."""
    w2c = np.asarray(w2c, dtype=np.float64)
    out = np.empty(means.shape[0], dtype=np.bool_)
    with numba_lock():
        _frustum_kernel(means.detach().numpy(), log_scales.detach().numpy(), w2c[:3, :3].copy(), w2c[:3, 3].copy(),
                        float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), float(intr.width),
                        float(intr.height), float(near), margin * intr.width, margin * intr.height, out)
    return torch.from_numpy(out)


def supported(g, w2c: torch.Tensor) -> bool:
    """Whether `project_isotropic_cpu` handles these inputs: isotropic Gaussians, CPU tensors of one
    dtype, float32 or float64, w2c 4 x 4."""
    ts = (g.means, g.log_scales, g.logit_opacities, w2c)
    dtype = g.means.dtype
    return (g.isotropic and g.log_scales.dim() == 2 and dtype in (torch.float32, torch.float64)
            and all(t.device.type == "cpu" and t.dtype == dtype for t in ts)
            and tuple(w2c.shape) == (4, 4))


def project_isotropic_cpu(g, intr: Intrinsics, w2c: torch.Tensor, *, near: float = 0.01,
                          eps2d: float = 0.3):
    """`project_gaussians` for inputs where `supported(g, w2c)`: a `Projected`, differentiable
    w.r.t. means, log_scales, logit_opacities and w2c."""
    np_dtype = np.float64 if g.means.dtype == torch.float64 else np.float32
    consts = _consts(np_dtype, intr, near, eps2d)
    means2d, conics, depths, opacities, radii = _ProjectIsotropicCPU.apply(
        g.means, g.log_scales, g.logit_opacities, w2c, consts)
    return Projected(means2d=means2d, conics=conics, depths=depths, opacities=opacities, radii=radii)
