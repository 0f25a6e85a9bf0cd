"""Smooth camera paths through a few poses (c2w), for fly-through videos.

    path = CameraPath(c2ws)            # N >= 1 poses, camera-to-world, OpenCV axes
    c2w = path.at(s)                   # s in [0, 1]: the whole path; path.at(path.knots) == c2ws
    frames = path.sample(n)            # n poses at equal steps of s

Positions follow a non-uniform Catmull-Rom spline (cubic Hermite with finite-difference
tangents), rotations a squad curve through the poses' quaternions (the rotational analogue:
slerps of slerps with control quaternions from the neighbours). Knot spacing is proportional to
how far the camera moves between two poses (metres + `metres_per_radian` x turn angle), so the
camera travels at a roughly constant speed; linear and angular velocity are continuous at the
knots (both tangents are scaled by the knot spacing).
"""

from __future__ import annotations

import numpy as np

from .camera import pose_matrix, quat_to_rotmat_np, rotmat_to_quat


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _quat_log(q: np.ndarray) -> np.ndarray:
    """Unit quaternion -> its log, a pure quaternion (0, theta/2 * axis)."""
    v = q[1:]
    s = np.linalg.norm(v)
    if s < 1e-12:
        return np.zeros(4)
    return np.r_[0.0, v / s * np.arctan2(s, q[0])]


def _quat_exp(q: np.ndarray) -> np.ndarray:
    v = q[1:]
    a = np.linalg.norm(v)
    if a < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[np.cos(a), np.sin(a) * v / a]


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical interpolation along the great arc from q0 to q1 (no shortest-arc flip: squad's
    control quaternions must be used as given)."""
    d = float(np.clip(np.dot(q0, q1), -1.0, 1.0))
    if d > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(d)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / np.sin(theta)


def _same_hemisphere(quats: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions are within 90 degrees (q and -q are one rotation)."""
    out = quats.copy()
    for i in range(1, len(out)):
        if np.dot(out[i - 1], out[i]) < 0:
            out[i] = -out[i]
    return out


def turn_angle(q0: np.ndarray, q1: np.ndarray) -> float:
    """The rotation angle (radians) between two unit quaternions."""
    return 2.0 * float(np.arccos(np.clip(abs(np.dot(q0, q1)), 0.0, 1.0)))


class CameraPath:
    def __init__(self, c2ws, metres_per_radian: float = 0.5):
        c2ws = np.asarray(c2ws, dtype=np.float64).reshape(-1, 4, 4)
        if len(c2ws) == 0:
            raise ValueError("a camera path needs at least one pose")
        self.c2ws = c2ws
        self.positions = c2ws[:, :3, 3].copy()
        self.quats = _same_hemisphere(np.stack([rotmat_to_quat(T[:3, :3]) for T in c2ws]))
        steps = np.array([np.linalg.norm(self.positions[i + 1] - self.positions[i]) +
                          metres_per_radian * turn_angle(self.quats[i], self.quats[i + 1])
                          for i in range(len(c2ws) - 1)])
        steps = np.maximum(steps, 1e-6)   # a repeated pose still gets its own (short) segment
        self.knots = np.r_[0.0, np.cumsum(steps)] / max(steps.sum(), 1e-12) if len(steps) else np.zeros(1)
        self._tangents = self._position_tangents()
        self._controls = self._squad_controls()

    def __len__(self) -> int:
        return len(self.c2ws)

    def _position_tangents(self) -> np.ndarray:
        """dp/ds at each knot: the non-uniform Catmull-Rom finite difference; one-sided at the ends."""
        p, t = self.positions, self.knots
        m = np.zeros_like(p)
        n = len(p)
        if n < 2:
            return m
        m[0] = (p[1] - p[0]) / (t[1] - t[0])
        m[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
        for i in range(1, n - 1):
            d0, d1 = t[i] - t[i - 1], t[i + 1] - t[i]
            v0, v1 = (p[i] - p[i - 1]) / d0, (p[i + 1] - p[i]) / d1
            m[i] = (v0 * d1 + v1 * d0) / (d0 + d1)
        return m

    def _squad_controls(self) -> tuple[np.ndarray, np.ndarray]:
        """Squad's control quaternions, one pair per knot: a_i leaves q_i, b_i arrives at it.

        With L = log(q_i^-1 q_{i+1}), a segment's derivative at u = 0 is L + 2 log(q_i^-1 a_i),
        and likewise at its end; choosing a_i and b_i so both equal the knot's angular velocity
        w_i (a non-uniform finite difference of the logs, as for positions) times the segment's
        length makes the angular velocity continuous. With equal knot spacing this is Shoemake's
        squad (a_i = b_i = q_i exp(-(log(q_i^-1 q_{i+1}) + log(q_i^-1 q_{i-1})) / 4))."""
        q, t = self.quats, self.knots
        n = len(q)
        a, b = q.copy(), q.copy()
        if n < 2:
            return a, b
        nxt = [_quat_log(_quat_mul(_quat_conj(q[i]), q[i + 1])) for i in range(n - 1)]   # at q_i
        prv = [_quat_log(_quat_mul(_quat_conj(q[i + 1]), q[i])) for i in range(n - 1)]   # at q_{i+1}
        for i in range(n):
            if i == 0:
                w = nxt[0] / (t[1] - t[0])
            elif i == n - 1:
                w = -prv[-1] / (t[-1] - t[-2])
            else:
                d0, d1 = t[i] - t[i - 1], t[i + 1] - t[i]
                w = (-prv[i - 1] / d0 * d1 + nxt[i] / d1 * d0) / (d0 + d1)
            if i < n - 1:
                a[i] = _quat_mul(q[i], _quat_exp(((t[i + 1] - t[i]) * w - nxt[i]) / 2.0))
            if i > 0:
                b[i] = _quat_mul(q[i], _quat_exp(-((t[i] - t[i - 1]) * w + prv[i - 1]) / 2.0))
        return a, b

    def at(self, s: float) -> np.ndarray:
        """The c2w pose at path parameter s in [0, 1] (clamped)."""
        if len(self.c2ws) == 1:
            return self.c2ws[0].copy()
        s = float(np.clip(s, 0.0, 1.0))
        i = int(np.clip(np.searchsorted(self.knots, s, side="right") - 1, 0, len(self.knots) - 2))
        h = self.knots[i + 1] - self.knots[i]
        u = (s - self.knots[i]) / h
        h00, h10 = 2 * u ** 3 - 3 * u ** 2 + 1, u ** 3 - 2 * u ** 2 + u
        h01, h11 = -2 * u ** 3 + 3 * u ** 2, u ** 3 - u ** 2
        p = (h00 * self.positions[i] + h10 * h * self._tangents[i] +
             h01 * self.positions[i + 1] + h11 * h * self._tangents[i + 1])
        q, (a, b) = self.quats, self._controls
        rot = slerp(slerp(q[i], q[i + 1], u), slerp(a[i], b[i + 1], u), 2 * u * (1 - u))
        return pose_matrix(quat_to_rotmat_np(rot / np.linalg.norm(rot)), p)

    def sample(self, n: int) -> np.ndarray:
        """n poses (n x 4 x 4) at equal steps of the path parameter, both ends included."""
        if n < 1:
            raise ValueError("need at least one frame")
        return np.stack([self.at(s) for s in np.linspace(0.0, 1.0, n)])
