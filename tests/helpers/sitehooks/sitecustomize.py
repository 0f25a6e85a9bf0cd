"""Test-only: hold a `splatam run` after its first checkpoint, until the test ends it.

Python imports `sitecustomize` at start-up from the first folder on sys.path that has one; the
batch tests put this folder first on PYTHONPATH (helpers/hold.py), so every process of the batch
(driver, scheduler, Dask workers, their `splatam run` children) imports it. Without
SPLATAM_TEST_HOLD_DIR it does nothing. With it, a Pipeline whose run folder's name is listed in
SPLATAM_TEST_HOLD_RUNS (comma-separated) writes HOLD_DIR/<name>.held after it saved its first
checkpoint and then waits until HOLD_DIR/<name>.release exists: the run has started and cannot
finish, whatever the machine's load. A run is held once (a resumed run that finds <name>.held goes
on). SIGINT (Ctrl-C) interrupts the wait like any other step of the run; so does the death of the
Dask worker (the child's PDEATHSIG).
"""

import os

_DIR = os.environ.get("SPLATAM_TEST_HOLD_DIR")


def _patch(pipeline_class):
    import time
    from pathlib import Path

    hold_dir = Path(_DIR)
    names = {n for n in os.environ.get("SPLATAM_TEST_HOLD_RUNS", "").split(",") if n}
    save = pipeline_class.save_checkpoint

    def save_checkpoint(self):
        save(self)
        name = Path(self.out_dir).name if self.out_dir is not None else None
        if name not in names or (hold_dir / f"{name}.held").exists():
            return
        (hold_dir / f"{name}.held").write_text(str(os.getpid()))
        deadline = time.monotonic() + 600          # a forgotten hold ends the run's wait, not the suite
        while not (hold_dir / f"{name}.release").exists() and time.monotonic() < deadline:
            time.sleep(0.05)

    pipeline_class.save_checkpoint = save_checkpoint


if _DIR:
    import importlib.abc
    import importlib.machinery
    import sys

    class _PatchPipeline(importlib.abc.MetaPathFinder):
        """Patches splat_core.run.pipeline.Pipeline right after the module is first executed."""

        def find_spec(self, fullname, path, target=None):
            if fullname != "splat_core.run.pipeline":
                return None
            spec = importlib.machinery.PathFinder.find_spec(fullname, path)
            if spec is None or spec.loader is None:
                return spec
            execute = spec.loader.exec_module

            def exec_module(module):
                execute(module)
                _patch(module.Pipeline)
            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, _PatchPipeline())
