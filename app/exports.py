"""Exporting a map: one call for the CLI (`splatam export`) and for a viewer button.

    export_map(map_arrays_or_path, fmt, out_path) -> Path

Formats: ply (3DGS, SH degree 0), splat (antimatter15), spz (Niantic; RUB axes, converted on
write), compressed-ply (PlayCanvas / SuperSplat), html (a standalone viser page). Every output is
written atomically (temporary name, then rename).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from splat_core.errors import InputError
from splat_core.io.map_files import SUFFIXES, format_of, map_path_of, read_map_file, write_map_file

EXPORT_SUFFIXES = {**SUFFIXES, "html": ".html"}
FORMATS = tuple(EXPORT_SUFFIXES)


def resolve_format(fmt: str | None, out_path) -> str:
    """`fmt`, or the one named by `out_path`'s suffix; InputError when unknown or untellable."""
    if fmt is None:
        fmt = format_of(out_path, EXPORT_SUFFIXES)
        if fmt is None:
            raise InputError(f"{out_path}: cannot tell the format from the suffix; "
                             f"pass --format {'|'.join(FORMATS)}")
    if fmt not in FORMATS:
        raise InputError(f"unknown export format {fmt!r}; expected one of {', '.join(FORMATS)}")
    return fmt


def load_arrays(map_arrays_or_path) -> dict:
    """Gaussian arrays from a dict (GaussianMap.to_numpy() layout), a GaussianMap, a run folder or
    a map file."""
    if isinstance(map_arrays_or_path, Mapping):
        return map_arrays_or_path
    if hasattr(map_arrays_or_path, "to_numpy"):
        return map_arrays_or_path.to_numpy()
    return read_map_file(map_path_of(Path(map_arrays_or_path)))


def export_map(map_arrays_or_path, fmt: str | None, out_path) -> Path:
    """Write the map in format `fmt` (None: from the suffix of `out_path`) atomically; returns
    the path. Raises InputError (one line, naming the file) for a missing or empty map, an
    unknown format or an unusable output path."""
    out = Path(out_path)
    fmt = resolve_format(fmt, out)
    if out.is_dir():
        raise InputError(f"{out}: is a folder; expected a file name")
    arrays = load_arrays(map_arrays_or_path)
    if len(arrays["means"]) == 0:
        raise InputError(f"{out}: the map has no Gaussians; nothing to export")
    if fmt == "html":
        from .html_export import write_html
        return write_html(out, arrays)
    return write_map_file(out, arrays, fmt)
