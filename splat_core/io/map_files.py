"""Gaussian map files by format: finding a run's map, reading any supported map file, writing
one in a named format, and telling the format from a file name.

Formats: `ply` (3DGS PLY, ply.py), `splat` (antimatter15, ply.py), `spz` (Niantic, RUB axes)
and `compressed-ply` (PlayCanvas / SuperSplat), both in compressed.py.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

SUFFIXES = {"ply": ".ply", "splat": ".splat", "spz": ".spz", "compressed-ply": ".compressed.ply"}


def format_of(path, suffixes: dict[str, str] = SUFFIXES) -> str | None:
    """The format named by `path`'s suffix (case-insensitive; the longest match wins, so
    x.compressed.ply is compressed-ply), or None."""
    name = Path(path).name.lower()
    matches = [(len(suffix), fmt) for fmt, suffix in suffixes.items() if name.endswith(suffix)]
    return max(matches)[1] if matches else None


def map_path_of(run: Path) -> Path:
    """RUN_DIR/map.ply, or `run` itself when it is a file; InputError when neither exists."""
    run = Path(run)
    if run.is_dir():
        path = run / "map.ply"
        if not path.is_file():
            raise InputError(f"{run}: not a run folder (expected map.ply inside)")
        return path
    if not run.is_file():
        raise InputError(f"{run}: no such run folder or map file")
    return run


def read_map_file(path) -> dict:
    """Gaussian arrays from a .ply (3DGS or compressed), .splat or .spz file."""
    from . import compressed, ply

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".splat":
        return ply.read_splat(path)
    if suffix == ".spz":
        return compressed.read_spz(path)
    if path.is_file() and compressed.is_compressed_ply(path):
        return compressed.read_compressed_ply(path)
    return ply.read_ply(path)


def write_map_file(path, arrays: dict, fmt: str) -> Path:
    """Write `arrays` to `path` atomically in format `fmt` (a key of SUFFIXES)."""
    from . import compressed, ply

    writers = {"ply": ply.write_ply, "splat": ply.write_splat, "spz": compressed.write_spz,
               "compressed-ply": compressed.write_compressed_ply}
    if fmt not in writers:
        raise InputError(f"unknown map format {fmt!r}; expected one of {', '.join(writers)}")
    return writers[fmt](path, arrays)
