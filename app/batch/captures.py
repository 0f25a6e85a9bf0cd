"""The captures of a batch: paths from the command line and from `--list FILE`, each with the
name of its run folder (DIR/<name>/).

A list file holds one capture per line; blank lines and lines starting with '#' are ignored, and
a relative path is taken from the list file's folder. A name is the capture's folder or file name
(without .zip/.r3d); two captures with one name get their parent folders' names joined in front.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from splat_core.errors import InputError

ARCHIVE_SUFFIXES = (".zip", ".r3d")


@dataclass(frozen=True)
class Capture:
    name: str       # run folder name under DIR
    path: str       # absolute path of the capture ("synthetic": the demo scene)


def read_list(list_file) -> list[str]:
    path = Path(list_file)
    if not path.is_file():
        raise InputError(f"{path}: --list: no such file (expected one capture path per line)")
    out = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        p = Path(line).expanduser()
        out.append(str(p if p.is_absolute() else (path.parent / p)))
    if not out:
        raise InputError(f"{path}: --list: no capture paths in it (one per line; '#' starts a comment)")
    return out


def _base_name(path: Path) -> str:
    name = path.name[: -len(path.suffix)] if path.suffix.lower() in ARCHIVE_SUFFIXES else path.name
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", name) or "capture"


def list_captures(paths: list[str], list_file=None) -> list[Capture]:
    """The captures in order, duplicates (same path) once; InputError naming a missing one."""
    given = list(paths) + (read_list(list_file) if list_file else [])
    if not given:
        raise InputError("no captures: give capture paths or --list FILE")
    resolved: list[Path] = []
    for p in given:
        if p == "synthetic":
            resolved.append(Path("synthetic"))
            continue
        path = Path(p).expanduser().resolve()
        if not path.exists():
            raise InputError(f"{p}: no such capture folder or file")
        if path not in resolved:
            resolved.append(path)
    names = [_base_name(p) for p in resolved]
    depth = [1] * len(resolved)
    while len(set(names)) < len(names):       # prefix clashing names with their parents' names
        changed = False
        clashing = {n for n in names if names.count(n) > 1}
        for i, n in enumerate(names):
            if n in clashing and depth[i] < len(resolved[i].parts) - 1:
                depth[i] += 1
                names[i] = "_".join(_base_name(Path(part)) for part in resolved[i].parts[-depth[i]:])
                changed = True
        if not changed:
            seen: dict[str, int] = {}
            for i, n in enumerate(names):
                seen[n] = seen.get(n, 0) + 1
                if seen[n] > 1:
                    names[i] = f"{n}-{seen[n]}"
    return [Capture(n, "synthetic" if str(p) == "synthetic" else str(p)) for n, p in zip(names, resolved)]
