"""A run as a nerfstudio dataset (nerfstudio/data/dataparsers/nerfstudio_dataparser.py):

    OUT/transforms.json        camera_model, fl_x fl_y cx cy w h (k1 k2 p1 p2 = 0), frames[] with
                               file_path, depth_file_path, transform_matrix; ply_file_path
    OUT/images/frame_NNNNNN.jpg
    OUT/depth/frame_NNNNNN.png 16-bit metric depth in millimetres (0 = no reading)
    OUT/sparse_pc.ply          seed points: opaque Gaussian centres with colours (splatfacto starts from them)

Conventions converted here, nowhere else:
- transform_matrix is camera-to-world with OpenGL camera axes (+x right, +y up, +z backwards):
  our c2w with its camera y and z axes negated. The world frame is the run's (the seed points
  are in it too; nerfstudio orients, centres and scales both with the same transform).
- Pixels: nerfstudio casts the ray of pixel (i, j) through (j + 0.5, i + 0.5) (pixel_offset=0.5
  in Cameras.generate_rays), so cx, cy are ours + 0.5.
- Depth: nerfstudio scales depth images by its --depth-unit-scale-factor option (default 1e-3,
  millimetres to metres), not by a field of the file; the images are written in millimetres to
  match that default (the field depth_unit_scale_factor is written too, for readers that look).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import invert_pose
from ..io.atomic import write_text_atomic
from .folder import atomic_folder
from .frames import export_frames, prepare, write_color
from .seed_points import MAX_POINTS, seed_points, write_points_ply

PIXEL_OFFSET = 0.5
DEPTH_UNIT = 1e-3            # metres per depth-image unit
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


def nerfstudio_c2w(w2c: np.ndarray) -> np.ndarray:
    """transform_matrix (OpenGL camera axes) of an OpenCV-axes w2c."""
    return invert_pose(np.asarray(w2c, np.float64)) @ OPENCV_TO_OPENGL


def depth_png(depth: np.ndarray) -> bytes:
    import cv2

    raw = np.clip(np.round(np.nan_to_num(np.asarray(depth, np.float64)) / DEPTH_UNIT), 0, 65535).astype(np.uint16)
    return cv2.imencode(".png", raw)[1].tobytes()


def write_nerfstudio(run, out_dir, frames: str = "keyframes", source=None, input_override=None,
                     max_points: int = MAX_POINTS, progress=None) -> dict:
    """Write transforms.json, images, depth and seed points atomically to out_dir; returns a summary."""
    indices, source, intr = prepare(run, frames, source, input_override)
    seeds = seed_points(run.map.to_numpy(), max_points=max_points)
    out_dir = Path(out_dir)
    with atomic_folder(out_dir, "transforms.json") as tmp:
        (tmp / "images").mkdir()
        (tmp / "depth").mkdir()
        entries = []
        it = export_frames(run, indices, source)
        if progress is not None:
            it = progress(it, total=len(indices), unit="frame", desc="frames")
        for f in it:
            write_color(tmp / "images" / f"{f.name}.jpg", f.color)
            (tmp / "depth" / f"{f.name}.png").write_bytes(depth_png(f.depth))
            entries.append(dict(file_path=f"images/{f.name}.jpg", depth_file_path=f"depth/{f.name}.png",
                                transform_matrix=nerfstudio_c2w(f.w2c).tolist(), frame_index=f.index,
                                source_index=f.source_index))
        write_points_ply(tmp / "sparse_pc.ply", seeds.xyz, seeds.rgb)
        meta = dict(camera_model="OPENCV", fl_x=float(intr.fx), fl_y=float(intr.fy),
                    cx=float(intr.cx) + PIXEL_OFFSET, cy=float(intr.cy) + PIXEL_OFFSET,
                    w=int(intr.width), h=int(intr.height), k1=0.0, k2=0.0, p1=0.0, p2=0.0,
                    depth_unit_scale_factor=DEPTH_UNIT, ply_file_path="sparse_pc.ply", frames=entries)
        write_text_atomic(tmp / "transforms.json", json.dumps(meta, indent=2) + "\n")
    return dict(images=len(entries), points=len(seeds.xyz), size=[intr.width, intr.height], out=str(out_dir))
