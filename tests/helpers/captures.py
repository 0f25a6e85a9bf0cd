"""Tiny synthetic captures written in each app's or toolkit's own layout.

Each writer follows what the real writer does, as read from its source and summarised
in docs/formats.md, "Capture layouts in detail" (cited per writer: repository @ commit, path): file
names, image sizes where the reader depends on them, units and rounding, pose and intrinsics
conventions, invalid-depth markers. The scene, the expected frames and the tolerances live in
helpers/scene.py; `Fixture.expected(i)` is what a reader must return for frame i.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import cv2
import numpy as np

from splat_core.camera import Intrinsics, c2w_opengl_to_opencv, rotmat_to_quat
from .scene import (HOLE, MARK, MEDIUM, Fixture, Sequence, _rot, camera_path, make_intrinsics,  # noqa: F401
                           make_sequence, render_rays)


# ----------------------------------------------------------------------------- encoders

def _bgr8(color):
    return cv2.cvtColor(np.clip(np.round(color * 255), 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


def _jpg(color) -> bytes:
    return cv2.imencode(".jpg", _bgr8(color), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def _png(color) -> bytes:
    return cv2.imencode(".png", _bgr8(color))[1].tobytes()


def _depth_png(depth, units_per_metre, marker=None, truncate=False) -> bytes:
    """uint16 PNG; `truncate` converts like numpy's astype (the capture scripts), else rounds."""
    raw = depth.astype(np.float64) * units_per_metre
    raw = np.clip(np.floor(raw) if truncate else np.round(raw), 0, 65535).astype(np.uint16)
    if marker is not None:
        raw[MARK] = marker
    return cv2.imencode(".png", raw)[1].tobytes()


def _write(path: Path, data: bytes | str):
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)


def _write_all(path: Path, files: dict, as_zip: bool, top: str = ""):
    if as_zip:
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in files.items():
                z.writestr(top + name, data)
    else:
        for name, data in files.items():
            _write(path / name, data)


def _tum_line(t, T):
    q = rotmat_to_quat(T[:3, :3])
    return f"{t:.6f} {T[0, 3]:.10f} {T[1, 3]:.10f} {T[2, 3]:.10f} {q[1]:.10f} {q[2]:.10f} {q[3]:.10f} {q[0]:.10f}"


def _gl(T):
    return c2w_opengl_to_opencv(T)  # the flip is its own inverse


def _f32(x) -> float:
    return float(np.float32(x))


def _savetxt(M) -> str:
    """numpy.savetxt(fmt='%f') row by row, as ScanNet's SensorData.save_mat_to_file."""
    return "".join(" ".join(f"{v:f}" for v in row) + "\n" for row in np.asarray(M, dtype=np.float32))


# ----------------------------------------------------------------------------- benchmarks

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


# ScanNet's colour camera as intrinsic_color.txt prints it (float32 values, '%f')
SCANNET_COLOR_K = Intrinsics(1169.621094, 1167.105103, 646.295044, 489.927032, 1296, 968)


def write_scannet(root: Path, n=6, color_size=(1296, 968)) -> Fixture:
    """ScanNet/ScanNet SensReader/python/SensorData.py (docs/formats.md, capture layouts section 4): color/<f>.jpg,
    depth/<f>.png (uint16 mm, 640x480), pose/<f>.txt and intrinsic/{intrinsic,extrinsic}_{color,depth}.txt
    as savetxt('%f') rows; intrinsic_color is the sensor's 1296x968 camera even when
    `export_color_images(image_size=...)` resized the colour (nearest), e.g. color_size=(640, 480).
    Frame 3 has a -inf pose (as ScanNet marks lost tracking); frame 5's depth image is missing."""
    depth_intr = SCANNET_COLOR_K.scaled(640, 480)
    seq = make_sequence(n, depth_size=(640, 480), color_intr=SCANNET_COLOR_K)
    if tuple(color_size) != (1296, 968):  # SensorData: cv2.resize(color, image_size, INTER_NEAREST)
        seq.colors = [cv2.resize(c, tuple(color_size), interpolation=cv2.INTER_NEAREST) for c in seq.colors]
        seq.color_intr = SCANNET_COLOR_K.scaled(*color_size)
    for i in range(n):
        _write(root / f"color/{i}.jpg", _jpg(seq.colors[i]))
        if i != 5:
            _write(root / f"depth/{i}.png", _depth_png(seq.depths[i], 1000.0, marker=0))
        _write(root / f"pose/{i}.txt", _savetxt(np.full((4, 4), -np.inf) if i == 3 else seq.c2w[i]))
    Kc, Kd = np.eye(4), np.eye(4)
    Kc[:3, :3], Kd[:3, :3] = SCANNET_COLOR_K.K, depth_intr.K
    _write(root / "intrinsic/intrinsic_color.txt", _savetxt(Kc))
    _write(root / "intrinsic/intrinsic_depth.txt", _savetxt(Kd))
    _write(root / "intrinsic/extrinsic_color.txt", _savetxt(np.eye(4)))
    _write(root / "intrinsic/extrinsic_depth.txt", _savetxt(np.eye(4)))
    return Fixture("scannet", root, seq, [i for i in range(n) if i != 5], 1e-3, 0.03, poses={3: None})


# ScanNet++ DSLR fisheye camera of the resized images, shrunk 8x from 1752x1168 (sizes do not
# matter to the reader; distortion coefficients are per radian and kept at a realistic size).
SCANNETPP_FISHEYE = dict(fl_x=100.6, fl_y=100.4, cx=109.2, cy=73.4, w=219, h=146,
                         k1=-0.031, k2=-0.0042, k3=0.0011, k4=-0.0002)


def _scannetpp_cameras():
    """(fisheye K, D, size, pinhole Intrinsics) as scannetpp @f3b4712 dslr/undistort.py derives the
    undistorted camera: estimateNewCameraMatrixForUndistortRectify(balance=0), centre forced to w/2, h/2."""
    c = SCANNETPP_FISHEYE
    K = np.array([[c["fl_x"], 0, c["cx"]], [0, c["fl_y"], c["cy"]], [0, 0, 1]])
    D = np.array([c["k1"], c["k2"], c["k3"], c["k4"]])
    K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (c["w"], c["h"]), np.eye(3), balance=0.0)
    return K, D, (c["w"], c["h"]), Intrinsics(K_new[0, 0], K_new[1, 1], c["w"] / 2.0, c["h"] / 2.0, c["w"], c["h"])


def _fisheye_depth(c2w, K, D, size) -> np.ndarray:
    """Camera z seen through the fisheye lens, as the mesh renderer of common/render.py gives it."""
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
    xy = cv2.fisheye.undistortPoints(pts, K, D).reshape(h, w, 2)
    return render_rays(c2w, np.concatenate([xy, np.ones((h, w, 1))], -1))[1]


def write_scannetpp(root: Path, n=8, route="fork") -> Fixture:
    """ScanNet++ DSLR scene (docs/formats.md, capture layouts section 5). Both routes: the download's
    dslr/nerfstudio/transforms.json (scannetpp @f3b4712 common/utils/nerfstudio.py: OPENCV_FISHEYE
    fl_x fl_y cx cy k1-k4 w h, frames/test_frames with file_path, transform_matrix in OpenGL camera
    axes, mask_path; is_bad) and dslr/undistort.py's undistorted_images/ + transforms_undistorted.json
    (PINHOLE, k1-k4 zeroed). route="fork": Nik-V9/scannetpp @0b4489c undistort.py's
    undistorted_depths/<stem>.png (uint16 mm); route="official": common/render.py's fisheye
    render_depth/<stem>.png, `(depth * 1000).clip(0, 65535).astype(uint16)`.
    Every third frame is a test frame; frame 2 is_bad."""
    K, D, size, pinhole = _scannetpp_cameras()
    official = route == "official"
    seq = make_sequence(n, color_intr=pinhole, hole=not official)
    frames, test = [], []
    for i in range(n):
        name = f"DSC{i + 1:05d}.JPG"
        _write(root / f"dslr/undistorted_images/{name}", _jpg(seq.colors[i]))
        if official:
            depth = _fisheye_depth(seq.c2w[i], K, D, size)
            _write(root / f"dslr/render_depth/DSC{i + 1:05d}.png", _depth_png(depth, 1000.0, truncate=True))
        else:
            _write(root / f"dslr/undistorted_depths/DSC{i + 1:05d}.png",
                   _depth_png(seq.depths[i], 1000.0, marker=0, truncate=True))
        entry = dict(file_path=name, transform_matrix=_gl(seq.c2w[i]).tolist(), mask_path=name.replace(".JPG", ".png"),
                     is_bad=(i == 2))
        (test if i % 3 == 1 else frames).append(entry)
    fisheye = dict(SCANNETPP_FISHEYE, camera_model="OPENCV_FISHEYE", frames=frames[::-1], test_frames=test)
    _write(root / "dslr/nerfstudio/transforms.json", json.dumps(fisheye, indent=4))
    undistorted = dict(fisheye, fl_x=pinhole.fx, fl_y=pinhole.fy, cx=pinhole.cx, cy=pinhole.cy, camera_model="PINHOLE",
                       k1=0.0, k2=0.0, k3=0.0, k4=0.0)
    _write(root / "dslr/nerfstudio/transforms_undistorted.json", json.dumps(undistorted, indent=4))
    return Fixture("scannetpp", root, seq, [i for i in range(n) if i != 2], 2e-3, 0.03, marked=not official,
                   depth_exact=not official)


# ----------------------------------------------------------------------------- phone apps

def _float32_intrinsics(intr: Intrinsics) -> Intrinsics:
    """What survives the DDS message's float32 fields."""
    return Intrinsics(_f32(intr.fx), _f32(intr.fy), _f32(intr.cx), _f32(intr.cy), intr.width, intr.height)


def write_nerfcapture(root: Path, n=8, layout="splatam") -> Fixture:
    """The app streaming over DDS, saved by a capture script (docs/formats.md, capture layouts section 3):
    layout="splatam": spla-tam/SplaTAM @da6bbcd scripts/nerfcapture2dataset.py (rgb/<i>.png,
    depth/<i>.png, file_path "rgb/<i>.png"); layout="instant-ngp": NVlabs/instant-ngp
    scripts/nerfcapture2nerf.py (images/<i>.png, images/<i>.depth.png, file_path "images/<i>").
    Both: top-level fl_x fl_y cx cy w h of the first frame + integer_depth_scale = 10/65535; per frame
    the float32 fl_x fl_y cx cy w h and transform_matrix (DDS column-major reshaped and transposed:
    row-major c2w, ARKit camera axes), no timestamp; depth `(depth * 65535 / 10).astype(uint16)`
    from the 256x192 LiDAR map, then cv2.resize to the RGB size with INTER_NEAREST."""
    seq = make_sequence(n, color_size=(640, 480), depth_size=(256, 192), focal_jitter=0.004)
    seq.frame_intr = [_float32_intrinsics(k) for k in seq.frame_intr]  # sub-1e-4 px change: not re-rendered
    seq.color_intr = seq.frame_intr[0]
    seq.depths = [cv2.resize(d, (640, 480), interpolation=cv2.INTER_NEAREST) for d in seq.depths]
    seq.depth_size = (640, 480)
    ngp = layout == "instant-ngp"
    frames = []
    for i in range(n):
        rgb, dep = (f"images/{i}.png", f"images/{i}.depth.png") if ngp else (f"rgb/{i}.png", f"depth/{i}.png")
        _write(root / rgb, _png(seq.colors[i]))
        _write(root / dep, _depth_png(seq.depths[i], 65535 / 10.0, truncate=True))
        k = seq.frame_intr[i]
        frames.append(dict(transform_matrix=_gl(seq.c2w[i]).astype(np.float32).tolist(),
                           file_path=f"images/{i}" if ngp else rgb, fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy,
                           w=k.width, h=k.height, depth_path=dep))
    k0 = seq.frame_intr[0]
    meta = dict(fl_x=k0.fx, fl_y=k0.fy, cx=k0.cx, cy=k0.cy, w=k0.width, h=k0.height,
                frames=frames, integer_depth_scale=10.0 / 65535.0)
    _write(root / "transforms.json", json.dumps(meta, indent=4))
    return Fixture("nerfcapture", root, seq, list(range(n)), 2 * 10.0 / 65535, 0.003, marked=False)


def write_nerfcapture_offline(path: Path, n=3, depth="rgba", as_zip=True) -> Path:
    """The app's own offline export (jc211/NeRFCapture @312cb01 NeRFCapture/DatasetWriter.swift,
    Models/Manifest.swift; docs/formats.md, capture layouts section 3): Zip.quickZipFiles of a <YYMMddHHmmss>/
    folder with images/<i>.png, images/<i>.depth.png and transforms.json in Manifest's field order,
    snake-cased keys (w h fl_x fl_y cx cy depth_integer_scale=1.0 frames; frames: file_path
    "images/<i>", depth_path, transform_matrix, timestamp, fl_x fl_y cx cy w h). depth="rgba": the
    depth map drawn as an 8-bit RGBA picture at 3x the RGB size (UIGraphicsBeginImageContext at
    screen scale; NeRFCapture #10, #17); depth="none": listed but not written (the write is
    commented out at 32cf915). Not readable by design: returns the path."""
    seq = make_sequence(n)
    k, top = seq.color_intr, "240223175130/"
    files, frames = {}, []
    for i in range(n):
        files[f"images/{i}.png"] = _png(seq.colors[i])
        if depth == "rgba":
            grey = np.clip(seq.depths[i], 0, 1) * 255
            big = cv2.resize(grey, (3 * k.width, 3 * k.height), interpolation=cv2.INTER_LINEAR)
            files[f"images/{i}.depth.png"] = cv2.imencode(".png", np.dstack([big] * 3 + [np.full_like(big, 255)])
                                                          .astype(np.uint8))[1].tobytes()
        frames.append(dict(file_path=f"images/{i}", depth_path=f"images/{i}.depth.png",
                           transform_matrix=_gl(seq.c2w[i]).tolist(), timestamp=1000.0 + seq.timestamps[i],
                           fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy, w=k.width, h=k.height))
    meta = dict(w=k.width, h=k.height, fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy, depth_integer_scale=1.0, frames=frames)
    files["transforms.json"] = json.dumps(meta)
    _write_all(path, files, as_zip, top)
    return path


def _lzfse(arr: np.ndarray) -> bytes:
    import lzfse

    return lzfse.compress(np.ascontiguousarray(arr).tobytes())


def _confidence(shape) -> np.ndarray:
    conf = np.full(shape, 2, dtype=np.uint8)
    conf[MARK] = 0
    conf[MEDIUM] = 1
    return conf


def write_record3d(path: Path, n=8, as_zip=False, dw_dh=True, per_frame_intrinsics=True) -> Fixture:
    """A portrait LiDAR .r3d (docs/formats.md, capture layouts section 1, from the app author's reader
    marek-simonik/record3d_offline_unity_demo @ad5eade Assets/Scripts/Record3D/Playback/Record3DVideo.cs,
    nerfstudio-project/viser @6bd9d22 src/viser/extras/_record3d.py and codekansas/usa
    usa/tasks/datasets/r3d.py): a zip (or its unzipped folder) with `metadata` JSON (K column-major
    for the 720x960 RGB image, w=720, h=960, dw=192, dh=256 in the same orientation, fps,
    frameTimestamps, poses [qx qy qz qw tx ty tz] c2w in OpenGL camera axes, initPose,
    perFrameIntrinsicCoeffs [fx fy cx cy] per frame at the RGB size), rgbd/<i>.jpg,
    rgbd/<i>.depth (LZFSE float32 metres, 256 rows x 192 columns, NaN where invalid),
    rgbd/<i>.conf (LZFSE uint8 0/1/2), icon, sound.m4a. dw_dh=False, per_frame_intrinsics=False:
    an older file without those keys nor frameTimestamps (usa falls back to 256x192, n / fps)."""
    seq = make_sequence(n, color_size=(720, 960), depth_size=(192, 256),
                        focal_jitter=0.004 if per_frame_intrinsics else 0.0)
    k = seq.color_intr
    files, poses = {}, []
    for i in range(n):
        files[f"rgbd/{i}.jpg"] = _jpg(seq.colors[i])
        d = seq.depths[i].copy()
        d[MARK] = np.nan
        files[f"rgbd/{i}.depth"] = _lzfse(d.astype(np.float32))
        files[f"rgbd/{i}.conf"] = _lzfse(_confidence(d.shape))
        T = _gl(seq.c2w[i])
        q = rotmat_to_quat(T[:3, :3])
        poses.append([q[1], q[2], q[3], q[0], *T[:3, 3]])
    meta = dict(K=k.K.T.reshape(-1).tolist(), w=k.width, h=k.height, fps=30, poses=poses, initPose=poses[0])
    if dw_dh:
        meta.update(dw=192, dh=256, frameTimestamps=seq.timestamps.tolist())
    if per_frame_intrinsics:
        meta["perFrameIntrinsicCoeffs"] = [[f.fx, f.fy, f.cx, f.cy] for f in seq.frame_intr]
    files["metadata"] = json.dumps(meta).encode()
    files["icon"] = _jpg(seq.colors[0])
    files["sound.m4a"] = b""
    _write_all(path, files, as_zip)
    return Fixture("record3d", path, seq, list(range(n)), 1e-6, 0.03, medium_dropped=True)


def write_strayscanner(root: Path, n=8, old=False, video_frames=None) -> Fixture:
    """A Stray Scanner scan folder (strayrobots/scanner @e0e2522 docs/format.md and
    StrayScanner/Helpers/{DatasetEncoder,OdometryEncoder,DepthEncoder,ConfidenceEncoder,VideoEncoder}.swift,
    CCode/PngEncoder.mm; docs/formats.md, capture layouts section 2): rgb.mp4 at the 1920x1440 capture size (HEVC
    in the app; mp4v here, OpenCV cannot write HEVC), depth/<f:06>.png uint16 round(mm) 256 wide x
    192 high, confidence/<f:06>.png L8 0/1/2, odometry.csv `timestamp, frame, x, y, z, qx, qy, qz, qw`
    with ARFrame timestamps and frame as %06d, poses c2w already in OpenCV camera axes,
    camera_matrix.csv the row-major K for 1920x1440, imu.csv. old=True: the 2021 layout (@1ccec0d:
    depth/<f:06>.npy uint16 mm, odometry x y z qx qy qz qw without header). video_frames: how many
    frames rgb.mp4 holds (n - 1: one short of odometry.csv)."""
    seq = make_sequence(n, color_size=(1920, 1440), depth_size=(256, 192), t0=48213.25)
    root.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(root / "rgb.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 60.0, (1920, 1440))
    assert writer.isOpened(), "OpenCV cannot write mp4v video"
    for c in seq.colors[:n if video_frames is None else video_frames]:
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
        rows.append(vals if old else f"{seq.timestamps[i]:.6f}, {i:06d}, {vals}")
    header = "" if old else "timestamp, frame, x, y, z, qx, qy, qz, qw\n"
    _write(root / "odometry.csv", header + "\n".join(rows) + "\n")
    _write(root / "camera_matrix.csv", "\n".join(", ".join(f"{v:.10f}" for v in r) for r in seq.color_intr.K) + "\n")
    _write(root / "imu.csv", "timestamp, a_x, a_y, a_z, alpha_x, alpha_y, alpha_z\n")
    kept = list(range(n if video_frames is None else video_frames))
    return Fixture("strayscanner", root, seq, kept, 1e-3, 0.06, medium_dropped=True)


WRITERS = {
    "tum": write_tum,
    "replica": write_replica,
    "scannet": write_scannet,
    "scannetpp": write_scannetpp,
    "nerfcapture": write_nerfcapture,
    "record3d": write_record3d,
    "strayscanner": write_strayscanner,
}
