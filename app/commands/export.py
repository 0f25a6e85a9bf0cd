"""`splatam export`: a run's map as 3DGS .ply, .splat, .spz, compressed .ply or a standalone .html;
or a hand-off (app/handoffs.py): a COLMAP model, a nerfstudio dataset, a mesh."""

from __future__ import annotations

import argparse
from pathlib import Path


def export_formats() -> tuple[str, ...]:
    """Every --format this command accepts: the map formats, then the hand-offs."""
    from app.exports import FORMATS
    from app.handoffs import HANDOFF_FORMATS

    return tuple(FORMATS) + tuple(f for f in HANDOFF_FORMATS if f not in FORMATS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN_DIR", help="run folder (with map.ply) or a map file "
                   "(.ply, .compressed.ply, .splat, .spz)")
    # written out: importing the formats' modules takes a second, and --help stays quick (the tests
    # check that this is export_formats())
    p.add_argument("--format", default=None, metavar="ply|splat|spz|compressed-ply|html|colmap|nerfstudio|mesh",
                   help="output format (default: from the --out suffix; .obj/.glb are meshes)")
    p.add_argument("--out", required=True, help="file to write (colmap, nerfstudio: a folder)")
    from app.handoffs import add_handoff_arguments
    add_handoff_arguments(p)


def check_format(fmt: str | None, out) -> None:
    """An unknown --format, or an --out whose suffix names none, is refused naming every format accepted."""
    import difflib

    from app.exports import EXPORT_SUFFIXES
    from app.handoffs import handoff_format
    from splat_core.errors import InputError
    from splat_core.io.map_files import format_of

    formats = export_formats()
    if fmt is not None and fmt not in formats:
        close = difflib.get_close_matches(fmt, formats, n=1, cutoff=0.6)
        raise InputError(f"--format {fmt}: unknown export format; expected one of {', '.join(formats)}"
                         + (f" (did you mean {close[0]}?)" if close else ""))
    if fmt is None and handoff_format(None, out) is None and format_of(out, EXPORT_SUFFIXES) is None:
        raise InputError(f"{out}: cannot tell the format from the suffix; pass --format {'|'.join(formats)}")


def main(args) -> int:
    from app.handoffs import export_handoff, handoff_format

    check_format(args.format, args.out)
    fmt = handoff_format(args.format, args.out)
    if fmt is not None:
        return export_handoff(args, fmt)
    from app.exports import export_map, load_arrays, resolve_format

    fmt = resolve_format(args.format, args.out)
    arrays = load_arrays(Path(args.run))
    out = export_map(arrays, fmt, args.out)
    print(f"wrote {len(arrays['means']):,} Gaussians to {out} ({fmt}, {out.stat().st_size:,} bytes)")
    return 0
