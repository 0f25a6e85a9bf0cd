"""A run as a COLMAP sparse model in COLMAP's text format (https://colmap.github.io/format.html):

    OUT/images/frame_NNNNNN.jpg          the chosen frames at the capture's resolution
    OUT/sparse/0/cameras.txt             CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]  (one PINHOLE: fx fy cx cy)
    OUT/sparse/0/images.txt              IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then POINTS2D[] as (X Y POINT3D_ID)
    OUT/sparse/0/points3D.txt            POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID POINT2D_IDX)

Conventions converted here, nowhere else:
- Poses: COLMAP stores world-to-camera (R as a scalar-first quaternion, t) with OpenCV camera axes,
  the same as our w2c: no axis change.
- Pixels: COLMAP puts the centre of the top-left pixel at (0.5, 0.5); ours is at (0, 0)
  (camera.py). So cx, cy and every 2D point are ours + 0.5.
Readers of the text model: COLMAP itself, pycolmap.Reconstruction (gsplat's simple_trainer uses it),
nerfstudio's colmap dataparser (reads cameras.txt before cameras.bin); see docs/handoffs.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Intrinsics, rotmat_to_quat
from .folder import atomic_folder
from .frames import export_frames, prepare, write_color
from .seed_points import MAX_POINTS, add_observations, seed_points

PIXEL_OFFSET = 0.5   # COLMAP pixel coordinate = ours + 0.5
IMAGE_SUFFIX = ".jpg"


def colmap_camera_line(intr: Intrinsics, camera_id: int = 1) -> str:
    return (f"{camera_id} PINHOLE {intr.width} {intr.height} {float(intr.fx)!r} {float(intr.fy)!r} "
            f"{float(intr.cx) + PIXEL_OFFSET!r} {float(intr.cy) + PIXEL_OFFSET!r}")


def colmap_pose(w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qvec wxyz, tvec) of a w2c, as images.txt stores them."""
    q = rotmat_to_quat(np.asarray(w2c, np.float64)[:3, :3])
    q = q / np.linalg.norm(q)
    return (-q if q[0] < 0 else q), np.asarray(w2c, np.float64)[:3, 3]


def write_colmap(run, out_dir, frames: str = "keyframes", source=None, input_override=None,
                 max_points: int = MAX_POINTS, progress=None) -> dict:
    """Write the COLMAP model and images atomically to out_dir; returns a summary dict.

    `source`: an open capture (default: the run's recorded one, or `input_override`)."""
    indices, source, intr = prepare(run, frames, source, input_override)
    seeds = seed_points(run.map.to_numpy(), max_points=max_points)
    out_dir = Path(out_dir)
    with atomic_folder(out_dir, "sparse/0/images.txt") as tmp:
        (tmp / "images").mkdir()
        sparse = tmp / "sparse" / "0"
        sparse.mkdir(parents=True)
        names, poses = [], []
        for pos, f in enumerate(_progress(export_frames(run, indices, source), len(indices), progress)):
            write_color(tmp / "images" / (f.name + IMAGE_SUFFIX), f.color)
            add_observations(seeds, f.w2c, f.depth, intr)
            names.append(f.name + IMAGE_SUFFIX)
            poses.append(f.w2c)
        _write_model(sparse, intr, names, poses, seeds)
    tracked = len(np.unique(np.concatenate([o[0] for o in seeds.observations]))) if names else 0
    return dict(images=len(names), points=tracked, size=[intr.width, intr.height], out=str(out_dir))


def _progress(it, total, progress):
    return it if progress is None else progress(it, total=total, unit="frame", desc="frames")


def _write_model(sparse: Path, intr: Intrinsics, names, poses, seeds) -> None:
    """cameras.txt, images.txt, points3D.txt. Points that no exported frame sees are left out
    (COLMAP's points always have a track); IMAGE_ID and POINT3D_ID count from 1, POINT2D_IDX from 0
    (a point's place in its image's POINTS2D list)."""
    seen = [o[0] for o in seeds.observations]
    all_seen = np.concatenate(seen) if seen else np.zeros(0, np.int64)
    point_id = np.zeros(len(seeds.xyz), np.int64)
    tracked = np.unique(all_seen)
    point_id[tracked] = np.arange(1, len(tracked) + 1)
    image_of = np.concatenate([np.full(len(s), pos + 1) for pos, s in enumerate(seen)]) if seen else all_seen
    p2d_idx = np.concatenate([np.arange(len(s)) for s in seen]) if seen else all_seen
    order = np.argsort(all_seen, kind="stable")               # group the observations by point
    starts = np.searchsorted(all_seen[order], tracked)
    ends = np.append(starts[1:], len(order))

    (sparse / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: 1\n{colmap_camera_line(intr)}\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(names)}"]
    for pos, (name, w2c) in enumerate(zip(names, poses)):
        q, t = colmap_pose(w2c)
        lines.append(" ".join([str(pos + 1), *(repr(float(x)) for x in q), *(repr(float(x)) for x in t), "1", name]))
        idx, u, v = seeds.observations[pos]
        lines.append(" ".join(f"{x:.6f} {y:.6f} {pid}" for x, y, pid in
                              zip((u + PIXEL_OFFSET).tolist(), (v + PIXEL_OFFSET).tolist(), point_id[idx].tolist())))
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")
    with open(sparse / "points3D.txt", "w") as f:
        f.write("# 3D point list with one line of data per point:\n"
                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                f"# Number of points: {len(tracked)}\n")
        pairs = np.stack([image_of[order], p2d_idx[order]], 1).tolist()
        for n, i in enumerate(tracked.tolist()):
            x, y, z = seeds.xyz[i].tolist()
            r, g, b = seeds.rgb[i].tolist()
            track = " ".join(f"{img} {j}" for img, j in pairs[starts[n]: ends[n]])
            f.write(f"{n + 1} {x!r} {y!r} {z!r} {r} {g} {b} 0 {track}\n")
