"""`splatam export --format colmap | nerfstudio | mesh`: a finished run handed to other tools
(splat_core/export/). One call per format for the CLI and, later, the viewer's export panel."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HANDOFF_FORMATS = ("colmap", "nerfstudio", "mesh")


def add_handoff_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("colmap / nerfstudio / mesh (RUN_DIR must be a finished run folder)")
    g.add_argument("--frames", default=None, metavar="keyframes|all|N",
                   help="which frames (N: every Nth processed frame); colmap, nerfstudio: default keyframes; "
                        "mesh: the keyframes plus these, re-read from the capture (default 3)")
    g.add_argument("--input", default=None, metavar="CAPTURE",
                   help="the capture to re-read images from (default: the one the run recorded)")
    g.add_argument("--max-points", type=int, default=None, help="colmap, nerfstudio: seed points at most (default 100000)")
    g.add_argument("--voxel", type=float, default=None, help="mesh: voxel size in metres (default: median depth / 200)")
    g.add_argument("--trunc", type=float, default=None, help="mesh: TSDF truncation in metres (default: 4 voxels)")
    g.add_argument("--depth", default="captured", choices=("captured", "rendered"),
                   help="mesh: fuse the keyframes' captured depth (default) or the map's rendered depth")
    g.add_argument("--quiet", action="store_true", help="no progress bar")


def handoff_format(fmt: str | None, out) -> str | None:
    """The hand-off format asked for, or None for a map format (.obj / .glb name a mesh)."""
    if fmt in HANDOFF_FORMATS:
        return fmt
    if fmt is None and Path(out).suffix.lower() in (".obj", ".glb"):
        return "mesh"
    return None


def export_handoff(args, fmt: str) -> int:
    from tqdm import tqdm

    from splat_core.errors import InputError
    from splat_core.refine.run_data import load_run_data

    if not Path(args.run).is_dir():
        raise InputError(f"{args.run}: --format {fmt} needs a finished run folder (its keyframes and poses)")
    progress = None if args.quiet else (lambda it, **kw: tqdm(it, file=sys.stderr, dynamic_ncols=True, **kw))
    run = load_run_data(args.run)
    t0 = time.perf_counter()
    if fmt == "mesh":
        from splat_core.export.mesh import build_mesh, mesh_format, write_mesh

        mesh_format(args.out)
        frames = {} if args.frames is None else dict(frames=args.frames)
        mesh = build_mesh(run, voxel=args.voxel, trunc=args.trunc, depth=args.depth, progress=progress,
                          input_override=args.input, **frames)
        out = write_mesh(mesh, args.out)
        summary = dict(format="mesh", out=str(out), vertices=len(mesh.vertices), faces=len(mesh.faces),
                       **{k: mesh.metadata[k] for k in ("voxel", "trunc", "depth", "frames", "fused")})
    else:
        from splat_core.export import write_colmap, write_nerfstudio

        writer = write_colmap if fmt == "colmap" else write_nerfstudio
        kw = {} if args.max_points is None else dict(max_points=args.max_points)
        frames = args.frames or "keyframes"
        summary = dict(format=fmt, **writer(run, args.out, frames=frames, input_override=args.input,
                                            progress=progress, **kw))
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    print(json.dumps(summary))
    return 0
