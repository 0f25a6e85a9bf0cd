"""`splatam export`: a run's map as 3DGS .ply, .splat, .spz, compressed .ply or a standalone .html;
or a hand-off (app/handoffs.py): a COLMAP model, a nerfstudio dataset, a mesh."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN_DIR", help="run folder (with map.ply) or a map file "
                   "(.ply, .compressed.ply, .splat, .spz)")
    p.add_argument("--format", default=None, metavar="ply|splat|spz|compressed-ply|html|colmap|nerfstudio|mesh",
                   help="output format (default: from the --out suffix; .obj/.glb are meshes)")
    p.add_argument("--out", required=True, help="file to write (colmap, nerfstudio: a folder)")
    from app.handoffs import add_handoff_arguments
    add_handoff_arguments(p)


def main(args) -> int:
    from app.handoffs import export_handoff, handoff_format

    fmt = handoff_format(args.format, args.out)
    if fmt is not None:
        return export_handoff(args, fmt)
    from app.exports import export_map, load_arrays, resolve_format

    fmt = resolve_format(args.format, args.out)
    arrays = load_arrays(Path(args.run))
    out = export_map(arrays, fmt, args.out)
    print(f"wrote {len(arrays['means']):,} Gaussians to {out} ({fmt}, {out.stat().st_size:,} bytes)")
    return 0
