"""Two cameras: a colour camera beside the depth camera, and registration of colour to depth.

Convention (docs/formats.md, "Two cameras"): the frames, the trajectory and every intrinsics a
reader reports are the DEPTH camera's. A camera file's fx fy cx cy width height describe the depth
camera; `color_intrinsics` the colour camera; `depth_to_color` the rigid map p_color = R p_depth + t
(metres, OpenCV axes). A reference trajectory of the colour camera is compared after
c2w_depth = c2w_color @ T_depth_to_color (`colour_to_depth_poses`).

Registration (`register_frame`) brings the colour to the depth grid: each valid depth pixel's
point goes into the colour camera and the colour is sampled there (bilinear). Occlusion: a z-buffer
on the colour grid keeps, per colour pixel, the nearest depth point that lands within a pixel of it
(2 x 2 footprint); a point farther than that by more than `Z_TOLERANCE` (2 % + 1 cm) is hidden. A
depth pixel without colour (hidden, or outside the colour image) becomes invalid: no map point gets
a colour it was not seen with. Depth-invalid pixels get the colour seen along their ray at the
frame's median depth (for display only: nothing uses their depth).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from .camera import Intrinsics, quat_to_rotmat_np, rotmat_to_quat
from .errors import InputError
from .parallel import prefer_512_bit_vectors  # noqa: F401  (before the kernels: their vector width)

Z_TOLERANCE = (0.02, 0.01)   # relative, absolute (metres): a point this much behind the z-buffer is hidden


@dataclass(frozen=True)
class TwoCameras:
    """The colour camera's intrinsics and the depth-to-colour transform (p_color = R p_depth + t)."""

    color: Intrinsics
    rotation: np.ndarray = None      # 3x3
    translation: np.ndarray = None   # (3,) metres

    def __post_init__(self):
        R = np.eye(3) if self.rotation is None else np.asarray(self.rotation, dtype=np.float64)
        t = np.zeros(3) if self.translation is None else np.asarray(self.translation, dtype=np.float64)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    @property
    def matrix(self) -> np.ndarray:
        """4x4 T_depth_to_color."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.translation
        return T

    def is_identity(self, depth: Intrinsics, focal_tol: float = 0.0, offset_tol: float = 0.0) -> bool:
        """True when the colour camera is the depth camera (so frames are already registered)."""
        c = self.color.scaled(depth.width, depth.height)
        same_k = (abs(c.fx / depth.fx - 1) <= focal_tol and abs(c.fy / depth.fy - 1) <= focal_tol
                  and abs(c.cx - depth.cx) <= focal_tol * depth.fx and abs(c.cy - depth.cy) <= focal_tol * depth.fy)
        return bool(same_k and np.abs(self.rotation - np.eye(3)).max() <= 1e-9
                    and np.linalg.norm(self.translation) <= offset_tol)

    def camera_file_lines(self) -> list[str]:
        """The camera.yaml lines that describe this colour camera."""
        c = self.color
        q = rotmat_to_quat(self.rotation)   # (w, x, y, z)
        t = ", ".join(f"{v:.5f}" for v in self.translation)
        return [f"color_intrinsics: {{fx: {c.fx:.2f}, fy: {c.fy:.2f}, cx: {c.cx:.2f}, cy: {c.cy:.2f}, "
                f"width: {c.width}, height: {c.height}}}",
                f"depth_to_color: {{translation: [{t}], rotation_xyzw: "
                f"[{q[1]:.6f}, {q[2]:.6f}, {q[3]:.6f}, {q[0]:.6f}]}}"]


def _numbers(value, n: int, key: str, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: '{key}' must be a list of {n} numbers, got {value!r}")
    return arr


def parse_two_cameras(data: dict, where: str) -> TwoCameras | None:
    """`color_intrinsics` and `depth_to_color` of a camera file (None when it has neither)."""
    ci, dc = data.get("color_intrinsics"), data.get("depth_to_color")
    if ci is None and dc is None:
        return None
    if not isinstance(ci, dict):
        raise InputError(f"{where}: 'color_intrinsics' must be a mapping with fx fy cx cy width height"
                         + (" (depth_to_color is given without it)" if ci is None else f", got {ci!r}"))
    missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in ci]
    if missing:
        raise InputError(f"{where}: 'color_intrinsics' is missing {', '.join(missing)}")
    try:
        color = Intrinsics(float(ci["fx"]), float(ci["fy"]), float(ci["cx"]), float(ci["cy"]),
                           int(round(float(ci["width"]))), int(round(float(ci["height"]))))
    except (TypeError, ValueError) as e:
        raise InputError(f"{where}: 'color_intrinsics' must hold numbers ({e})") from None
    except InputError as e:
        raise InputError(f"{where}: color_intrinsics: {e}") from None
    if dc is None:
        dc = {}
    if not isinstance(dc, dict):
        raise InputError(f"{where}: 'depth_to_color' must be a mapping with translation [x, y, z] "
                         f"and rotation_xyzw [x, y, z, w], got {dc!r}")
    t = _numbers(dc.get("translation", [0, 0, 0]), 3, "depth_to_color.translation", where)
    q = _numbers(dc.get("rotation_xyzw", [0, 0, 0, 1]), 4, "depth_to_color.rotation_xyzw", where)
    if abs(np.linalg.norm(q) - 1) > 1e-3:
        raise InputError(f"{where}: 'depth_to_color.rotation_xyzw' must be a unit quaternion, "
                         f"got norm {np.linalg.norm(q):.4f}")
    if np.linalg.norm(t) > 1.0:
        raise InputError(f"{where}: 'depth_to_color.translation' is {np.linalg.norm(t):.2f} m long "
                         f"(metres expected: millimetres written as metres?)")
    return TwoCameras(color, quat_to_rotmat_np([q[3], q[0], q[1], q[2]]), t)


def colour_to_depth_poses(c2w_color: np.ndarray, cams: TwoCameras) -> np.ndarray:
    """c2w of the depth camera from c2w of the colour camera (..., 4, 4)."""
    return np.asarray(c2w_color) @ cams.matrix


@lru_cache(maxsize=8)
def _rays(fx, fy, cx, cy, width, height) -> tuple[np.ndarray, np.ndarray]:
    u = ((np.arange(width, dtype=np.float32) - cx) / fx)[None, :]
    v = ((np.arange(height, dtype=np.float32) - cy) / fy)[:, None]
    return np.broadcast_to(u, (height, width)), np.broadcast_to(v, (height, width))


def project_depth(depth: np.ndarray, intr: Intrinsics, cams: TwoCameras, color_intr: Intrinsics):
    """Depth pixels -> (u, v, z) in the colour camera (HxW float32 each)."""
    rx, ry = _rays(intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height)
    R, t = cams.rotation.astype(np.float32), cams.translation.astype(np.float32)
    z = depth.astype(np.float32, copy=False)
    x, y = rx * z, ry * z
    xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
    yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
    zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(zc > 1e-6, 1.0 / zc, 0.0).astype(np.float32)
    return (np.float32(color_intr.fx) * xc * inv + np.float32(color_intr.cx),
            np.float32(color_intr.fy) * yc * inv + np.float32(color_intr.cy), zc)


@njit(cache=True, nogil=True, error_model="numpy")
def _project_visible(depth, k, R, t, kc, cw, ch, rel, absolute, z_fill):  # pragma: no cover - compiled
    """Per depth pixel: (u, v) in the colour image, and whether it is the nearest point there
    (z-buffer on the colour grid, each point written to the 2 x 2 pixels around it; a point is
    hidden when a nearer one, by more than rel * z + absolute, wrote the pixel it lands nearest).
    Depth-less pixels get (u, v) of their ray at z_fill and are not seen."""
    h, w = depth.shape
    uc = np.empty((h, w), dtype=np.float32)
    vc = np.empty((h, w), dtype=np.float32)
    zc = np.zeros((h, w), dtype=np.float32)
    zbuf = np.full((ch + 1, cw + 1), np.inf, dtype=np.float32)
    ifx, ify = np.float32(1) / k[0], np.float32(1) / k[1]
    for y in range(h):
        ry = (y - k[3]) * ify
        for x in range(w):
            rx = (x - k[2]) * ifx
            z = depth[y, x]
            filled = not z > 0
            if filled:
                z = z_fill
            X = (R[0, 0] * rx + R[0, 1] * ry + R[0, 2]) * z + t[0]
            Y = (R[1, 0] * rx + R[1, 1] * ry + R[1, 2]) * z + t[1]
            Z = (R[2, 0] * rx + R[2, 1] * ry + R[2, 2]) * z + t[2]
            if not Z > 1e-6:
                uc[y, x], vc[y, x] = -1, -1
                continue
            iz = np.float32(1) / Z
            u, v = kc[0] * X * iz + kc[2], kc[1] * Y * iz + kc[3]
            uc[y, x], vc[y, x] = u, v
            if filled or u < 0 or v < 0 or u > cw - 1 or v > ch - 1:
                continue
            zc[y, x] = Z
            u0, v0 = int(u), int(v)
            zbuf[v0, u0] = min(zbuf[v0, u0], Z)
            zbuf[v0, u0 + 1] = min(zbuf[v0, u0 + 1], Z)
            zbuf[v0 + 1, u0] = min(zbuf[v0 + 1, u0], Z)
            zbuf[v0 + 1, u0 + 1] = min(zbuf[v0 + 1, u0 + 1], Z)
    seen = np.zeros((h, w), dtype=np.bool_)
    for y in range(h):
        for x in range(w):
            Z = zc[y, x]
            if Z > 0:
                seen[y, x] = Z <= zbuf[int(vc[y, x] + 0.5), int(uc[y, x] + 0.5)] * (1 + rel) + absolute
    return uc, vc, seen


def register_frame(color: np.ndarray, depth: np.ndarray, intr: Intrinsics, cams: TwoCameras):
    """(colour on the depth grid, depth with unseen pixels invalid): see the module doc.

    color: the colour image as stored (HcxWcx3 float32; `cams.color` is scaled to its size);
    depth: HxW metres (0 invalid) on the grid of `intr`, the depth camera."""
    import cv2

    ch, cw = color.shape[:2]
    ck = cams.color if (cams.color.width, cams.color.height) == (cw, ch) else cams.color.scaled(cw, ch)
    valid = depth > 0
    # display colour for depth-less pixels: their ray at the median depth
    z_fill = np.float32(np.median(depth[valid])) if (valid.any() and not valid.all()) else np.float32(2.0)
    k = np.array([intr.fx, intr.fy, intr.cx, intr.cy], dtype=np.float32)
    kc = np.array([ck.fx, ck.fy, ck.cx, ck.cy], dtype=np.float32)
    uc, vc, seen = _project_visible(np.ascontiguousarray(depth, dtype=np.float32), k,
                                    cams.rotation.astype(np.float32), cams.translation.astype(np.float32),
                                    kc, cw, ch, np.float32(Z_TOLERANCE[0]), np.float32(Z_TOLERANCE[1]), z_fill)
    out = cv2.remap(np.ascontiguousarray(color, dtype=np.float32), uc, vc, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    new_depth = np.where(seen, depth, np.float32(0)).astype(np.float32)
    return np.clip(out, 0.0, 1.0), new_depth


def depth_in_color_camera(depth: np.ndarray, intr: Intrinsics, cams: TwoCameras, color_intr: Intrinsics) -> np.ndarray:
    """The depth camera's depth seen from the colour camera (hand-offs that describe the colour
    camera: docs/handoffs.md): each valid depth pixel's point goes to the nearest colour pixel,
    and the nearest point there is kept (a z-buffer); the value is the point's z in the colour
    camera. Colour pixels no point lands on are 0 (no reading): outside the depth camera's view,
    hidden from it, or a gap between landing points where the colour camera's pixels are smaller."""
    u, v, z = project_depth(depth, intr, cams, color_intr)
    ui, vi = np.rint(u), np.rint(v)
    ok = (depth > 0) & (z > 0) & (ui >= 0) & (vi >= 0) & (ui <= color_intr.width - 1) & (vi <= color_intr.height - 1)
    flat = np.full(color_intr.width * color_intr.height, np.inf, dtype=np.float32)
    np.minimum.at(flat, (vi[ok].astype(np.int64) * color_intr.width + ui[ok].astype(np.int64)), z[ok])
    flat[~np.isfinite(flat)] = 0
    return flat.reshape(color_intr.height, color_intr.width)
