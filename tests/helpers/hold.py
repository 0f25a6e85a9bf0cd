"""Holding a batch's `splatam run` child at a known point, so a test acts on a run that has
started and cannot finish, without timing (see sitehooks/sitecustomize.py for the mechanism).

    hold = Hold(tmp_path / "hold", ["b"])
    proc = subprocess.Popen(cmd, env=hold.env(base_env))
    wait_until(lambda: hold.held("b"), ...)     # b saved its first checkpoint and waits
    ... interrupt, kill its worker ...; hold.release("b") lets it go on
"""

from __future__ import annotations

import os
from pathlib import Path

SITEHOOKS = Path(__file__).resolve().parent / "sitehooks"


class Hold:
    def __init__(self, folder: Path, names):
        self.folder, self.names = Path(folder), list(names)
        self.folder.mkdir(parents=True, exist_ok=True)

    def env(self, base: dict) -> dict:
        path = os.pathsep.join(p for p in (str(SITEHOOKS), base.get("PYTHONPATH", "")) if p)
        return dict(base, PYTHONPATH=path, SPLATAM_TEST_HOLD_DIR=str(self.folder),
                    SPLATAM_TEST_HOLD_RUNS=",".join(self.names))

    def held(self, name: str) -> bool:
        return (self.folder / f"{name}.held").exists()

    def release(self, name: str) -> None:
        (self.folder / f"{name}.release").write_text("")
