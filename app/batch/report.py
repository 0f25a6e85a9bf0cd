"""DIR/index.html: the summary table, and per capture a plot of its trajectory seen from above
(estimate and reference) with links to its files and exports. One self-contained page (inline
SVG, no scripts), written atomically.

"From above": the run's world is its first camera (OpenCV axes: x right, y down, z forward), so
the plot shows x across and z (forward) up, looking down the first camera's -y axis; for a
capture started level that is the floor plan. The reference is shown in the same world (its
first pose on the estimate's), not aligned, as the run folder keeps it.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from splat_core.io.atomic import write_text_atomic
from splat_core.run.run_folder import RunFolder

from . import state
from .summary import COLUMNS, HEADERS, _cell, counts

PLOT_W, PLOT_H, PAD = 320, 240, 14


def estimate_xz(run_dir: Path) -> np.ndarray | None:
    try:
        _, c2w = RunFolder(run_dir).read_trajectory()
    except Exception:
        return None
    c2w = np.asarray(c2w)
    return c2w[:, [0, 2], 3] if len(c2w) else None


def reference_xz(run_dir: Path) -> np.ndarray | None:
    """The reference camera centres in the run's world (checkpoint/meta.json 'references': the
    capture's c2w per frame, made relative to the first as the pipeline does for ATE)."""
    refs = (RunFolder(run_dir).checkpoint_meta() or {}).get("references") or []
    if not refs or refs[0] is None:
        return None
    first_inv = np.linalg.inv(np.asarray(refs[0], dtype=np.float64))
    points = [(first_inv @ np.asarray(r, dtype=np.float64))[[0, 2], 3] for r in refs if r is not None]
    points = [p for p in points if np.all(np.isfinite(p))]
    return np.array(points) if len(points) >= 2 else None


def trajectory_svg(est: np.ndarray | None, ref: np.ndarray | None) -> str:
    """An inline SVG of the estimate (blue) and the reference (grey, dashed) from above, equal axes."""
    tracks = [t for t in (est, ref) if t is not None and len(t)]
    if not tracks:
        return '<p class="none">no trajectory</p>'
    pts = np.concatenate(tracks)
    lo, hi = pts.min(0), pts.max(0)
    span = max(float((hi - lo).max()), 1e-3)
    scale = min((PLOT_W - 2 * PAD), (PLOT_H - 2 * PAD)) / span
    centre = (lo + hi) / 2

    def path(t):   # x right, z (forward) up
        xs = PLOT_W / 2 + (t[:, 0] - centre[0]) * scale
        ys = PLOT_H / 2 - (t[:, 1] - centre[1]) * scale
        return " ".join(f"{x:.1f},{y:.1f}" for x, y in zip(xs, ys))

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{PLOT_W}" height="{PLOT_H}" '
             f'viewBox="0 0 {PLOT_W} {PLOT_H}" role="img" aria-label="trajectory from above">',
             f'<rect width="{PLOT_W}" height="{PLOT_H}" fill="#fafafa" stroke="#ccc"/>']
    if ref is not None and len(ref):
        parts.append(f'<polyline class="reference" points="{path(ref)}" fill="none" stroke="#888" '
                     'stroke-width="1.5" stroke-dasharray="4 3"/>')
    if est is not None and len(est):
        parts.append(f'<polyline class="estimate" points="{path(est)}" fill="none" stroke="#1f77b4" stroke-width="1.5"/>')
        x0, y0 = path(est[:1]).split(",")
        parts.append(f'<circle cx="{x0}" cy="{y0}" r="3" fill="#1f77b4"/>')
    bar_m = 10 ** np.floor(np.log10(span / 2))
    bar_px = bar_m * scale
    parts.append(f'<line x1="{PAD}" y1="{PLOT_H - 8}" x2="{PAD + bar_px:.1f}" y2="{PLOT_H - 8}" stroke="#333"/>'
                 f'<text x="{PAD}" y="{PLOT_H - 11}" font-size="10">{bar_m:g} m</text>')
    parts.append(f'<text x="{PLOT_W - PAD}" y="{PAD}" font-size="10" text-anchor="end">'
                 f'blue: estimate{", grey: reference" if ref is not None else ""}; up: forward (z)</text></svg>')
    return "".join(parts)


def _links(run_dir: Path, name: str) -> str:
    folder = RunFolder(run_dir)
    files = [p.name for p in (folder.map, folder.refined_map, folder.trajectory, folder.metrics,
                              run_dir / state.LOG_FILE) if p.exists()]
    exports = (state.read_status(run_dir).get("exports") or {})
    links = [f'<a href="{html.escape(name)}/{html.escape(f)}">{html.escape(f)}</a>' for f in files]
    links += [f'<a href="{html.escape(name)}/{html.escape(p)}">{html.escape(fmt)}</a>'
              for fmt, p in sorted(exports.items()) if (run_dir / p).exists()]
    return " · ".join(links)


STYLE = """body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ddd;padding:3px 6px;text-align:right}
td.t,th.t{text-align:left}tr.failed td{background:#fde8e8}tr.interrupted td,tr.pending td{background:#fff6dd}
.cards{display:flex;flex-wrap:wrap;gap:14px;margin-top:1.5em}.card{border:1px solid #ddd;padding:8px;width:330px}
.card h3{margin:0 0 4px;font-size:15px}.card p{margin:4px 0;font-size:12px}.err{color:#a00}"""


def write_report(out_root, captures, rows: list[dict], meta: dict) -> Path:
    out_root = Path(out_root)
    text_cols = {"name", "status", "exports", "error"}
    cols = [c for c in COLUMNS if c not in ("input", "run_dir", "exports")]
    head = "".join(f'<th class="{"t" if c in text_cols else ""}">{html.escape(HEADERS.get(c, c))}</th>' for c in cols)
    body = []
    for r in rows:
        cells = "".join(f'<td class="{"t" if c in text_cols else ""}">'
                        + (f'<a href="#{html.escape(r["name"])}">{html.escape(r["name"])}</a>' if c == "name"
                           else html.escape(_cell(r[c]))) + "</td>" for c in cols)
        body.append(f'<tr class="{html.escape(r["status"])}">{cells}</tr>')
    cards = []
    for cap, r in zip(captures, rows):
        run_dir = out_root / cap.name
        error = f'<p class="err">{html.escape(r["error"])}</p>' if r.get("error") else ""
        cards.append(f'<div class="card" id="{html.escape(cap.name)}"><h3>{html.escape(cap.name)} '
                     f'<small>({html.escape(r["status"])})</small></h3>'
                     f'{trajectory_svg(estimate_xz(run_dir), reference_xz(run_dir))}'
                     f'<p>{html.escape(cap.path)}</p><p>{_links(run_dir, cap.name)}</p>{error}</div>')
    tally = ", ".join(f"{n} {s}" for s, n in counts(rows).items() if n)
    page = (f'<!doctype html><html><head><meta charset="utf-8"><title>splatam batch</title><style>{STYLE}</style>'
            f'</head><body><h1>splatam batch</h1><p>{html.escape(str(out_root))}: {html.escape(tally)}; '
            f'{html.escape(meta.get("cluster", ""))}</p><p>Also: <a href="summary.csv">summary.csv</a> · '
            f'<a href="summary.json">summary.json</a> · <a href="summary.md">summary.md</a></p>'
            f'<table><tr>{head}</tr>{"".join(body)}</table><div class="cards">{"".join(cards)}</div></body></html>\n')
    return write_text_atomic(out_root / "index.html", page)
