"""`splatam export`: a run's map as a standard 3DGS .ply or an antimatter15 .splat."""

from __future__ import annotations

import argparse
from pathlib import Path

from splat_core.errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN_DIR", help="run folder (with map.ply) or a 3DGS .ply file")
    p.add_argument("--format", choices=["ply", "splat"], default=None,
                   help="output format (default: from the --out suffix)")
    p.add_argument("--out", required=True, help="file to write")


def map_path_of(run: Path) -> Path:
    if run.is_dir():
        path = run / "map.ply"
        if not path.is_file():
            raise InputError(f"{run}: not a run folder (expected map.ply inside)")
        return path
    if not run.is_file():
        raise InputError(f"{run}: no such run folder or map file")
    return run


def main(args) -> int:
    from app.browse import read_map
    from splat_core.io.ply import write_ply, write_splat

    out = Path(args.out)
    fmt = args.format or out.suffix.lower().lstrip(".")
    if fmt not in ("ply", "splat"):
        raise InputError(f"--out {out}: cannot tell the format from the suffix; pass --format ply|splat")
    if out.is_dir():
        raise InputError(f"--out {out}: is a folder; expected a file name")
    arrays = read_map(map_path_of(Path(args.run)))
    (write_ply if fmt == "ply" else write_splat)(out, arrays)
    print(f"wrote {len(arrays['means']):,} Gaussians to {out} ({fmt})")
    return 0
