"""A mesh of a run: TSDF fusion of depth at the run's poses, marching cubes, clean-up, trimesh.

    build_mesh(run, voxel=None, trunc=None, depth="captured", frames=DEFAULT_FRAMES, ...) -> trimesh.Trimesh
    fuse_views(views, intrinsics, voxel, trunc, progress=None) -> BlockVolume
    extract_mesh(volume, min_component_faces=..., progress=None) -> trimesh.Trimesh
    write_mesh(mesh, path)  -> .ply | .obj | .glb, atomically

`depth`: "captured" fuses the keyframes' own depth and colour (stored in the run at the working
resolution); "rendered" fuses the map's rendered depth (normalised by its silhouette, kept where
the silhouette is >= RENDER_MIN_ALPHA) and colour at the same poses. docs/handoffs.md says which is
better where, measured by benchmarks/mesh.py.

`frames`: "keyframes" fuses the keyframes alone; "all" or "N" (every Nth processed frame) fuses the
keyframes plus those frames (lost frames left out), their captured depth re-read from the run's
capture at the working resolution and posed by the run's estimated trajectory. When the capture
cannot be read, one warning and the keyframes alone. docs/handoffs.md has the measurement behind
DEFAULT_FRAMES.

Marching cubes (scikit-image) runs chunk by chunk (CHUNK^3 blocks plus one voxel of the next
chunk), so no dense grid of the whole bounding box is ever made; a cube is meshed only when all
eight corners have been observed and none is truncated.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from .tsdf import BlockVolume

CHUNK = 4                      # blocks per chunk side for marching cubes
MIN_COMPONENT_FACES = 200      # smaller disconnected pieces are removed
RENDER_MIN_ALPHA = 0.9
MAX_STEP_VOXELS = 3.0 * np.sqrt(3.0)   # largest TSDF change across a meshed cube, in voxels (benchmarks/mesh.py)
DEPTH_MODES = ("captured", "rendered")
MIN_VOXEL = 0.001              # metres; finer would allocate blocks by the million
MESH_SUFFIXES = {".ply": "ply", ".obj": "obj", ".glb": "glb"}
DEFAULT_FRAMES = "3"           # keyframes + every 3rd frame: docs/handoffs.md, "Which frames, measured"


def default_voxel(depths) -> float:
    """Voxel size from the depth range: 1/200 of the median depth reading, within [4 mm, 5 cm]
    (1 cm for a room seen from ~2 m)."""
    vals = np.concatenate([np.asarray(d)[np.asarray(d) > 0].ravel()[::7] for d in depths])
    if len(vals) == 0:
        raise InputError("no depth readings to build a mesh from")
    return float(np.clip(np.median(vals) / 200.0, 0.004, 0.05))


def default_trunc(voxel: float) -> float:
    return 4.0 * voxel


def fusion_indices(run, frames: str = "keyframes") -> list[int]:
    """Processed-frame numbers fused for --frames: the keyframes plus the chosen frames, lost ones left out."""
    from .frames import choose_frames

    keep = set(run.keyframe_indices)
    if str(frames) != "keyframes":
        keep.update(k for k in choose_frames(run, frames) if not run.records[k].get("lost"))
    return sorted(keep)


def mesh_source(run, input_override=None, warn=None):
    """The capture to re-read frames' depth from; None, after one warning, when the run records none
    or it is gone (a capture named by `input_override` that cannot be opened is an error)."""
    from ..refine.run_data import open_run_capture

    reason = f"{run.run_dir}: the run does not record its capture"
    try:
        source = open_run_capture(run, input_override)
    except InputError as e:
        if input_override is not None:
            raise
        source, reason = None, str(e).removesuffix("; pass --input CAPTURE")
    if source is None:
        (warn or _warn)(f"{reason}; fusing the keyframes only (pass --input CAPTURE to fuse more frames)")
    return source


def _warn(message: str) -> None:
    import sys

    print(f"warning: {message}", file=sys.stderr, flush=True)


def frame_views(run, indices, depth: str = "captured", source=None):
    """(colour, depth, w2c) per processed frame `indices` at the working resolution: keyframes from
    the run (their frozen poses), other frames re-read from `source` (captured) or rendered."""
    if depth not in DEPTH_MODES:
        raise InputError(f"--depth {depth}: expected captured or rendered")
    keyframes = {kf.frame_index: kf for kf in run.keyframes}
    for k in indices:
        kf = keyframes.get(k)
        w2c = np.asarray(kf.w2c if kf is not None else run.w2cs[k], np.float64)
        if depth == "rendered":
            yield _rendered(run, w2c)
        elif kf is not None:
            yield np.asarray(kf.color, np.float32), np.asarray(kf.depth, np.float32), w2c
        elif source is not None:
            from ..run.frame_feed import prepare_frame

            try:
                f = prepare_frame(source, int(run.records[k]["source_index"]), run.intrinsics, run.config.max_depth)
            except InputError:      # a frame without usable depth adds nothing
                continue
            yield np.asarray(f.color, np.float32), np.asarray(f.depth, np.float32), w2c


def _rendered(run, w2c):
    import torch
    from ..render import render

    with torch.no_grad():
        r = render(run.map, run.intrinsics, w2c)
    alpha = r.alpha.cpu().numpy().astype(np.float32)
    ok = alpha >= RENDER_MIN_ALPHA
    safe = np.where(ok, alpha, 1.0)
    d = np.where(ok, r.depth.cpu().numpy() / safe, 0.0).astype(np.float32)
    c = np.clip(r.color.cpu().numpy() / safe[..., None], 0, 1).astype(np.float32)
    return c, d, w2c


def fuse_views(views, intr: Intrinsics, voxel: float, trunc: float, progress=None, total=None) -> BlockVolume:
    volume = BlockVolume(voxel, trunc)
    it = views if progress is None else progress(views, total=total, unit="frame", desc="fusing")
    for color, depth, w2c in it:
        volume.integrate(depth, color, w2c, intr)
    return volume


def _chunk_arrays(volume: BlockVolume, chunk: np.ndarray):
    """Dense tsdf, weight, colour of one chunk plus one voxel layer of its +x/+y/+z neighbours."""
    b = volume.block
    n = CHUNK * b + 1
    tsdf = np.ones((n, n, n), np.float32)
    weight = np.zeros((n, n, n), np.float32)
    color = np.zeros((n, n, n, 3), np.float32)
    base = chunk * CHUNK
    for a in range(CHUNK + 1):
        for c in range(CHUNK + 1):
            for e in range(CHUNK + 1):
                s = volume.slot_of(base + (a, c, e))
                if s is None:
                    continue
                sl = tuple(slice(o * b, min(o * b + b, n)) for o in (a, c, e))
                m = tuple(x.stop - x.start for x in sl)
                tsdf[sl] = volume.tsdf[s, : m[0], : m[1], : m[2]]
                weight[sl] = volume.weight[s, : m[0], : m[1], : m[2]]
                color[sl] = volume.color[s, : m[0], : m[1], : m[2]]
    return tsdf, weight, color


def _cube_mask(tsdf: np.ndarray, weight: np.ndarray, max_step: float) -> np.ndarray:
    """Marks each cube whose 8 corners are observed and untruncated and whose values differ by at
    most `max_step`. A distance field changes by at most sqrt(3) voxels across a cube; the
    projective distance TSDF fusion stores grows faster on surfaces seen at a grazing angle
    (hence the allowance of 3 sqrt(3)), and the false crossings fusion leaves behind depth edges
    (free space next to the averaged-in back of an object) jump by more than that."""
    ok = (weight > 0) & (np.abs(tsdf) < 0.999)
    cube = ok[:-1, :-1, :-1].copy()
    lo = tsdf[:-1, :-1, :-1].copy()
    hi = lo.copy()
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                sl = (slice(dx, dx + ok.shape[0] - 1), slice(dy, dy + ok.shape[1] - 1), slice(dz, dz + ok.shape[2] - 1))
                cube &= ok[sl]
                np.minimum(lo, tsdf[sl], out=lo)
                np.maximum(hi, tsdf[sl], out=hi)
    cube &= (hi - lo) <= max_step
    # scikit-image's marching_cubes meshes the cube [x-1, x] x [y-1, y] x [z-1, z] where mask[x, y, z]
    # is True (measured: tests/export/test_handoffs.py::test_marching_cubes_mask_convention).
    mask = np.zeros_like(ok)
    mask[1:, 1:, 1:] = cube
    return mask


def extract_mesh(volume: BlockVolume, min_component_faces: int = MIN_COMPONENT_FACES, progress=None):
    import trimesh
    from skimage.measure import marching_cubes

    if volume.n == 0:
        raise InputError("nothing was fused: no depth readings at the keyframe poses")
    chunks = np.unique(np.floor_divide(volume.coords[: volume.n], CHUNK), axis=0)
    max_step = MAX_STEP_VOXELS * volume.voxel / volume.trunc
    verts, faces, colors, offset = [], [], [], 0
    it = chunks if progress is None else progress(chunks, total=len(chunks), unit="chunk", desc="meshing")
    for chunk in it:
        tsdf, weight, color = _chunk_arrays(volume, chunk)
        mask = _cube_mask(tsdf, weight, max_step)
        if not mask.any():
            continue
        seen = tsdf[(weight > 0) & (np.abs(tsdf) < 0.999)]
        if seen.min() > 0 or seen.max() < 0:
            continue
        try:
            v, f, _, _ = marching_cubes(tsdf, level=0.0, mask=mask, allow_degenerate=False)
        except (ValueError, RuntimeError):      # no crossing inside the mask
            continue
        if len(f) == 0:
            continue
        idx = np.clip(np.round(v).astype(np.int64), 0, tsdf.shape[0] - 1)
        colors.append(color[idx[:, 0], idx[:, 1], idx[:, 2]])
        verts.append((v + chunk * CHUNK * volume.block) * volume.voxel)
        faces.append(f + offset)
        offset += len(v)
    if not faces:
        raise InputError("the fused volume has no surface to mesh")
    vc = np.clip(np.round(np.concatenate(colors) * 255), 0, 255).astype(np.uint8)
    vc = np.concatenate([vc, np.full((len(vc), 1), 255, np.uint8)], 1)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), vertex_colors=vc, process=False)
    mesh.merge_vertices()
    return remove_small_components(mesh, min_component_faces)


def remove_small_components(mesh, min_faces: int):
    """Drop connected pieces with fewer than min_faces faces (the pieces trimesh's split finds)."""
    import trimesh

    if min_faces <= 1 or len(mesh.faces) == 0:
        return mesh
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    counts = np.bincount(labels)
    keep = counts[labels] >= min_faces
    mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    return mesh


def build_mesh(run, voxel: float | None = None, trunc: float | None = None, depth: str = "captured",
               min_component_faces: int = MIN_COMPONENT_FACES, progress=None, frames: str = DEFAULT_FRAMES,
               source=None, input_override=None, warn=None):
    """The run's mesh (world frame of the run, metres, vertex colours) as a trimesh.Trimesh.
    `source`: the capture to re-read frames from (default: the run's, or `input_override`)."""
    if voxel is None:
        voxel = default_voxel(kf.depth for kf in run.keyframes)
    if trunc is None:
        trunc = default_trunc(voxel)
    if not (voxel >= MIN_VOXEL and trunc >= voxel):
        raise InputError(f"--voxel {voxel} / --trunc {trunc}: need voxel >= {MIN_VOXEL} m and trunc >= voxel")
    indices = fusion_indices(run, frames)
    if depth == "captured" and len(indices) > len(run.keyframes) and source is None:
        source = mesh_source(run, input_override, warn)
        if source is None:
            indices, frames = run.keyframe_indices, "keyframes"
    views = frame_views(run, indices, depth, source)
    volume = fuse_views(views, run.intrinsics, voxel, trunc, progress, len(indices))
    mesh = extract_mesh(volume, min_component_faces, progress)
    mesh.metadata.update(voxel=voxel, trunc=trunc, depth=depth, volume_bytes=volume.nbytes, blocks=volume.n,
                         frames=str(frames), fused=len(indices))
    return mesh


def mesh_format(path) -> str:
    fmt = MESH_SUFFIXES.get(Path(path).suffix.lower())
    if fmt is None:
        raise InputError(f"{path}: expected a mesh file name ending in {', '.join(MESH_SUFFIXES)}")
    return fmt


def write_mesh(mesh, path) -> Path:
    """Write through trimesh (vertex colours kept), atomically."""
    from ..io.atomic import atomic_path

    path = Path(path)
    fmt = mesh_format(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected a mesh file name")
    with atomic_path(path) as tmp:
        mesh.export(str(tmp), file_type=fmt)
    return path
