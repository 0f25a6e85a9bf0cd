"""Writing an export folder atomically: build it beside the target, then swap it in.

A crash mid-export leaves the previous export (or nothing) at `out`, never a half-written folder.
An existing `out` is replaced only when it holds a previous export of the same kind (`marker`, a
path inside it that the export always writes) or is empty; anything else is refused (InputError).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import InputError
from ..io.atomic import _UMASK


@contextmanager
def atomic_folder(out, marker: str):
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: is a file; expected a folder for the export")
    if out.is_dir() and any(out.iterdir()) and not (out / marker).exists():
        raise InputError(f"{out}: exists and is not a previous export (no {marker} inside); "
                         "choose another --out or empty it")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    os.chmod(tmp, 0o777 & ~_UMASK)
    try:
        yield tmp
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

