"""Small finished runs and the CLI called in-process, for the viewer and video tests."""

from __future__ import annotations

import numpy as np

from splat_core.io.ply import write_ply
from splat_core.io.trajectory import write_tum_trajectory

from .viewer import blob_map


class CliResult:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def make_run(tmp_path, n=400):
    run = tmp_path / "run"
    m = blob_map(n, 0)
    write_ply(run / "map.ply", m.to_numpy())
    c2w = np.stack([np.eye(4)] * 3)
    c2w[:, 0, 3] = [0.0, 0.1, 0.2]
    write_tum_trajectory(run / "trajectory.txt", [0.0, 0.1, 0.2], c2w)
    return run


def run_cli(*argv):
    """`splatam ARGS` in process (a subprocess would spend seconds importing torch)."""
    import contextlib
    import io

    from app.cli import splatam_main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = splatam_main(list(argv))
    return CliResult(code, out.getvalue(), err.getvalue())
