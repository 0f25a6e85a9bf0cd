"""File access inside a capture folder or a zip archive (one interface for both readers)."""

from __future__ import annotations

import threading
import zipfile
import zlib
from pathlib import Path

from ..errors import InputError


class DirStore:
    """Files under a folder, addressed by relative path."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def exists(self, rel: str) -> bool:
        return (self.root / rel).is_file()

    def names(self) -> list[str]:
        return [p.relative_to(self.root).as_posix() for p in self.root.rglob("*") if p.is_file()]

    def read(self, rel: str) -> bytes:
        from .images import read_bytes

        return read_bytes(self.root / rel)

    def label(self, rel: str) -> str:
        return str(self.root / rel)


class ZipStore:
    """Files inside a zip archive (e.g. a Record3D .r3d), read without unpacking.

    When every entry sits under one top folder, names are relative to it.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self._zip = zipfile.ZipFile(self.path)
            entries = [n for n in self._zip.namelist() if not n.endswith("/")]
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise InputError(f"{self.path}: not a readable zip archive ({e}); truncated or damaged download?") from None
        tops = {n.split("/", 1)[0] for n in entries}
        self._prefix = ""
        if len(tops) == 1 and all("/" in n for n in entries):
            self._prefix = tops.pop() + "/"
        self._names = {n[len(self._prefix):]: n for n in entries}
        self._lock = threading.Lock()

    def exists(self, rel: str) -> bool:
        return rel in self._names

    def names(self) -> list[str]:
        return list(self._names)

    def read(self, rel: str) -> bytes:
        if rel not in self._names:
            raise InputError(f"{self.label(rel)}: not found in the archive")
        try:
            with self._lock:
                return self._zip.read(self._names[rel])
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError) as e:
            raise InputError(f"{self.label(rel)}: cannot read from the archive ({e}); truncated or damaged file?") from None

    def label(self, rel: str) -> str:
        return f"{self.path}:{rel}"


def open_store(path: Path):
    path = Path(path)
    return DirStore(path) if path.is_dir() else ZipStore(path)
