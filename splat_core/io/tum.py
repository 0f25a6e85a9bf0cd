"""TUM RGB-D layout: rgb.txt, depth.txt ("timestamp path"), optional associations.txt
("t_rgb rgb_path t_depth depth_path"), optional groundtruth.txt ("t tx ty tz qx qy qz qw", c2w,
OpenCV camera axes). Intrinsics and depth scale from camera.yaml / camera.json beside the data,
else the published TUM fr1/fr2/fr3 cameras when the folder name says which, else an error.

Pairing: associations.txt when present; otherwise each RGB stamp takes the nearest depth stamp
within `max_dt` (0.08 s, as SplaTAM), one-to-one (a depth image is never used twice). Reference
poses are interpolated (slerp) between the ground-truth samples around the RGB stamp when both
lie within `pose_max_dt` (0.02 s, the TUM tools' default), else the nearest sample within it,
else none (a frame whose pose is missing in a 30 Hz trajectory is not filled from its neighbours).
Depth value 65535 is "no reading" (7-Scenes) and becomes invalid like 0. A camera file that
describes two cameras (color_intrinsics, depth_to_color: docs/formats.md) gives the depth camera in
fx fy cx cy width height; colour is then registered to depth when read (common.py, registration.py).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..camera import pose_matrix, quat_to_rotmat_np, rotmat_to_quat
from ..errors import InputError
from .camera_files import find_camera_file, load_camera_file, make_intrinsics
from .common import IndexedCapture, sort_by_time
from .images import read_color, read_depth_png
from .trajectory import parse_tum_lines, read_tum_trajectory

DEFAULT_DEPTH_SCALE = 5000.0
# Published intrinsics of the TUM RGB-D cameras (640x480).
TUM_CAMERAS = {
    "fr1": (517.3, 516.5, 318.6, 255.3),
    "fr2": (520.9, 521.0, 325.1, 249.7),
    "fr3": (535.4, 539.2, 320.1, 247.6),
}
GT_FILES = ("groundtruth.txt", "pose.txt")


def guess_tum_camera(folder: Path) -> str | None:
    """'fr1'/'fr2'/'fr3' when the folder name says so (rgbd_dataset_freiburg1_xyz, fr2_desk, ...)."""
    for part in reversed(Path(folder).resolve().parts):
        m = re.search(r"(?:freiburg|fr)_?([123])(?![0-9])", part.lower())
        if m:
            return "fr" + m.group(1)
    return None


def _read_list(path: Path) -> tuple[np.ndarray, list[str]]:
    stamps, names = [], []
    for n, fields in parse_tum_lines(path, 2):
        try:
            stamps.append(float(fields[0]))
        except ValueError:
            raise InputError(f"{path}:{n}: expected 'timestamp path', got {' '.join(fields)[:60]!r}") from None
        names.append(fields[1])
    return np.asarray(stamps), names


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        th = np.arccos(d)
        q = (np.sin((1 - a) * th) * q0 + np.sin(a * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def interpolate_pose(stamps: np.ndarray, c2w: np.ndarray, t: float, max_dt: float) -> np.ndarray | None:
    """c2w at time t from sorted samples: slerp between the neighbours when both are within
    max_dt, else the nearest sample within max_dt, else None."""
    if len(stamps) == 0:
        return None
    k = int(np.searchsorted(stamps, t))
    lo, hi = k - 1, k
    if hi < len(stamps) and abs(stamps[hi] - t) < 1e-9:
        return c2w[hi].copy()
    if lo >= 0 and hi < len(stamps) and t - stamps[lo] <= max_dt and stamps[hi] - t <= max_dt:
        a = (t - stamps[lo]) / (stamps[hi] - stamps[lo])
        q = _slerp(rotmat_to_quat(c2w[lo][:3, :3]), rotmat_to_quat(c2w[hi][:3, :3]), a)
        trans = (1 - a) * c2w[lo][:3, 3] + a * c2w[hi][:3, 3]
        return pose_matrix(quat_to_rotmat_np(q), trans)
    best = [j for j in (lo, hi) if 0 <= j < len(stamps) and abs(stamps[j] - t) <= max_dt]
    if not best:
        return None
    j = min(best, key=lambda j: abs(stamps[j] - t))
    return c2w[j].copy()


def associate(rgb_t: np.ndarray, depth_t: np.ndarray, max_dt: float) -> list[tuple[int, int]]:
    """One-to-one nearest-stamp pairs (rgb index, depth index) within max_dt, in RGB order."""
    if len(depth_t) == 0:
        return []
    order = np.argsort(depth_t)
    ds = depth_t[order]
    cand = []
    for i, t in enumerate(rgb_t):
        k = int(np.searchsorted(ds, t))
        js = [j for j in (k - 1, k) if 0 <= j < len(ds)]
        j = min(js, key=lambda j: abs(ds[j] - t))
        dt = abs(ds[j] - t)
        if dt <= max_dt:
            cand.append((dt, i, int(order[j])))
    used, pairs = set(), []
    for dt, i, j in sorted(cand):
        if j not in used:
            used.add(j)
            pairs.append((i, j))
    return sorted(pairs)


class TUMCapture(IndexedCapture):
    format_name = "tum"

    def __init__(self, path, *, max_dt: float = 0.08, pose_max_dt: float = 0.02, depth_scale: float | None = None, **options):
        super().__init__(path, **options)
        root = self.path
        if not root.is_dir():
            raise InputError(f"{root}: not a folder (TUM layout needs rgb.txt and depth.txt)")
        assoc = root / "associations.txt"
        if assoc.is_file():
            rgb_t, rgb_n, dep_t, dep_n = [], [], [], []
            for n, f in parse_tum_lines(assoc, 4):
                try:
                    rgb_t.append(float(f[0]))
                    dep_t.append(float(f[2]))
                except ValueError:
                    raise InputError(f"{assoc}:{n}: expected 't_rgb rgb_path t_depth depth_path'") from None
                rgb_n.append(f[1])
                dep_n.append(f[3])
            rgb_t, dep_t = np.asarray(rgb_t), np.asarray(dep_t)
            pairs = [(k, k) for k in range(len(rgb_t))]
            source_name = "associations.txt"
        else:
            for name in ("rgb.txt", "depth.txt"):
                if not (root / name).is_file():
                    raise InputError(f"{root}: TUM layout needs rgb.txt and depth.txt (or associations.txt); "
                                     f"{name} is missing")
            rgb_t, rgb_n = _read_list(root / "rgb.txt")
            dep_t, dep_n = _read_list(root / "depth.txt")
            pairs = associate(rgb_t, dep_t, max_dt)
            if len(pairs) < len(rgb_t):
                self.warn(f"{len(rgb_t) - len(pairs)} of {len(rgb_t)} colour frames have no depth within "
                          f"{max_dt} s (skipped)")
            source_name = "rgb.txt"
        # files that are listed but absent: skip, counted
        kept = []
        missing = 0
        for i, j in pairs:
            if (root / rgb_n[i]).is_file() and (root / dep_n[j]).is_file():
                kept.append((i, j))
            else:
                missing += 1
                if missing == 1:
                    first_missing = rgb_n[i] if not (root / rgb_n[i]).is_file() else dep_n[j]
        if missing:
            self.warn(f"{missing} frames skipped: listed image file missing (first: {root / first_missing})")
        stamps = np.array([rgb_t[i] for i, _ in kept])
        order = sort_by_time(stamps, str(root / source_name), self.warnings)
        kept = [kept[k] for k in order]
        stamps = stamps[order]
        self._rgb = [rgb_n[i] for i, _ in kept]
        self._depth = [dep_n[j] for _, j in kept]

        # camera
        cam_file = find_camera_file(root)
        cam = load_camera_file(cam_file) if cam_file else None
        if cam is None:
            which = guess_tum_camera(root)
            if which is None:
                raise InputError(f"{root}: no camera.yaml or camera.json with fx fy cx cy width height "
                                 f"depth_scale, and the folder name does not say fr1/fr2/fr3")
            fx, fy, cx, cy = TUM_CAMERAS[which]
            cam = dict(fx=fx, fy=fy, cx=cx, cy=cy, width=640, height=480)
            self.warn(f"no camera file: using the published TUM {which} intrinsics (guessed from the folder name)")
            cam_file = root
            self.registered_by = "the TUM RGB-D benchmark: depth registered to colour by the Kinect's driver"
        self.depth_scale = float(depth_scale or cam.get("depth_scale") or DEFAULT_DEPTH_SCALE)
        self.registered = bool(cam.get("registered", True))
        if cam.get("registered") is True:
            self.registered_by = f"{cam_file.name} says depth_registered_to_rgb: true"
        if "width" not in cam or "height" not in cam:
            if not self._rgb:
                raise InputError(f"{cam_file}: needs width and height")
            img = read_color(root / self._rgb[0])
            cam["width"], cam["height"] = img.shape[1], img.shape[0]
        self._color_intr = make_intrinsics(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["width"],
                                           cam["height"], str(cam_file))
        self.use_two_cameras(cam.get("two_cameras"))   # then the depth camera's, colour registered when read

        # reference poses
        gt = next((root / g for g in GT_FILES if (root / g).is_file()), None)
        c2w = [None] * len(stamps)
        if gt is not None:
            gt_t, gt_T = read_tum_trajectory(gt)
            order = sort_by_time(gt_t, str(gt), self.warnings)
            gt_t, gt_T = gt_t[order], gt_T[order]
            c2w = [interpolate_pose(gt_t, gt_T, t, pose_max_dt) for t in stamps]
        self._finish(stamps, c2w, f"no colour/depth pairs in {root / source_name}")

    def _name(self, i, kind):
        return str(self.path / (self._depth[i] if kind != "color" else self._rgb[i]))

    def _read_color(self, i):
        return read_color(self.path / self._rgb[i])

    def _read_depth(self, i):
        return read_depth_png(self.path / self._depth[i], self.depth_scale)
