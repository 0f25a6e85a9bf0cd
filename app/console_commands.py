"""Commands as the messages print them: what the user can paste into this shell.

    command("splatam-viewer")            # "splatam-viewer" when PATH finds this install's script,
                                         # else its path: ".venv/bin/splatam-viewer" (under the cwd)
    pip_install("splatam-viewer[batch]") # ".venv/bin/pip install 'splatam-viewer[batch]'" in a venv,
                                         # else "/usr/bin/python3 -m pip install ..." (this interpreter)

`make demo` installs into `.venv` without activating it, so a bare `splatam-viewer` in a message
would say "command not found", and a bare `pip` would install into another Python.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path


def scripts_dir() -> Path:
    """The folder of this interpreter's console scripts (a venv's python is a link: not resolved)."""
    return Path(os.path.abspath(sys.executable)).parent


def shown_path(path: Path) -> str:
    """`path` relative to the cwd when it is under it (with a slash, so a shell runs that file), else absolute."""
    path = Path(os.path.abspath(path))
    try:
        relative = path.relative_to(Path.cwd())
    except ValueError:
        return shlex.quote(str(path))
    text = str(relative)
    return shlex.quote(text if os.sep in text else f".{os.sep}{text}")


def command(name: str) -> str:
    """How to run our console script `name` from this shell."""
    script = scripts_dir() / name
    if not script.is_file():           # not installed as a script (python -m from a checkout): its name
        return name
    found = shutil.which(name)
    if found is not None and os.path.samefile(found, script):
        return name
    return shown_path(script)


def in_virtualenv() -> bool:
    return sys.prefix != getattr(sys, "base_prefix", sys.prefix)


def pip_install(requirement: str) -> str:
    """How to install `requirement` into the Python that runs this program."""
    spec = shlex.quote(requirement)
    if in_virtualenv() and (scripts_dir() / "pip").is_file():
        return f"{command('pip')} install {spec}"
    return f"{shown_path(Path(sys.executable))} -m pip install {spec}"
