"""One capture's task on a Dask worker: the ordinary `splatam run` (or `--resume`), then
`splatam refine` and `splatam export`, each in a child process, so a crash ends one capture.

The task is idempotent: a step whose output exists is not redone, and a run folder with a
checkpoint is continued from it. Dask reruns the task elsewhere when its worker dies; the retry
then resumes from the checkpoint the killed run left. The task returns a plain dict (the
result) and never raises for a failed capture: that is a result too.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from splat_core.run.run_folder import RunFolder

from . import state
from .child import PARENT_ENV

STOP_POLL_SECONDS = 1.0
STOP_GRACE_SECONDS = 20.0
INTERRUPTED_CODES = (130, 143, -signal.SIGINT, -signal.SIGTERM)


@dataclass(frozen=True)
class RunOptions:
    """The options every capture's run gets (picklable: sent to the workers)."""
    config: str | None = None
    engine: str = "sequential"
    resolution: str | None = None
    max_frames: int | None = None
    stride: int = 1
    device: str = "auto"
    format: str | None = None
    refine: int = 0
    exports: tuple[str, ...] = ()
    cores: int | None = None                    # threads of one run (OMP/MKL/Numba); None: the child's default
    gpu_slots: dict = field(default_factory=dict)   # local cluster on GPUs: worker name -> CUDA_VISIBLE_DEVICES
    stop_event: str | None = None               # name of a distributed.Event set to stop the batch


def run_command(capture, run_dir: Path, opts: RunOptions, resume: bool) -> list[str]:
    cmd = ["run", "--input", capture.path, "--out", str(run_dir), "--quiet", "--engine", opts.engine,
           "--stride", str(opts.stride), "--device", opts.device]
    for flag, value in (("--config", opts.config), ("--resolution", opts.resolution),
                        ("--max-frames", opts.max_frames), ("--format", opts.format)):
        if value is not None:
            cmd += [flag, str(value)]
    return cmd + (["--resume"] if resume else [])


def export_command(run_dir: Path, fmt: str, refined: bool) -> list[str]:
    from app.exports import FORMATS
    source = RunFolder(run_dir).refined_map if refined and fmt in FORMATS else run_dir
    return ["export", str(source), "--format", fmt, "--out", str(run_dir / state.export_output(fmt))]


def _error_line(log: Path, start: int, code: int) -> str:
    """The child's one-line error ('error: ...'), else its last line; how it died if by a signal."""
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"killed by {name}" + (" (out of memory?)" if -code == signal.SIGKILL else "")
    with open(log, "rb") as f:
        f.seek(start)
        lines = [ln.strip() for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if errors:                       # an InputError's one line (exit 2)
        return errors[-1][len("error:"):].strip()
    return f"exit code {code}" + (f": {lines[-1]}" if lines else "")   # a crash: its traceback's last line


def _stop_requested(event) -> bool:
    try:
        return event is not None and event.is_set()
    except Exception:       # the scheduler is gone: the batch is over
        return True


class Child:
    """Runs `splatam <args>` steps of one capture, logging to RUN/batch.log."""

    def __init__(self, run_dir: Path, opts: RunOptions, worker_name=None):
        self.log = run_dir / state.LOG_FILE
        self.env = dict(os.environ, PYTHONUNBUFFERED="1", **{PARENT_ENV: str(os.getpid())})
        try:    # what Dask's nanny sets for its worker (1 BLAS thread, malloc trimming) is not for the run
            import dask
            for key, value in (dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}).items():
                if self.env.get(key) == str(value):
                    del self.env[key]
        except ImportError:
            pass
        if opts.cores:
            for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
                self.env[var] = str(opts.cores)
        if opts.gpu_slots and worker_name in opts.gpu_slots:
            self.env["CUDA_VISIBLE_DEVICES"] = str(opts.gpu_slots[worker_name])
        self.event = None
        if opts.stop_event:
            try:
                from distributed import Event
                self.event = Event(opts.stop_event)
            except Exception:
                self.event = None

    def __call__(self, args: list[str]) -> tuple[int, str | None]:
        """(exit code, the error line or None)."""
        cmd = [sys.executable, "-m", "app.batch.child", *args]
        with open(self.log, "ab") as f:
            f.write(f"\n$ splatam {' '.join(args)}\n".encode())
            f.flush()
            start = f.tell()
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=self.env)
        try:
            while True:
                try:
                    code = proc.wait(timeout=STOP_POLL_SECONDS)
                    break
                except subprocess.TimeoutExpired:
                    if _stop_requested(self.event):
                        proc.send_signal(signal.SIGINT)
                        try:
                            proc.wait(timeout=STOP_GRACE_SECONDS)
                        except subprocess.TimeoutExpired:
                            proc.kill()
                        return 130, "interrupted"
        except BaseException:
            proc.kill()
            raise
        if code in INTERRUPTED_CODES:
            return code, "interrupted"
        return code, None if code == 0 else _error_line(self.log, start, code)


def _worker_identity():
    try:
        from distributed import get_worker
        w = get_worker()
        return w.name, w.address
    except Exception:        # called outside a Dask worker (a plain function call)
        return None, None


def run_capture(capture, out_root: str, opts: RunOptions) -> dict:
    """Bring capture's run folder to finished (run, refine, exports); returns the result dict:
    name, status (done / resumed / failed / interrupted), error, seconds (this task's wall time),
    attempts, worker, host."""
    started = time.perf_counter()
    run_dir = Path(out_root) / capture.name
    run_dir.mkdir(parents=True, exist_ok=True)
    name, address = _worker_identity()
    previous = state.read_status(run_dir)
    status = dict(previous, status="running", error=None, input=capture.path, attempts=previous.get("attempts", 0) + 1,
                  worker=address, host=socket.gethostname(), pid=os.getpid(), started=time.time())
    status.setdefault("exports", {})
    state.write_status(run_dir, status)
    child = Child(run_dir, opts, name)
    outcome = "done"

    def result(kind: str, error: str | None = None) -> dict:
        status.update(status=kind, error=error, seconds=time.perf_counter() - started, ended=time.time())
        state.write_status(run_dir, status)
        return dict(name=capture.name, input=capture.path, status=kind, error=error, seconds=status["seconds"],
                    attempts=status["attempts"], worker=address, host=status["host"])

    steps = []
    if not state.finished(run_dir):
        resume = state.has_checkpoint(run_dir)
        outcome = "resumed" if resume else "done"
        steps.append(run_command(capture, run_dir, opts, resume))
    if opts.refine and not state.refine_done(run_dir, opts.refine):
        steps.append(["refine", str(run_dir), "--iterations", str(opts.refine), "--quiet", "--device", opts.device])
    missing = state.exports_missing(run_dir, list(opts.exports), status)
    if missing:
        (run_dir / state.EXPORT_DIR).mkdir(exist_ok=True)
    for args in steps:
        code, error = child(args)
        if error == "interrupted":
            return result("interrupted", "interrupted (Ctrl-C); the next batch resumes it")
        if code != 0:
            return result("failed", f"splatam {args[0]}: {error}")
    for fmt in missing:
        code, error = child(export_command(run_dir, fmt, bool(opts.refine)))
        if error == "interrupted":
            return result("interrupted", "interrupted (Ctrl-C); the next batch resumes it")
        if code != 0:
            return result("failed", f"splatam export --format {fmt}: {error}")
        status["exports"][fmt] = state.export_output(fmt)
        state.write_status(run_dir, status)
    return result(outcome)
