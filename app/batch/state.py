"""What happened to each capture, kept beside its run: DIR/<name>/batch_status.json (atomic).

    {"status": "running" | "done" | "resumed" | "failed" | "interrupted",
     "error": one line or null, "attempts": task starts, "worker": address, "pid": worker process id,
     "refine": iterations done or null, "exports": {format: path relative to the run folder}, ...}

A run folder (splat_core.run.run_folder.RunFolder, which names its files) with metrics.json is a
finished run (whoever made it); one with a checkpoint and no metrics.json was killed and is
resumed. A capture recorded as failed is not rerun unless the batch is given --retry-failed.
"""

from __future__ import annotations

import json
from pathlib import Path

from splat_core.io.atomic import write_text_atomic
from splat_core.run.run_folder import RunFolder

# The batch's own files in a run folder (RunFolder names the run's).
STATUS_FILE = "batch_status.json"
LOG_FILE = "batch.log"          # the output of the capture's `splatam` steps
EXPORT_DIR = "export"
# Where `splatam export --format F` writes inside the run folder: the map formats get a file
# named after their suffix; the hand-off formats (COLMAP model, nerfstudio dataset) a folder; a
# mesh a .ply; any other format a file or folder named after it.
HANDOFF_OUTPUTS = {"colmap": "colmap", "nerfstudio": "nerfstudio", "mesh": "mesh.ply"}

# Statuses a capture ends a batch with: done (ran now), resumed (continued from a killed run's
# checkpoint), skipped (finished before this batch), failed, interrupted (Ctrl-C; resumed next
# time), pending (never started: the batch was stopped first).
STATUSES = ("done", "resumed", "skipped", "failed", "interrupted", "pending")


def export_output(fmt: str) -> str:
    """The path, relative to the run folder, that `--export fmt` writes."""
    if fmt in HANDOFF_OUTPUTS:
        return f"{EXPORT_DIR}/{HANDOFF_OUTPUTS[fmt]}"
    from app.exports import EXPORT_SUFFIXES
    if fmt in EXPORT_SUFFIXES:
        return f"{EXPORT_DIR}/map{EXPORT_SUFFIXES[fmt]}"
    return f"{EXPORT_DIR}/{fmt}"


def read_status(run_dir) -> dict:
    path = Path(run_dir) / STATUS_FILE
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def write_status(run_dir, status: dict) -> None:
    write_text_atomic(Path(run_dir) / STATUS_FILE, json.dumps(status, indent=1))


def update_status(run_dir, **fields) -> dict:
    status = read_status(run_dir)
    status.update(fields)
    write_status(run_dir, status)
    return status


def read_metrics(run_dir) -> dict | None:
    return RunFolder(run_dir).read_metrics()


def finished(run_dir) -> bool:
    return RunFolder(run_dir).is_finished()


def has_checkpoint(run_dir) -> bool:
    """A killed run's checkpoint, which `--resume` continues."""
    return RunFolder(run_dir).has_checkpoint()


def refine_done(run_dir, iterations: int) -> bool:
    folder = RunFolder(run_dir)
    m = folder.read_metrics() or {}
    return (m.get("refine") or {}).get("iterations") == iterations and folder.refined_map.is_file()


def exports_missing(run_dir, formats: list[str], status: dict | None = None) -> list[str]:
    """The formats whose export this batch has not recorded as written (or whose output is gone)."""
    done = (status if status is not None else read_status(run_dir)).get("exports") or {}
    return [f for f in formats if f not in done or not (Path(run_dir) / done[f]).exists()]


def plan(run_dir, refine: int, exports: list[str], retry_failed: bool) -> str:
    """What this batch does with a capture: 'skip' (finished, with its refine and exports),
    'failed' (failed before; not rerun without --retry-failed) or 'submit'."""
    status = read_status(run_dir)
    if status.get("status") == "failed" and not retry_failed:
        return "failed"
    if status.get("status") != "failed" and finished(run_dir) and (not refine or refine_done(run_dir, refine)) \
            and not exports_missing(run_dir, exports, status):
        return "skip"
    return "submit"
