"""Tiny procedural RGB-D sequences written in every capture format's own conventions.

The scene: a camera moving (and turning) in front of a textured back wall, a floor, a side wall
and a floating panel. Depth is analytic (ray/plane intersection at the pixel centres, camera.py's
convention), colour a smooth function of the hit point, poses exact (c2w, OpenCV axes).
Each writer stores the sequence as that format does: OpenGL poses, column-major K, portrait depth
arrays, millimetre or 65535/10 depth, LZFSE, mp4, -inf poses, is_bad frames, 65535 = no reading.
`Fixture.expected(i)` is what a reader must return for frame i at its default working resolution.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from splat_core.camera import (Intrinsics, c2w_opengl_to_opencv, pose_matrix, rotmat_to_quat)

# Regions of every depth map (rows, cols) used to plant invalid values.
HOLE = (slice(0, 4), slice(0, 6))  # depth 0 in every format
MARK = (slice(4, 8), slice(0, 6))  # the format's own "invalid" marker (65535, NaN, low confidence)
MEDIUM = (slice(8, 12), slice(0, 6))  # confidence 1 (kept by the default min_confidence=1)

PLANES = [  # (normal n, offset c): points x with n.x = c; optional bounds on the hit point
    (np.array([0.0, 0.0, 1.0]), 4.0, None),  # back wall z = 4
    (np.array([0.0, 1.0, 0.0]), 1.2, None),  # floor y = 1.2 (OpenCV: y down)
    (np.array([1.0, 0.0, 0.0]), -2.0, None),  # left wall x = -2
    (np.array([0.0, 0.0, 1.0]), 2.5, ((0.1, 1.0), (-0.8, 0.3))),  # panel z = 2.5, x and y bounds
]


def _rot(yaw, pitch, roll):
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def camera_path(n: int) -> list[np.ndarray]:
    out = []
    for i in range(n):
        s = i / max(n - 1, 1)
        t = [0.35 * np.sin(2.0 * s), -0.15 + 0.1 * np.cos(3.0 * s), 0.4 * s]
        R = _rot(np.radians(-8 + 16 * s), np.radians(4 * np.sin(3 * s)), np.radians(3 * s))
        out.append(pose_matrix(R, t))
    return out


def render(c2w: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(colour HxWx3 float32 in [0,1], depth HxW float32 metres) seen by camera c2w."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    d_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)
    d = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    best = np.full(u.shape, np.inf)
    hit = np.zeros(u.shape + (3,))
    plane_id = np.zeros(u.shape, dtype=int)
    for k, (n, c, bounds) in enumerate(PLANES):
        nd = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (c - o @ n) / nd
        p = o + s[..., None] * d
        ok = (s > 1e-6) & np.isfinite(s)
        if bounds is not None:
            ok &= (p[..., 0] > bounds[0][0]) & (p[..., 0] < bounds[0][1])
            ok &= (p[..., 1] > bounds[1][0]) & (p[..., 1] < bounds[1][1])
        closer = ok & (s < best)
        best[closer] = s[closer]
        hit[closer] = p[closer]
        plane_id[closer] = k
    x, y, z = hit[..., 0], hit[..., 1], hit[..., 2]
    color = np.stack([
        0.5 + 0.35 * np.sin(2.2 * x + 1.3 * y + 0.7 * plane_id),
        0.5 + 0.35 * np.sin(1.7 * y - 1.1 * z + 1.9 * plane_id),
        0.5 + 0.35 * np.cos(1.5 * x + 1.2 * z - 0.5 * plane_id),
    ], -1)
    depth = np.where(np.isfinite(best), best, 0.0)  # d_cam has z = 1, so s is the camera z
    return color.astype(np.float32), depth.astype(np.float32)


def make_intrinsics(width: int, height: int) -> Intrinsics:
    f = 0.85 * max(width, height)
    return Intrinsics(f, f * 1.01, (width - 1) / 2 + 0.7, (height - 1) / 2 - 0.4, width, height)


@dataclass
class Sequence:
    color_intr: Intrinsics
    depth_size: tuple[int, int]
    timestamps: np.ndarray
    c2w: list[np.ndarray]
    colors: list[np.ndarray]  # at the colour resolution
    depths: list[np.ndarray]  # at the depth resolution, 0 in HOLE

    @property
    def depth_intr(self) -> Intrinsics:
        w, h = self.depth_size
        return self.color_intr if (w, h) == (self.color_intr.width, self.color_intr.height) else \
            self.color_intr.scaled(w, h)

    def __len__(self):
        return len(self.c2w)


def make_sequence(n: int = 8, color_size=(64, 48), depth_size=None, t0: float = 0.0) -> Sequence:
    depth_size = tuple(depth_size or color_size)
    cintr = make_intrinsics(*color_size)
    dintr = cintr if depth_size == tuple(color_size) else cintr.scaled(*depth_size)
    poses = camera_path(n)
    colors, depths = [], []
    for T in poses:
        colors.append(render(T, cintr)[0])
        d = render(T, dintr)[1]
        d[HOLE] = 0.0
        depths.append(d)
    return Sequence(cintr, depth_size, t0 + np.arange(n) / 30.0, poses, colors, depths)


@dataclass
class Fixture:
    name: str
    path: Path
    seq: Sequence
    frames: list[int]  # sequence frames the reader should return, in order
    depth_tol: float  # quantisation of the format's depth
    color_tol: float  # mean |error| allowed for lossy colour
    marked: bool = True  # MARK region must read back as invalid
    poses: dict = field(default_factory=dict)  # sequence index -> expected c2w or None (default: seq.c2w)

    def expected(self, k: int):
        """(colour, depth, intrinsics, c2w) the reader must return for its k-th frame."""
        i = self.frames[k]
        intr = self.seq.depth_intr
        color = self.seq.colors[i]
        if (color.shape[1], color.shape[0]) != (intr.width, intr.height):
            color = cv2.resize(color, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
        depth = self.seq.depths[i].copy()
        if self.marked:
            depth[MARK] = 0.0
        return color, depth, intr, self.poses.get(i, self.seq.c2w[i])


# ----------------------------------------------------------------------------- encoders

def _bgr8(color):
    return cv2.cvtColor(np.clip(np.round(color * 255), 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


def _jpg(color) -> bytes:
    return cv2.imencode(".jpg", _bgr8(color), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def _png(color) -> bytes:
    return cv2.imencode(".png", _bgr8(color))[1].tobytes()


def _depth_png(depth, units_per_metre, marker=None) -> bytes:
    raw = np.round(depth.astype(np.float64) * units_per_metre)
    raw = np.clip(raw, 0, 65535).astype(np.uint16)
    if marker is not None:
        raw[MARK] = marker
    return cv2.imencode(".png", raw)[1].tobytes()


def _write(path: Path, data: bytes | str):
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)


def _tum_line(t, T):
    q = rotmat_to_quat(T[:3, :3])
    return f"{t:.6f} {T[0, 3]:.10f} {T[1, 3]:.10f} {T[2, 3]:.10f} {q[1]:.10f} {q[2]:.10f} {q[3]:.10f} {q[0]:.10f}"


def _gl(T):
    return c2w_opengl_to_opencv(T)  # the flip is its own inverse


# ----------------------------------------------------------------------------- writers

def write_tum(root: Path, n=8, camera_file=True, associations=False, shuffled=False) -> Fixture:
    """TUM layout: depth stamps 10 ms after colour, 65535 = no reading (7-Scenes), camera.yaml."""
    seq = make_sequence(n, t0=1305031102.0)
    rgb_lines, depth_lines, assoc = [], [], []
    for i in range(n):
        t = seq.timestamps[i]
        td = t + 0.01
        _write(root / f"rgb/{t:.6f}.png", _png(seq.colors[i]))
        _write(root / f"depth/{td:.6f}.png", _depth_png(seq.depths[i], 5000.0, marker=65535))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
        assoc.append(f"{t:.6f} rgb/{t:.6f}.png {td:.6f} depth/{td:.6f}.png")
    if shuffled:
        rgb_lines = rgb_lines[::-1]
    _write(root / "rgb.txt", "# color images\n# timestamp filename\n" + "\n".join(rgb_lines) + "\n")
    _write(root / "depth.txt", "# depth maps\n# timestamp filename\n" + "\n".join(depth_lines) + "\n")
    if associations:
        _write(root / "associations.txt", "\n".join(assoc) + "\n")
    _write(root / "groundtruth.txt", "# ground truth\n# timestamp tx ty tz qx qy qz qw\n"
           + "\n".join(_tum_line(seq.timestamps[i], seq.c2w[i]) for i in range(n)) + "\n")
    if camera_file:
        k = seq.color_intr
        _write(root / "camera.yaml", f"fx: {k.fx!r}\nfy: {k.fy!r}\ncx: {k.cx!r}\ncy: {k.cy!r}\n"
               f"width: {k.width}\nheight: {k.height}\ndepth_scale: 5000.0\nnote: \"synthetic\"\n")
    return Fixture("tum", root, seq, list(range(n)), 1 / 5000, 0.003)


def write_replica(root: Path, n=8) -> Fixture:
    seq = make_sequence(n)
    for i in range(n):
        _write(root / f"results/frame{i:06d}.jpg", _jpg(seq.colors[i]))
        _write(root / f"results/depth{i:06d}.png", _depth_png(seq.depths[i], 6553.5))
    _write(root / "traj.txt", "\n".join(" ".join(f"{v:.12g}" for v in T.reshape(-1)) for T in seq.c2w) + "\n")
    k = seq.color_intr
    _write(root / "cam_params.json", json.dumps({"camera": dict(w=k.width, h=k.height, fx=k.fx, fy=k.fy, cx=k.cx,
                                                                 cy=k.cy, scale=6553.5)}))
    return Fixture("replica", root, seq, list(range(n)), 1 / 6553.5, 0.03, marked=False)


def write_scannet(root: Path, n=8) -> Fixture:
    """Colour 128x96 over depth 64x48; frame 3 has a -inf pose; frame 5 lacks its depth image."""
    seq = make_sequence(n, color_size=(128, 96), depth_size=(64, 48))
    for i in range(n):
        _write(root / f"color/{i}.jpg", _jpg(seq.colors[i]))
        if i != 5:
            _write(root / f"depth/{i}.png", _depth_png(seq.depths[i], 1000.0, marker=0))
        T = np.full((4, 4), -np.inf) if i == 3 else seq.c2w[i]
        _write(root / f"pose/{i}.txt", "\n".join(" ".join(f"{v:.12g}" for v in row) for row in T) + "\n")
    Kc, Kd = np.eye(4), np.eye(4)
    Kc[:3, :3] = seq.color_intr.K
    Kd[:3, :3] = seq.depth_intr.K
    _write(root / "intrinsic/intrinsic_color.txt", "\n".join(" ".join(f"{v:.12g}" for v in r) for r in Kc))
    _write(root / "intrinsic/intrinsic_depth.txt", "\n".join(" ".join(f"{v:.12g}" for v in r) for r in Kd))
    return Fixture("scannet", root, seq, [i for i in range(n) if i != 5], 1e-3, 0.03, poses={3: None})


def write_scannetpp(root: Path, n=8) -> Fixture:
    """Every third frame in test_frames; frame 2 is_bad; OpenGL poses."""
    seq = make_sequence(n)
    k = seq.color_intr
    frames, test = [], []
    for i in range(n):
        name = f"DSC{i + 1:05d}.JPG"
        _write(root / f"dslr/undistorted_images/{name}", _jpg(seq.colors[i]))
        _write(root / f"dslr/undistorted_depths/DSC{i + 1:05d}.png", _depth_png(seq.depths[i], 1000.0, marker=0))
        entry = dict(file_path=name, transform_matrix=_gl(seq.c2w[i]).tolist(), is_bad=(i == 2))
        (test if i % 3 == 1 else frames).append(entry)
    meta = dict(fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy, w=k.width, h=k.height, camera_model="PINHOLE",
                frames=frames[::-1], test_frames=test)
    _write(root / "dslr/nerfstudio/transforms_undistorted.json", json.dumps(meta))
    return Fixture("scannetpp", root, seq, [i for i in range(n) if i != 2], 1e-3, 0.03)


def write_nerfcapture(root: Path, n=8) -> Fixture:
    seq = make_sequence(n)
    k = seq.color_intr
    frames = []
    for i in range(n):
        _write(root / f"rgb/{i}.png", _png(seq.colors[i]))
        _write(root / f"depth/{i}.png", _depth_png(seq.depths[i], 65535 / 10.0, marker=0))
        frames.append(dict(file_path=f"rgb/{i}.png", depth_path=f"depth/{i}.png",
                           transform_matrix=_gl(seq.c2w[i]).tolist(), timestamp=seq.timestamps[i],
                           fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy, w=k.width, h=k.height))
    meta = dict(fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy, w=k.width, h=k.height,
                integer_depth_scale=10.0 / 65535, frames=frames)
    _write(root / "transforms.json", json.dumps(meta, indent=1))
    return Fixture("nerfcapture", root, seq, list(range(n)), 10.0 / 65535, 0.003)


def _lzfse(arr: np.ndarray) -> bytes:
    import lzfse

    return lzfse.compress(np.ascontiguousarray(arr).tobytes())


def _confidence(shape) -> np.ndarray:
    conf = np.full(shape, 2, dtype=np.uint8)
    conf[MARK] = 0
    conf[MEDIUM] = 1
    return conf


def write_record3d(path: Path, n=8, portrait=False, as_zip=False) -> Fixture:
    """Colour twice the depth size; NaN depth in MARK plus confidence 0 there; K column-major;
    poses [qx qy qz qw tx ty tz] OpenGL. Portrait: colour 96x128, metadata dw/dh in the sensor's
    landscape order (64, 48), depth arrays stored 64 rows x 48 columns like the colour image."""
    cs, ds = ((96, 128), (48, 64)) if portrait else ((128, 96), (64, 48))
    seq = make_sequence(n, color_size=cs, depth_size=ds)
    k = seq.color_intr
    files = {}
    poses = []
    for i in range(n):
        files[f"rgbd/{i}.jpg"] = _jpg(seq.colors[i])
        d = seq.depths[i].copy()
        d[MARK] = np.nan
        files[f"rgbd/{i}.depth"] = _lzfse(d.astype(np.float32))
        files[f"rgbd/{i}.conf"] = _lzfse(_confidence(d.shape))
        T = _gl(seq.c2w[i])
        q = rotmat_to_quat(T[:3, :3])
        poses.append([q[1], q[2], q[3], q[0], *T[:3, 3]])
    meta = dict(K=k.K.T.reshape(-1).tolist(), w=k.width, h=k.height, dw=max(ds), dh=min(ds), fps=30,
                poses=poses, initPose=poses[0], cameraType=0)
    files["metadata"] = json.dumps(meta).encode()
    files["sound.m4a"] = b""
    if as_zip:
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in files.items():
                z.writestr(name, data)
    else:
        for name, data in files.items():
            _write(path / name, data)
    return Fixture("record3d", path, seq, list(range(n)), 1e-6, 0.03)


def write_strayscanner(root: Path, n=8, old=False) -> Fixture:
    """rgb.mp4 (mp4v) at 128x96 over 64x48 depth; new layout: odometry with timestamp/frame columns,
    depth png (mm); old layout: odometry without them, depth .npy."""
    seq = make_sequence(n, color_size=(128, 96), depth_size=(64, 48))
    root.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(root / "rgb.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (128, 96))
    assert writer.isOpened(), "OpenCV cannot write mp4v video"
    for c in seq.colors:
        writer.write(_bgr8(c))
    writer.release()
    rows = []
    for i in range(n):
        raw = np.round(seq.depths[i].astype(np.float64) * 1000).astype(np.uint16)
        if old:
            (root / "depth").mkdir(exist_ok=True)
            np.save(root / f"depth/{i:06d}.npy", raw)
        else:
            _write(root / f"depth/{i:06d}.png", cv2.imencode(".png", raw)[1].tobytes())
        _write(root / f"confidence/{i:06d}.png", cv2.imencode(".png", _confidence(raw.shape))[1].tobytes())
        T = seq.c2w[i]
        q = rotmat_to_quat(T[:3, :3])  # (w, x, y, z)
        vals = ", ".join(f"{v:.10f}" for v in [*T[:3, 3], q[1], q[2], q[3], q[0]])
        rows.append(vals if old else f"{seq.timestamps[i]:.6f}, {i}, {vals}")
    header = "x, y, z, qx, qy, qz, qw" if old else "timestamp, frame, x, y, z, qx, qy, qz, qw"
    _write(root / "odometry.csv", header + "\n" + "\n".join(rows) + "\n")
    _write(root / "camera_matrix.csv", "\n".join(", ".join(f"{v:.10f}" for v in r) for r in seq.color_intr.K) + "\n")
    _write(root / "imu.csv", "timestamp, a_x, a_y, a_z, alpha_x, alpha_y, alpha_z\n")
    return Fixture("strayscanner", root, seq, list(range(n)), 1e-3, 0.06)


WRITERS = {
    "tum": write_tum,
    "replica": write_replica,
    "scannet": write_scannet,
    "scannetpp": write_scannetpp,
    "nerfcapture": write_nerfcapture,
    "record3d": write_record3d,
    "strayscanner": write_strayscanner,
}
