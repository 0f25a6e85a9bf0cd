"""Camera-path videos: render a map along poses and encode the frames as an H.264 MP4.

    frames = render_frames(arrays, intrinsics, c2ws, mode="color", near=0.01)   # uint8 HxWx3 each
    write_mp4(path, frames, fps=30, size=(W, H), total=len(c2ws))                # atomic

Encoding uses imageio-ffmpeg (BSD-2; its wheel carries a static ffmpeg binary that runs as a
separate process, so no ffmpeg library is linked into ours). It is the optional extra
`splatam-viewer[video]`; without it, writing an MP4 is a one-line error saying how to install it.
H.264 in yuv420p, which every browser and player plays, needs even frame sizes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from splat_core.errors import InputError

from .console_commands import pip_install

def install_hint() -> str:
    return f"{pip_install('splatam-viewer[video]')} (or: {pip_install('imageio-ffmpeg')})"


class Cancelled(Exception):
    """A video render was cancelled; write_mp4 then leaves no file behind."""


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480); InputError unless both are positive and even (H.264 yuv420p)."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480") from None
    if w <= 0 or h <= 0 or w % 2 or h % 2:
        raise InputError(f"--size {text!r}: width and height must be positive and even (H.264)")
    return w, h


def gaussians_of(arrays, device="cpu"):
    """Renderer input from map arrays: a snapshot's (made once, kept by the snapshot's map) or any
    dict in the GaussianMap.to_numpy() layout."""
    import torch

    from splat_core.gaussians import Gaussians

    if not hasattr(arrays, "tensors"):
        return Gaussians.from_arrays(arrays, device=device)
    g = arrays.tensors()
    return g if g.means.device == torch.device(device) else Gaussians(*(t.to(device) for t in g.fields()))


def render_frames(arrays: dict, intrinsics, c2ws, *, mode: str = "color", near: float = 0.01,
                  backend: str = "auto", background: float = 0.0, depth_max: float | None = None,
                  device="cpu", cancelled=None):
    """Yield one uint8 HxWx3 image per pose: colour, depth (one colour range for the whole path,
    so the video does not flicker) or silhouette. Raises Cancelled when `cancelled()` turns true."""
    import torch

    from app.images import colorize_depth, colorize_silhouette, to_uint8
    from splat_core.camera import invert_pose
    from splat_core.render import Renderer

    g = gaussians_of(arrays, device)
    renderer = Renderer(near, backend)
    for c2w in c2ws:
        if cancelled is not None and cancelled():
            raise Cancelled("video render cancelled")
        w2c = torch.as_tensor(invert_pose(np.asarray(c2w, np.float64)), dtype=torch.float32, device=device)
        with torch.no_grad():
            r = renderer.render_visible(g, intrinsics, w2c, background=background)   # same image, culled first
        if mode == "color":
            yield to_uint8(r.color.cpu().numpy())
        elif mode == "depth":
            depth = r.depth.cpu().numpy()
            if depth_max is None:
                valid = depth[depth > 0]
                depth_max = float(np.percentile(valid, 99)) if valid.size else 1.0
            yield colorize_depth(depth, depth_max)
        else:
            yield colorize_silhouette(r.alpha.cpu().numpy())


def _ffmpeg():
    try:
        import imageio_ffmpeg
    except ImportError:
        raise InputError(f"writing an MP4 needs imageio-ffmpeg: {install_hint()}") from None
    return imageio_ffmpeg


def write_mp4(path, frames, *, fps: float, size: tuple[int, int], total: int | None = None,
              progress: bool = False, on_frame=None) -> int:
    """Encode `frames` (uint8 HxWx3, all of `size` = (W, H)) as an H.264 MP4 at `path`,
    atomically; returns the number of frames written. `on_frame(i)` is called after each frame."""
    from tqdm import tqdm

    from splat_core.io.atomic import atomic_path

    ffmpeg = _ffmpeg()
    w, h = size
    if w % 2 or h % 2:
        raise InputError(f"{path}: frame size {w}x{h} must be even for H.264")
    params = ["-movflags", "+faststart", "-f", "mp4"]   # -f: the temporary name has no .mp4 suffix
    count = 0
    with atomic_path(path) as tmp:
        # codec None: the first H.264 encoder the binary has (libx264 in the wheel's), at its default quality
        writer = ffmpeg.write_frames(str(tmp), (w, h), fps=fps, codec=None, quality=None, macro_block_size=1,
                                     output_params=params, ffmpeg_log_level="error")
        writer.send(None)   # start ffmpeg
        try:
            for img in tqdm(frames, total=total, unit="frame", disable=not progress, desc="video"):
                if img.shape != (h, w, 3) or img.dtype != np.uint8:
                    raise ValueError(f"frame {count} is {img.shape} {img.dtype}; expected ({h}, {w}, 3) uint8")
                writer.send(np.ascontiguousarray(img))
                count += 1
                if on_frame is not None:
                    on_frame(count)
        finally:
            writer.close()
        if count == 0:
            raise InputError(f"{path}: no frames to write")
    return count


def read_mp4(path) -> tuple[list[np.ndarray], tuple[int, int], float]:
    """Decode an MP4: (frames as uint8 HxWx3, (W, H), fps). For tests and checks."""
    ffmpeg = _ffmpeg()
    reader = ffmpeg.read_frames(str(path))
    meta = reader.__next__()
    w, h = meta["size"]
    frames = [np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader]
    return frames, (w, h), float(meta["fps"])


def mp4_path(path) -> Path:
    """The --video argument as a path, checked: an .mp4 file name."""
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise InputError(f"--video {path}: expected a file name ending in .mp4")
    if path.is_dir():
        raise InputError(f"--video {path}: is a folder; expected an .mp4 file name")
    return path
