"""Which of a run's frames an export takes, and their images at the capture's resolution.

`choose_frames(run, "keyframes" | "all" | "N")`: processed-frame numbers (keyframes; every frame;
every Nth frame). `export_frames(...)` yields each chosen frame's colour and depth re-read from the
capture at the capture's resolution, with its estimated w2c. A run without a recorded capture (the
synthetic demo) can still export its keyframes, at the working resolution they are stored at.
A capture with two cameras is exported as its colour camera (color_camera.py): `prepare` returns
the colour camera's intrinsics and `export_frames` its images, depth and poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from .color_camera import color_camera_intrinsics, handoff_cameras, to_color_camera


@dataclass
class ExportFrame:
    index: int            # processed-frame number (run.records / run.w2cs)
    source_index: int     # the capture's frame number
    name: str             # image file name in the export
    w2c: np.ndarray       # 4 x 4, OpenCV axes
    color: np.ndarray     # H x W x 3 float32 in [0, 1]
    depth: np.ndarray     # H x W float32 metres, 0 = invalid


def choose_frames(run, which: str = "keyframes") -> list[int]:
    """Processed-frame numbers for --frames keyframes | all | N (every Nth)."""
    which = str(which)
    n = len(run.records)
    if which == "keyframes":
        return list(run.keyframe_indices)
    if which == "all":
        return list(range(n))
    try:
        step = int(which)
    except ValueError:
        step = 0
    if step < 1:
        raise InputError(f"--frames {which}: expected keyframes, all or a positive whole number (every Nth frame)")
    return list(range(0, n, step))


def frame_name(run, k: int) -> str:
    return f"frame_{int(run.records[k]['source_index']):06d}"


def export_intrinsics(run, source) -> Intrinsics:
    """The intrinsics of the exported images: the capture's (its colour camera's when it has two),
    or the working resolution's without one."""
    if source is None:
        return run.intrinsics
    cams = handoff_cameras(source)
    return source.intrinsics if cams is None else color_camera_intrinsics(cams)


def open_source(run, which: str, override=None):
    """The run's capture (None when it records none and only keyframes are asked for)."""
    from ..refine.run_data import open_run_capture

    source = open_run_capture(run, override)
    if source is None and str(which) != "keyframes":
        raise InputError(f"{run.run_dir}: the run does not record its capture; pass --input CAPTURE "
                         f"or export --frames keyframes (stored at the working resolution)")
    return source


def prepare(run, frames: str, source=None, input_override=None):
    """What the COLMAP and nerfstudio exports start from: the chosen frame indices, the capture to
    re-read them from, and the intrinsics they are written at."""
    indices = choose_frames(run, frames)
    if source is None:
        source = open_source(run, frames, input_override)
    return indices, source, export_intrinsics(run, source)


def export_frames(run, indices: list[int], source) -> Iterator[ExportFrame]:
    """Each chosen frame's images (capture resolution; stored keyframes when `source` is None)."""
    if source is None:
        by_index = {kf.frame_index: kf for kf in run.keyframes}
        for k in indices:
            kf = by_index[k]
            yield ExportFrame(k, int(run.records[k]["source_index"]), frame_name(run, k), np.array(kf.w2c),
                              np.asarray(kf.color, np.float32), np.asarray(kf.depth, np.float32))
        return
    from ..run.frame_feed import prepare_frame

    intr = source.intrinsics
    cams = handoff_cameras(source)
    keyframe_w2c = {kf.frame_index: kf.w2c for kf in run.keyframes}
    for k in indices:
        si = int(run.records[k]["source_index"])
        frame = prepare_frame(source, si, intr, run.config.max_depth)
        # A keyframe's frozen pose is the one the map was optimised against.
        w2c = keyframe_w2c.get(k, run.w2cs[k])
        out = ExportFrame(k, si, frame_name(run, k), np.array(w2c, np.float64),
                          np.asarray(frame.color, np.float32), np.asarray(frame.depth, np.float32))
        yield out if cams is None else to_color_camera(out, source, cams, run.config.max_depth)


def to_uint8(color: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.asarray(color) * 255.0), 0, 255).astype(np.uint8)


def write_color(path, color: np.ndarray) -> None:
    import cv2

    bgr = cv2.cvtColor(to_uint8(color), cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(path.suffix, bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise InputError(f"{path}: could not encode the image")
    path.write_bytes(data.tobytes())
