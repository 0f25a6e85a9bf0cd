"""Stray Scanner (iPhone): rgb.mp4, depth/<i:06>.png (uint16 mm; older exports: .npy),
confidence/<i:06>.png (0/1/2), odometry.csv, camera_matrix.csv (3x3 K for the video frames).

odometry.csv: header `timestamp, frame, x, y, z, qx, qy, qz, qw` (c2w); older exports have no
timestamp/frame columns (then row i is video frame i at i / fps s). The poses are OpenCV camera
axes: the app converts ARKit's camera axes before writing (OdometryEncoder.swift, see
docs/formats.md, capture layouts section 2). camera_matrix.csv describes the full-resolution video (1920x1440); when the
video is smaller, K is scaled to it, with a warning. Rows for frames beyond the last one rgb.mp4
decodes are dropped with a warning. Confidence: default high only (common.py says why).

Video frames decode lazily: sequential reads continue the open decoder, short forward jumps skip
frames with grab(), other jumps seek; the last few decoded frames are cached.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from ..camera import pose_matrix, quat_to_rotmat_np
from ..errors import InputError
from .camera_files import intrinsics_for_image
from .common import IndexedCapture, sort_by_time
from .images import color_to_float, decode_depth_image, raw_depth_to_metres, read_bytes, sanitize_depth

DEPTH_SCALE = 1000.0


class VideoFrames:
    """Random access to the frames of a video file, thread-safe."""

    def __init__(self, path, cache_size: int = 8, max_skip: int = 48):
        import cv2

        self.path = path
        self._cap = cv2.VideoCapture(str(path))
        if not self._cap.isOpened():
            raise InputError(f"{path}: cannot open video (corrupt file or unsupported codec)")
        self.width = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0) or 60.0
        self.count = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self._next = 0
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_size, self._max_skip = cache_size, max_skip
        self._lock = threading.Lock()

    def __getitem__(self, k: int) -> np.ndarray:
        import cv2

        with self._lock:
            if k in self._cache:
                self._cache.move_to_end(k)
                return self._cache[k]
            if not (self._next <= k <= self._next + self._max_skip):
                self._cap.set(cv2.CAP_PROP_POS_FRAMES, k)
                self._next = k
            while self._next < k:
                if not self._cap.grab():
                    break
                self._next += 1
            ok, img = self._cap.read() if self._next == k else (False, None)
            if not ok:
                self._next = 10 ** 12  # force a seek next time
                raise InputError(f"{self.path}: cannot decode video frame {k} (video has {self.count} frames)")
            self._next = k + 1
            self._cache[k] = img
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
            return img


def _read_csv(path) -> tuple[list[str] | None, list[list[float]]]:
    text = read_bytes(path).decode(errors="replace")
    header, rows = None, []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            if header is None and not rows:
                header = [f.lower() for f in fields]
                continue
            raise InputError(f"{path}:{n}: expected comma-separated numbers, got {line[:60]!r}") from None
    return header, rows


class StrayScannerCapture(IndexedCapture):
    format_name = "strayscanner"
    registered_by = "the phone app: ARKit delivers depth registered to the colour image"

    def __init__(self, path, **options):
        super().__init__(path, **options)
        root = self.path
        for name in ("rgb.mp4", "odometry.csv", "camera_matrix.csv"):
            if not (root / name).is_file():
                raise InputError(f"{root}: Stray Scanner layout needs rgb.mp4, depth/, odometry.csv and "
                                 f"camera_matrix.csv; {name} is missing")
        _, krows = _read_csv(root / "camera_matrix.csv")
        K = np.asarray(krows, dtype=np.float64)
        if K.shape != (3, 3):
            raise InputError(f"{root / 'camera_matrix.csv'}: expected a 3x3 matrix, got shape {K.shape}")
        self.video = VideoFrames(root / "rgb.mp4")
        vw, vh = self.video.width, self.video.height
        self._color_intr, written_for = intrinsics_for_image(K[0, 0], K[1, 1], K[0, 2], K[1, 2], vw, vh,
                                                             str(root / "camera_matrix.csv"), [(1920, 1440)])
        if written_for:
            self.warn(f"camera_matrix.csv looks like it is for {written_for[0]}x{written_for[1]}; "
                      f"scaled to the {vw}x{vh} video")

        opath = root / "odometry.csv"
        header, rows = _read_csv(opath)
        if not rows:
            raise InputError(f"{opath}: no poses")
        ncol = len(rows[0])
        if any(len(r) != ncol for r in rows):
            raise InputError(f"{opath}: rows have different numbers of columns")
        if header is not None:
            if len(header) != ncol:
                raise InputError(f"{opath}: header has {len(header)} columns, rows have {ncol}")
            col = {name: k for k, name in enumerate(header)}
        elif ncol == 9:
            col = {n: k for k, n in enumerate(["timestamp", "frame", "x", "y", "z", "qx", "qy", "qz", "qw"])}
        elif ncol == 7:
            col = {n: k for k, n in enumerate(["x", "y", "z", "qx", "qy", "qz", "qw"])}
        else:
            raise InputError(f"{opath}: expected columns [timestamp, frame,] x, y, z, qx, qy, qz, qw; got {ncol}")
        missing = [n for n in ("x", "y", "z", "qx", "qy", "qz", "qw") if n not in col]
        if missing:
            raise InputError(f"{opath}: missing column(s) {', '.join(missing)}")
        R = np.asarray(rows)
        frame_ids = R[:, col["frame"]].astype(int) if "frame" in col else np.arange(len(R))
        stamps = R[:, col["timestamp"]] if "timestamp" in col else frame_ids / self.video.fps
        order = sort_by_time(stamps, str(opath), self.warnings)
        R, frame_ids, stamps = R[order], frame_ids[order], stamps[order]

        n_video = self._decodable_frames(int(frame_ids.max()) + 1)
        self._frames, c2w, keep_t = [], [], []
        no_depth = beyond = 0
        for r, f, t in zip(R, frame_ids, stamps):
            if f >= n_video:
                beyond += 1
                continue
            dep = self._depth_file(f)
            if dep is None:
                no_depth += 1
                continue
            q = np.array([r[col["qw"]], r[col["qx"]], r[col["qy"]], r[col["qz"]]])
            t3 = [r[col["x"]], r[col["y"]], r[col["z"]]]
            ok = np.all(np.isfinite(q)) and np.all(np.isfinite(t3)) and np.linalg.norm(q) > 1e-6
            self._frames.append((int(f), dep))
            c2w.append(pose_matrix(quat_to_rotmat_np(q / np.linalg.norm(q)), t3) if ok else None)
            keep_t.append(t)
        if beyond:
            self.warn(f"rgb.mp4 decodes {n_video} frames; {beyond} later row(s) of {opath.name} dropped")
        if no_depth:
            self.warn(f"{no_depth} of {len(R)} odometry rows have no depth file (skipped)")
        if self._frames:
            d0, _ = self._read_depth_file(self._frames[0][1])
            if (d0.shape[1], d0.shape[0]) != self.color_size:
                self._depth_size = (d0.shape[1], d0.shape[0])
        self._finish(np.asarray(keep_t), c2w, f"no odometry row of {opath} has a depth file in depth/")

    def _decodable_frames(self, needed: int) -> int:
        """How many leading video frames decode, up to `needed`. The app's video can hold a frame
        less than odometry.csv has rows (its first sample is stamped -1/60 s; docs/formats.md,
        capture layouts section 2):
        the container's count is checked by decoding the last frame, stepping back if it fails."""
        n = min(self.video.count, needed) if self.video.count > 0 else needed
        for _ in range(3):
            try:
                self.video[n - 1]
                return n
            except InputError:
                n -= 1
                if n <= 0:
                    break
        return max(n, 0)

    def _depth_file(self, f: int):
        for ext in (".png", ".npy"):
            p = self.path / "depth" / f"{f:06d}{ext}"
            if p.is_file():
                return p
        return None

    def _read_depth_file(self, p):
        if p.suffix == ".npy":
            try:
                arr = np.load(p, allow_pickle=False)
            except Exception as e:
                raise InputError(f"{p}: cannot read .npy depth ({e})") from None
            if np.issubdtype(arr.dtype, np.integer):
                return raw_depth_to_metres(arr, DEPTH_SCALE, str(p), invalid_values=())
            return sanitize_depth(arr, str(p))  # float arrays hold metres
        raw = decode_depth_image(read_bytes(p), str(p))
        return raw_depth_to_metres(raw, DEPTH_SCALE, str(p), invalid_values=())

    def _name(self, i, kind):
        f, dep = self._frames[i]
        if kind == "color":
            return f"{self.path / 'rgb.mp4'} (frame {f})"
        if kind == "confidence":
            return str(self.path / "confidence" / f"{f:06d}.png")
        return str(dep)

    def _read_color(self, i):
        return color_to_float(self.video[self._frames[i][0]], self._name(i, "color"), bgr=True)

    def _read_depth(self, i):
        return self._read_depth_file(self._frames[i][1])

    def _read_confidence(self, i):
        p = self.path / "confidence" / f"{self._frames[i][0]:06d}.png"
        if not p.is_file():
            return None
        import cv2

        conf = cv2.imdecode(np.frombuffer(read_bytes(p), np.uint8), cv2.IMREAD_UNCHANGED)
        if conf is None:
            raise InputError(f"{p}: cannot decode confidence image")
        return conf if conf.ndim == 2 else conf[..., 0]
