"""Where a run's PSNR is lost: the map rendered at each evaluated frame's estimated pose against
the captured frame (as the run's own PSNR), split by frame and by kind of pixel.

    python benchmarks/psnr_profile.py --run RUN [--every 5] [--json]

Per evaluated frame (frame 0 and every --every-th, as metrics.json's PSNR): the PSNR; the mean
brightness of the capture and of the render (their ratio: an exposure change shows as a ratio
away from 1 that the map cannot follow); the PSNR after an affine colour fit per frame
(`fitted`, gain and offset per channel fitted by least squares to the frame being evaluated
itself: an optimistic bound of what a per-frame exposure model could give, not a figure of the
map); the squared error's share from pixels with no valid depth, from the image border (the
outer 8 % of each side), from depth edges (a 3 x 3 neighbourhood spanning more than 10 cm) and
from pixels the map leaves uncovered (rendered alpha < 0.5); and a sharpness figure of the
capture (the mean absolute Laplacian of its grey image: motion blur lowers it).

Summaries over frames: means, and the correlation of per-frame PSNR with the brightness ratio's
distance from 1 and with sharpness. Prints a table (or JSON); writes nothing.

`masked` is the PSNR as the original SplaTAM code evaluates it (../shared/reference/splatam_spec.md
section 5.2): render and capture both zeroed where the captured depth is invalid, the mean still
over every pixel, so pixels without depth count as perfect. It is shown beside the figure of
record (metrics.json's psnr: every pixel compared), not instead of it: on a capture with depth
holes (7-Scenes) it is the higher of the two.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _psnr(mse: float) -> float:
    return float(-10.0 * np.log10(max(mse, 1e-12)))


def affine_fit(render: np.ndarray, capture: np.ndarray) -> np.ndarray:
    """render mapped per channel by the least-squares gain and offset onto capture."""
    out = np.empty_like(render)
    for c in range(3):
        a = np.stack([render[..., c].ravel(), np.ones(render[..., c].size)], axis=1)
        coef, *_ = np.linalg.lstsq(a, capture[..., c].ravel(), rcond=None)
        out[..., c] = render[..., c] * coef[0] + coef[1]
    return out


def depth_edges(depth: np.ndarray, jump: float = 0.10) -> np.ndarray:
    """Pixels whose 3 x 3 neighbourhood's valid depths span more than `jump` metres, or touch a hole."""
    h, w = depth.shape
    pad = np.pad(depth, 1, mode="edge")
    stack = np.stack([pad[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
    valid = stack > 0
    hi = np.where(valid, stack, -np.inf).max(axis=0)
    lo = np.where(valid, stack, np.inf).min(axis=0)
    return ((hi - lo) > jump) | (valid.any(axis=0) & ~valid.all(axis=0))


def sharpness(color: np.ndarray) -> float:
    grey = color.mean(axis=2)
    lap = (grey[1:-1, :-2] + grey[1:-1, 2:] + grey[:-2, 1:-1] + grey[2:, 1:-1] - 4 * grey[1:-1, 1:-1])
    return float(np.abs(lap).mean())


def masked_psnr(render_color: np.ndarray, color: np.ndarray, depth: np.ndarray) -> float:
    """The original SplaTAM evaluation's PSNR: both images zeroed where depth <= 0, the mean over
    all pixels (so a pixel without depth adds no error but still counts)."""
    sq = ((render_color - color) ** 2).mean(axis=2)
    return _psnr(float(np.where(depth > 0, sq, 0.0).mean()))


def profile_frame(render_color, render_alpha, color, depth, border: float = 0.08) -> dict:
    h, w = depth.shape
    sq = ((render_color - color) ** 2).mean(axis=2)
    total = float(sq.sum())
    by, bx = max(1, int(round(border * h))), max(1, int(round(border * w)))
    edge_band = np.ones((h, w), bool)
    edge_band[by:h - by, bx:w - bx] = False
    masks = {"no_depth": depth <= 0, "border": edge_band, "depth_edges": depth_edges(depth),
             "uncovered": render_alpha < 0.5}
    fitted = affine_fit(render_color, color)
    interior = ~(masks["no_depth"] | masks["border"] | masks["depth_edges"])
    return dict(
        psnr=_psnr(sq.mean()),
        masked=masked_psnr(render_color, color, depth),
        fitted=_psnr(float(((fitted - color) ** 2).mean())),
        interior=_psnr(float(sq[interior].mean())) if interior.any() else None,
        brightness_capture=float(color.mean()), brightness_render=float(render_color.mean()),
        ratio=float(color.mean() / max(render_color.mean(), 1e-6)),
        sharpness=sharpness(color),
        **{f"share_{k}": float(sq[m].sum() / max(total, 1e-12)) for k, m in masks.items()},
        **{f"pixels_{k}": float(m.mean()) for k, m in masks.items()},
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", required=True)
    ap.add_argument("--every", type=int, default=None, help="evaluate frame 0 and every N-th (default: the run's eval_every)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    import torch

    from splat_core.refine.run_data import frame_views, load_run_data, open_run_capture
    from splat_core.render import Renderer

    run = load_run_data(args.run)
    source = open_run_capture(run)
    every = args.every or run.config.eval_every
    picks = [k for k in range(len(run.records))
             if (k == 0 or (k + 1) % every == 0) and not run.records[k].get("lost")]
    renderer = Renderer(near=run.config.near_plane)
    rows = []
    with torch.no_grad():
        for k in picks:
            view = frame_views(run, source, run.intrinsics, [k])[0]
            out = renderer.render_visible(run.map, run.intrinsics, view.w2c)
            row = profile_frame(out.color.cpu().numpy().astype(np.float64), out.alpha.cpu().numpy().reshape(view.depth.shape),
                                view.color.cpu().numpy().astype(np.float64), view.depth.cpu().numpy())
            rows.append(dict(frame=k, keyframe=k in set(run.keyframe_indices), **row))
    keys = [k for k in rows[0] if k not in ("frame", "keyframe")]
    summary = {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in keys}
    psnr = np.array([r["psnr"] for r in rows])
    summary["corr_psnr_vs_abs_log_ratio"] = float(np.corrcoef(psnr, [abs(np.log(r["ratio"])) for r in rows])[0, 1])
    summary["corr_psnr_vs_sharpness"] = float(np.corrcoef(psnr, [r["sharpness"] for r in rows])[0, 1])
    if args.json:
        print(json.dumps(dict(run=str(args.run), frames=rows, summary=summary), indent=1))
        return 0
    cols = ["frame", "psnr", "masked", "fitted", "interior", "ratio", "sharpness", "share_no_depth", "share_border",
            "share_depth_edges", "share_uncovered"]
    print(" ".join(f"{c:>10.10}" for c in cols))
    for r in rows:
        print(" ".join(f"{r[c]:>10.3f}" if isinstance(r[c], float) else f"{str(r[c]):>10}" for c in cols))
    print("mean " + " ".join(f"{k}={v:.3f}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
