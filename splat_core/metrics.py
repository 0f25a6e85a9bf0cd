"""Evaluation: trajectory error (ATE), rendering quality (PSNR, SSIM), depth L1.

Every function accepts numpy arrays or torch tensors and returns Python floats (or numpy
arrays for per-frame values). Conventions (docs/differences.md has why the standard ATE):

- `ate_rmse` is the standard number (TUM `evaluate_ate`, evo `ape --align`): camera centres,
  rigid alignment without scale, root-mean-square of the residuals.
- `ate_mean_legacy` reproduces the official SplaTAM code's "ATE RMSE": translation columns of
  the w2c matrices, ground truth aligned onto the estimate, MEAN of the errors (its evaluation
  code; `ate_mean_legacy_cm` in metrics.json).
- `psnr` is 20 log10(1 / sqrt(MSE)) on images in [0, 1], the prediction not clamped.
"""

from __future__ import annotations

import numpy as np
import torch


def _np(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().double().numpy()
    return np.asarray(x, dtype=np.float64)


def _torch(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.detach()
    return torch.as_tensor(np.asarray(x))


# ----------------------------------------------------------------------------- trajectories

def align_rigid(src_points, dst_points) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (3x3) and translation t (3,) minimising sum |R src_i + t - dst_i|^2.

    Closed form (Horn / Kabsch via SVD of the cross-covariance), no scale; the sign of the last
    singular direction is flipped when needed so that R is a rotation (det +1), never a
    reflection. src_points, dst_points: N x 3 corresponding points.
    """
    src, dst = _np(src_points), _np(dst_points)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"align_rigid needs two N x 3 arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    H = (src - mu_s).T @ (dst - mu_d)           # 3 x 3 cross-covariance
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    t = mu_d - R @ mu_s
    return R, t


def align_similarity(src_points, dst_points) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R and translation t minimising sum |s R src_i + t - dst_i|^2 (Umeyama 1991:
    `align_rigid`'s rotation, and the scale that the centred point sets' variance and the
    singular values give). For comparing against a reference of another scale (SfM)."""
    src, dst = _np(src_points), _np(dst_points)
    R, _ = align_rigid(src, dst)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    var = float((a ** 2).sum())
    s = float(np.einsum("ij,ij->", b, a @ R.T)) / var if var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s


def _valid_pairs(est, ref) -> tuple[np.ndarray, np.ndarray]:
    est, ref = _np(est), _np(ref)
    if est.shape != ref.shape or est.ndim != 3 or est.shape[1:] != (4, 4):
        raise ValueError(f"expected two T x 4 x 4 pose arrays of equal length, got {est.shape} and {ref.shape}")
    keep = np.all(np.isfinite(ref.reshape(len(ref), -1)), axis=1)
    return est[keep], ref[keep]


def ate_errors(est_c2w, ref_c2w, scale: bool = False) -> np.ndarray:
    """Per-frame camera-centre errors (metres) after aligning the ESTIMATE onto the REFERENCE
    with `align_rigid` (frames whose reference pose is not finite are dropped); `scale`: with
    `align_similarity` (Sim(3)) instead, in the reference's units.

    For a rigid (no-scale) alignment the residual norms are the same whichever trajectory is
    moved, so this equals aligning the reference onto the estimate. NaN if an estimated pose
    used is not finite.
    """
    est, ref = _valid_pairs(est_c2w, ref_c2w)
    if len(ref) == 0:
        return np.zeros(0)
    p_est, p_ref = est[:, :3, 3], ref[:, :3, 3]
    if not np.all(np.isfinite(p_est)):
        return np.full(len(p_est), np.nan)
    if scale:
        k, R, t = align_similarity(p_est, p_ref)
        return np.linalg.norm(k * p_est @ R.T + t - p_ref, axis=1)
    R, t = align_rigid(p_est, p_ref)
    return np.linalg.norm(p_est @ R.T + t - p_ref, axis=1)


def ate_rmse(est_c2w, ref_c2w) -> float:
    """Absolute trajectory error, metres: RMSE of camera-centre errors after rigid (no-scale)
    alignment of the estimate onto the reference (same value as aligning the reference onto the
    estimate), like TUM evaluate_ate / evo `ape --align`. est_c2w, ref_c2w: T x 4 x 4
    camera-to-world; frames with non-finite reference poses are skipped. NaN when no frame is
    usable or an estimated pose is not finite."""
    err = ate_errors(est_c2w, ref_c2w)
    return float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan")


class RunningAte:
    """`ate_rmse` of a trajectory that grows at its end, for a display after every frame (the viewer's
    worker): the same number to rounding, at a cost that does not grow with the run's length in
    Python (numpy compares the positions with the last call's, bit for bit; only pairs that are new or
    changed are summed).

        ate = RunningAte()
        cm = 100 * ate(est_c2w, ref_c2w)     # (n, 4, 4) arrays, NaN rows where a frame has no reference

    The rigid alignment's residual needs only the pairs' sums: with a = p - mean(p), b = q - mean(q)
    and H = sum a b^T = U S V^T, align_rigid's rotation R = V D U^T leaves
        sum |R a_i - b_i|^2 = sum |a|^2 + sum |b|^2 - 2 (s1 + s2 + d s3),   d = det(V U^T),
    so the sums of p, q, |p|^2, |q|^2 and p q^T are kept (about the first pair's positions, so that
    a trajectory far from its world's origin loses no digits). A pose the engine moved (a loop
    correction, a lost frame's fill) is found by comparing the arrays with the last call's; its old
    pair leaves the sums and its new one enters; many at once (or a shorter array: a resume)
    rebuild them. Returns NaN as `ate_rmse` does (an estimated pose that is not finite), None with
    fewer than two pairs."""

    REBUILD = 32        # more changed pairs than this: sum them all again

    def __init__(self):
        self._p = np.zeros((0, 3))
        self._q = np.zeros((0, 3))
        self._rebuild(self._p, self._q)

    def _rebuild(self, p, q) -> None:
        self._n, self._bad = 0, 0
        self._add(p, q, 1.0)

    def _add(self, p, q, sign: float) -> None:
        """Pairs (p_i, q_i) into the sums (sign +1) or out of them (-1); rows without a reference are not pairs."""
        ok = np.isfinite(q).all(axis=1)
        p, q = p[ok], q[ok]
        bad = ~np.isfinite(p).all(axis=1)
        p, q, n_bad = p[~bad], q[~bad], int(bad.sum())
        if self._n == self._bad == 0:       # no pair in the sums: start them about this first pair
            self._origin = (p[0], q[0]) if len(p) else (np.zeros(3), np.zeros(3))
            self._sp, self._sq, self._spq = np.zeros(3), np.zeros(3), np.zeros((3, 3))
            self._spp = self._sqq = 0.0
        self._n += int(sign) * (len(p) + n_bad)
        self._bad += int(sign) * n_bad
        p, q = p - self._origin[0], q - self._origin[1]
        self._sp += sign * p.sum(axis=0)
        self._sq += sign * q.sum(axis=0)
        self._spp += sign * float(np.einsum("ij,ij->", p, p))
        self._sqq += sign * float(np.einsum("ij,ij->", q, q))
        self._spq += sign * (p.T @ q)

    def __call__(self, est_c2w, ref_c2w) -> float | None:
        n = min(len(est_c2w), len(ref_c2w))
        p = np.array(np.asarray(est_c2w, np.float64)[:n, :3, 3])
        q = np.array(np.asarray(ref_c2w, np.float64)[:n, :3, 3])
        m = len(self._p)
        if n < m:
            self._rebuild(p, q)
        else:
            # bit for bit (NaN rows equal themselves), element by element: cheaper than per-row tests
            moved = (self._p.view(np.int64) != p[:m].view(np.int64)) | (self._q.view(np.int64) != q[:m].view(np.int64))
            changed = np.unique(np.flatnonzero(moved) // 3)
            if len(changed) > self.REBUILD:
                self._rebuild(p, q)
            else:
                for p_rows, q_rows, sign in ((self._p[changed], self._q[changed], -1.0),
                                             (p[changed], q[changed], 1.0), (p[m:], q[m:], 1.0)):
                    if len(p_rows):
                        self._add(p_rows, q_rows, sign)
        self._p, self._q = p, q
        if self._n < 2:
            return None
        if self._bad:
            return float("nan")
        k = self._n
        a2 = self._spp - self._sp @ self._sp / k            # sum |p - mean p|^2
        b2 = self._sqq - self._sq @ self._sq / k
        H = self._spq - np.outer(self._sp, self._sq) / k
        U, S, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        residual = a2 + b2 - 2.0 * (S[0] + S[1] + d * S[2])
        return float(np.sqrt(max(residual, 0.0) / k))


def ate_rmse_segments(est_c2w, ref_c2w, breaks) -> float:
    """ATE RMSE (metres) with the trajectory cut after each frame index in `breaks` and every
    piece aligned onto the reference on its own (rigid, no scale), the RMSE taken over all
    frames. For a reference with a known wrong step (io.checks.inconsistent_steps): the offset
    that step puts between the pieces is not charged to the estimate. Equals `ate_rmse` with no
    breaks."""
    est, ref = _np(est_c2w), _np(ref_c2w)
    cuts = [0] + sorted({int(b) + 1 for b in breaks if 0 <= int(b) < len(ref) - 1}) + [len(ref)]
    err = np.concatenate([ate_errors(est[a:b], ref[a:b]) for a, b in zip(cuts, cuts[1:])])
    return float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan")


def ate_mean_legacy(est_w2c, ref_w2c) -> float:
    """The official SplaTAM code's "ATE RMSE" (its evaluation code), metres: the translation COLUMNS of the
    w2c matrices (not camera centres), the reference aligned onto the estimate (rigid, no scale),
    then the MEAN of the per-frame errors. Frames with non-finite reference poses are skipped.
    Since a w2c translation is -R^T c, this number is NOT invariant to translating the world
    frame of one trajectory; it is meaningful only when both start at the same pose (SplaTAM
    makes frame 0 the identity in both)."""
    est, ref = _valid_pairs(est_w2c, ref_w2c)
    if len(ref) == 0:
        return float("nan")
    t_est, t_ref = est[:, :3, 3], ref[:, :3, 3]
    if not np.all(np.isfinite(t_est)):
        return float("nan")
    R, t = align_rigid(t_ref, t_est)
    return float(np.mean(np.linalg.norm(t_ref @ R.T + t - t_est, axis=1)))


def relative_pose_errors(est_c2w, ref_c2w, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors over `delta` frames (TUM RPE): for each i, the error of the motion
    E_i = (ref_i^-1 ref_{i+delta})^-1 (est_i^-1 est_{i+delta}); returns (translation norms in
    metres, rotation angles in degrees). Pairs with a non-finite reference pose are skipped.
    No alignment is needed: relative motions do not depend on the world frame."""
    est, ref = _np(est_c2w), _np(ref_c2w)
    if est.shape != ref.shape:
        raise ValueError(f"pose arrays differ in shape: {est.shape} vs {ref.shape}")
    trans, rot = [], []
    for i in range(len(ref) - delta):
        a, b = ref[i], ref[i + delta]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            continue
        rel_ref = np.linalg.inv(a) @ b
        rel_est = np.linalg.inv(est[i]) @ est[i + delta]
        E = np.linalg.inv(rel_ref) @ rel_est
        trans.append(np.linalg.norm(E[:3, 3]))
        rot.append(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return np.asarray(trans), np.asarray(rot)


# ----------------------------------------------------------------------------- images

def is_evaluated(k: int, every: int) -> bool:
    """Processed frame k is one a run's render metrics use (frame 0 and every `every`-th:
    run/report.evaluate); the end-of-run colour fit leaves these out (color_fit.py)."""
    return k == 0 or (k + 1) % max(1, every) == 0


def psnr(pred, target, mask=None) -> float:
    """Peak signal-to-noise ratio (dB) for images in [0, 1]: 20 log10(1 / sqrt(MSE)).

    pred, target: same shape (H x W x C or H x W); pred is NOT clamped. mask: optional H x W
    boolean; the MSE is then the mean over the selected pixels (all channels). inf when equal.
    """
    p, t = _np(pred), _np(target)
    if p.shape != t.shape:
        raise ValueError(f"psnr: shapes differ {p.shape} vs {t.shape}")
    sq = (p - t) ** 2
    if mask is not None:
        m = _np(mask).astype(bool)
        sq = sq[m]
        if sq.size == 0:
            return float("nan")
    mse = float(np.mean(sq))
    if mse == 0.0:
        return float("inf")
    return float(20.0 * np.log10(1.0 / np.sqrt(mse)))


def ssim_metric(pred, target) -> float:
    """Mean SSIM (losses.ssim: 11x11 Gaussian window, sigma 1.5) of two H x W x C images.
    Not the MS-SSIM that the original paper's tables report."""
    from .losses import ssim

    p, t = _torch(pred), _torch(target)
    if not p.is_floating_point():
        p = p.float()
    t = t.to(dtype=p.dtype, device=p.device)
    with torch.no_grad():
        return float(ssim(p, t))


def depth_l1(pred, target) -> float:
    """Mean |pred - target| (metres) over pixels with valid target depth (finite and > 0).
    NaN when no pixel is valid."""
    p, t = _np(pred), _np(target)
    if p.shape != t.shape:
        raise ValueError(f"depth_l1: shapes differ {p.shape} vs {t.shape}")
    valid = np.isfinite(t) & (t > 0)
    if not valid.any():
        return float("nan")
    return float(np.mean(np.abs(p[valid] - t[valid])))
