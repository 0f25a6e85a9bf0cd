"""Replica as rendered by NICE-SLAM / iMAP: results/frameNNNNNN.jpg, results/depthNNNNNN.png
(uint16, metres * 6553.5), traj.txt (one row-major 4x4 c2w per line, OpenCV camera axes).
Camera 1200x680, fx=fy=600, cx=599.5, cy=339.5 unless a camera file (camera.yaml, camera.json,
or NICE-SLAM's cam_params.json) beside results/ or one folder up says otherwise.
Timestamps: the frame index (Replica publishes none).
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from .camera_files import check_pose, find_camera_file, load_camera_file, make_intrinsics
from .common import IndexedCapture
from .images import read_color, read_depth_png

DEFAULT_CAMERA = dict(fx=600.0, fy=600.0, cx=599.5, cy=339.5, width=1200, height=680, depth_scale=6553.5)


def _numbered(folder, prefix: str, exts: tuple[str, ...]) -> dict[int, str]:
    out = {}
    pat = re.compile(rf"^{prefix}(\d+)\.({'|'.join(exts)})$", re.IGNORECASE)
    for p in folder.iterdir():
        m = pat.match(p.name)
        if m:
            out[int(m.group(1))] = p.name
    return out


def read_traj_rows(path) -> list[np.ndarray]:
    poses = []
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            vals = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise InputError(f"{path}:{n}: expected 16 numbers (row-major 4x4 c2w)") from None
        if len(vals) != 16:
            raise InputError(f"{path}:{n}: expected 16 numbers (row-major 4x4 c2w), got {len(vals)}")
        poses.append(np.asarray(vals).reshape(4, 4))
    return poses


class ReplicaCapture(IndexedCapture):
    format_name = "replica"
    registered_by = "Replica: colour and depth rendered from one camera"

    def __init__(self, path, *, depth_scale: float | None = None, **options):
        super().__init__(path, **options)
        root = self.path
        results = root / "results"
        traj = root / "traj.txt"
        if not results.is_dir() or not traj.is_file():
            raise InputError(f"{root}: Replica layout needs results/frame*.jpg, results/depth*.png and traj.txt")
        colors = _numbered(results, "frame", ("jpg", "jpeg", "png"))
        depths = _numbered(results, "depth", ("png",))
        if not colors:
            raise InputError(f"{results}: no frameNNNNNN.jpg images")
        rows = read_traj_rows(traj)
        ids = sorted(colors)
        if ids != list(range(len(ids))):
            raise InputError(f"{results}: frame numbers are not 0..{len(ids) - 1} without gaps; "
                             f"cannot match them to the rows of {traj}")
        if len(rows) != len(ids):
            raise InputError(f"{traj}: {len(rows)} poses for {len(ids)} frames in {results} (counts must match)")
        keep = [i for i in ids if i in depths]
        if len(keep) < len(ids):
            self.warn(f"{len(ids) - len(keep)} of {len(ids)} frames have no depth image (skipped)")
        self._rgb = [results / colors[i] for i in keep]
        self._depth = [results / depths[i] for i in keep]

        cam_file = find_camera_file(root) or find_camera_file(root.parent)
        cam = dict(DEFAULT_CAMERA)
        if cam_file:
            cam.update(load_camera_file(cam_file))
        self.depth_scale = float(depth_scale or cam["depth_scale"])
        self._color_intr = make_intrinsics(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["width"],
                                           cam["height"], str(cam_file or traj))
        c2w = [check_pose(rows[i], f"{traj}:{i + 1}") for i in keep]
        self._finish(np.asarray(keep, dtype=np.float64), c2w, f"no frames with depth in {results}")

    def _name(self, i, kind):
        return str(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return read_color(self._rgb[i])

    def _read_depth(self, i):
        return read_depth_png(self._depth[i], self.depth_scale, invalid_values=())
