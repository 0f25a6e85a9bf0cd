"""A synthetic two-camera RGB-D capture in the TUM layout: depth from the depth camera, colour from
a second camera with another focal length a few centimetres away (as a raw Kinect records), and a
camera.yaml that describes both (docs/formats.md, "Two cameras"). With ratio 1 and no offset it is
the same scene and poses seen by one camera: its registered twin. Tests and
benchmarks/two_camera_map.py use it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import Intrinsics, invert_pose
from ..io.images import write_color_png, write_depth_png
from ..io.trajectory import format_tum_line
from .source import SyntheticSource

COLOR_FOCAL_RATIO = 0.9                          # colour focal / depth focal (7-Scenes: 525 / 585)
DEPTH_TO_COLOR = np.array([-0.025, 0.0, 0.0])    # p_color = p_depth + t (metres)


@dataclass
class TwoCameraCapture:
    path: Path
    source: SyntheticSource     # the depth camera's sequence (its frames: exact single-camera colour and depth)
    depth_intr: Intrinsics
    color_intr: Intrinsics
    translation: np.ndarray
    frames: list[int]

    def color_c2w(self, i: int) -> np.ndarray:
        T = np.eye(4)
        T[:3, 3] = self.translation
        return self.source.c2w[i] @ invert_pose(T)


def write_two_camera_tum(root: Path, n=6, width=320, height=240, stride=8, describe=True,
                         ratio=COLOR_FOCAL_RATIO, translation=DEPTH_TO_COLOR) -> TwoCameraCapture:
    """Frames 0, stride, 2 stride, ... of the synthetic orbit. `describe`: the camera file says
    how the colour camera sits (else it only says colour and depth are not registered, as 7-Scenes' does).
    `ratio`: colour focal / depth focal, one for both axes or (x, y)."""
    root = Path(root)
    src = SyntheticSource(n_frames=n * stride, width=width, height=height)
    k = src.intrinsics
    rx, ry = np.broadcast_to(np.asarray(ratio, dtype=np.float64), (2,))
    kc = Intrinsics(k.fx * rx, k.fy * ry, k.cx, k.cy, width, height)
    cap = TwoCameraCapture(root, src, k, kc, np.asarray(translation, dtype=np.float64),
                           list(range(0, n * stride, stride)))
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(exist_ok=True)
    rgb, dep, assoc, gt = [], [], [], []
    for i in cap.frames:
        t = i / 30.0
        color, _ = src.scene.render(cap.color_c2w(i), kc)
        _, depth = src.scene.render(src.c2w[i], k)
        write_color_png(root / f"rgb/{t:.6f}.png", color)
        write_depth_png(root / f"depth/{t:.6f}.png", depth, 5000.0)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        dep.append(f"{t:.6f} depth/{t:.6f}.png")
        assoc.append(f"{t:.6f} rgb/{t:.6f}.png {t:.6f} depth/{t:.6f}.png")
        gt.append(format_tum_line(t, src.c2w[i]))
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(dep) + "\n")
    (root / "associations.txt").write_text("\n".join(assoc) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    text = (f"fx: {float(k.fx)!r}\nfy: {float(k.fy)!r}\ncx: {float(k.cx)!r}\ncy: {float(k.cy)!r}\nwidth: {width}\nheight: {height}\n"
            f"depth_scale: 5000.0\n")
    if describe:
        tx, ty, tz = (float(v) for v in cap.translation)
        text += (f"color_intrinsics: {{fx: {float(kc.fx)!r}, fy: {float(kc.fy)!r}, cx: {float(kc.cx)!r}, cy: {float(kc.cy)!r}, "
                 f"width: {width}, height: {height}}}\n"
                 f"depth_to_color: {{translation: [{tx!r}, {ty!r}, {tz!r}], rotation_xyzw: [0, 0, 0, 1]}}\n")
    else:
        text += "depth_registered_to_rgb: false\n"
    (root / "camera.yaml").write_text(text)
    return cap
