"""DIR/summary.csv, summary.json and summary.md: one row per capture, each file written atomically.

A row joins the batch's result for the capture (status, error, this batch's seconds) with its run
folder's metrics.json (frames, the run's own seconds, s/frame, ATE when the capture has reference
poses, PSNR, depth L1, Gaussians, lost and skipped frames, loops closed when the run reports them).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from splat_core.io.atomic import write_text_atomic

from . import state

COLUMNS = ("name", "status", "frames", "seconds", "s_per_frame", "ate_rmse_cm", "psnr", "depth_l1_cm", "gaussians",
           "frames_lost", "frames_skipped", "loops", "refine_psnr_gain_db", "batch_seconds", "attempts", "exports",
           "error", "input", "run_dir")
HEADERS = {"name": "capture", "s_per_frame": "s/frame", "ate_rmse_cm": "ATE cm", "depth_l1_cm": "depth L1 cm",
           "frames_lost": "lost", "frames_skipped": "skipped", "refine_psnr_gain_db": "refine dB",
           "batch_seconds": "batch s"}


def _loops(m: dict):
    """Loops closed, when the run's metrics report them (a count, a list, or a section with either)."""
    for key in ("loops", "loop_closures", "loops_closed"):
        v = m.get(key)
        if isinstance(v, bool):
            continue
        if isinstance(v, (int, float)):
            return int(v)
        if isinstance(v, list):
            return len(v)
        if isinstance(v, dict):
            for k in ("count", "closed", "loops"):
                if isinstance(v.get(k), (int, float)) and not isinstance(v.get(k), bool):
                    return int(v[k])
                if isinstance(v.get(k), list):
                    return len(v[k])
    return None


def make_row(capture, result: dict | None, out_root) -> dict:
    run_dir = Path(out_root) / capture.name
    result = result or {}
    m = state.read_metrics(run_dir) or {}
    per_frame = m.get("per_frame") or []
    seconds = sum(r.get("wall_seconds", 0.0) for r in per_frame) if per_frame else None
    status = state.read_status(run_dir)
    return dict(
        name=capture.name, status=result.get("status", "pending"), frames=m.get("frames"), seconds=seconds,
        s_per_frame=m.get("wall_seconds_per_frame"), ate_rmse_cm=m.get("ate_rmse_cm"), psnr=m.get("psnr"),
        depth_l1_cm=m.get("depth_l1_cm"), gaussians=m.get("num_gaussians"), frames_lost=m.get("frames_lost"),
        frames_skipped=m.get("frames_skipped"), loops=_loops(m),
        refine_psnr_gain_db=(m.get("refine") or {}).get("psnr_gain_db"),
        batch_seconds=result.get("seconds"), attempts=result.get("attempts", status.get("attempts")),
        exports=" ".join(sorted((status.get("exports") or {}).values())), error=result.get("error"),
        input=capture.path, run_dir=capture.name)


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 100 else f"{v:.1f}"
    return str(v)


def counts(rows: list[dict]) -> dict:
    out = {s: 0 for s in state.STATUSES}
    for r in rows:
        out[r["status"]] = out.get(r["status"], 0) + 1
    return out


def to_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r[k] is None else r[k] for k in COLUMNS})
    return buf.getvalue()


def to_markdown(rows: list[dict], title: str) -> str:
    cols = [c for c in COLUMNS if c not in ("input", "run_dir")]
    lines = [f"# {title}", "", ", ".join(f"{n} {s}" for s, n in counts(rows).items() if n), "",
             "| " + " | ".join(HEADERS.get(c, c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r[c]).replace("|", "\\|") for c in cols) + " |")
    return "\n".join(lines) + "\n"


def write_summary(out_root, rows: list[dict], meta: dict) -> None:
    out_root = Path(out_root)
    write_text_atomic(out_root / "summary.csv", to_csv(rows))
    write_text_atomic(out_root / "summary.json", json.dumps(dict(meta, counts=counts(rows), captures=rows), indent=1))
    write_text_atomic(out_root / "summary.md", to_markdown(rows, f"splatam batch: {out_root}"))
