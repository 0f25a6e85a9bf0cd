"""mapping.final_hole_fill on finished runs: the engine's end-of-run passes (SplaTAM.finish:
splat_core/final_holes.py, then splat_core/color_fit.py) applied to each run folder's map as it was
before them, and the PSNR of record (every eval_every-th frame at the estimated pose, every pixel,
as metrics.json's psnr) of each variant, on the same map and poses.

    python benchmarks/final_holes.py RUN [RUN ...] [--fraction F] [--opacity 0.95] [--passes 0] [--json]
                                     [--variants fit,holes+fit,holes] [--orders]

--fraction defaults to the `cpu` preset's mapping.final_hole_fill (0.1), --opacity and --passes to
the settings' defaults. Variants: `fit` (the colour fit alone: the `cpu` preset before this
pass), `holes+fit` (the hole fill, then the colour fit: what SplaTAM.finish does with the setting
on), `holes` (the hole fill alone) and, with --orders, `fit+holes` (the colour fit first). The passes move no pose (tracking
has finished), so applying them to a run folder of the same configuration gives the map and PSNR a
run with the setting would write; the kept frames (colour and depth, never an evaluated frame) are
re-read from the capture (benchmarks/color_fit.py). A run made with the passes is measured from
its map before them (its checkpoint keeps it). Per variant: PSNR overall and over the last
quarter of the evaluated frames, Gaussians added, seconds of each pass. Writes nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from color_fit import fit_samples, restore_before_finish, run_psnr  # noqa: E402


def _copy(gmap):
    from splat_core.gaussians import GaussianMap

    return GaussianMap.from_numpy(gmap.to_numpy(), device=gmap.device, dtype=gmap.dtype)


def apply(variant: str, run, views, intrinsics, renderer, config) -> dict:
    """The passes of `variant` on a copy of run.map (run.map is replaced by it); their records."""
    from splat_core.color_fit import fit_map_colors
    from splat_core.final_holes import fill_final_holes

    run.map, out = _copy(run.map), {}
    for step in variant.split("+"):
        start = time.perf_counter()
        if step == "holes":
            out["holes"] = fill_final_holes(run.map, views, intrinsics, renderer, config)
        else:
            out["fit"] = fit_map_colors(run.map, views, intrinsics, renderer,
                                        config.mapping.final_color_fit_min_improvement,
                                        config.mapping.final_color_fit_prior)
        out[f"{step}_seconds"] = time.perf_counter() - start
    return out


def measure(path, fraction: float, opacity: float, passes: int, variants: list[str]) -> dict:
    import dataclasses

    from splat_core.refine.run_data import load_run_data, open_run_capture
    from splat_core.render import Renderer

    run = load_run_data(path)
    restore_before_finish(path, run)
    config = dataclasses.replace(run.config, mapping=dataclasses.replace(
        run.config.mapping, final_hole_fill=fraction, final_hole_fill_opacity=opacity,
        final_hole_fill_iterations=passes))
    source = open_run_capture(run)
    renderer = Renderer(near=config.near_plane)
    samples = fit_samples(run, source, keep_depth=True)
    lost = lambda k: run.records[k].get("lost")  # noqa: E731
    views = samples.views(run.w2cs, lost)
    base = run.map
    plain, frames = run_psnr(run, source, renderer)
    rows = dict(none=dict(psnr=plain, gaussians=len(base)))
    quarter = len(frames) * 3 // 4
    rows["none"]["psnr_last_quarter"] = float(np.mean(frames[quarter:]))
    for variant in variants:
        run.map = base
        record = apply(variant, run, views, samples.intrinsics, renderer, config)
        psnr, per_frame = run_psnr(run, source, renderer)
        holes = record.get("holes", {})
        rows[variant] = dict(psnr=psnr, psnr_last_quarter=float(np.mean(per_frame[quarter:])), gaussians=len(run.map),
                             added=holes.get("added"), hole_seconds=record.get("holes_seconds"),
                             fit_seconds=record.get("fit_seconds"), fit_kept=record.get("fit", {}).get("kept"),
                             held_out_ratio=record.get("fit", {}).get("held_out_ratio"))
    return dict(run=str(path), fraction=fraction, opacity=opacity, passes=passes, kept_frames=len(views),
                variants=rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+")
    from splat_core.config import load_config

    default = load_config("cpu").mapping
    ap.add_argument("--fraction", type=float, default=default.final_hole_fill,
                    help="mapping.final_hole_fill (default: the cpu preset's)")
    ap.add_argument("--opacity", type=float, default=default.final_hole_fill_opacity,
                    help="mapping.final_hole_fill_opacity")
    ap.add_argument("--passes", type=int, default=default.final_hole_fill_iterations,
                    help="mapping.final_hole_fill_iterations")
    ap.add_argument("--orders", action="store_true", help="also the colour fit before the hole fill")
    ap.add_argument("--variants", default="fit,holes+fit,holes", help="which, comma-separated")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    variants = args.variants.split(",") + (["fit+holes"] if args.orders else [])
    rows = [measure(p, args.fraction, args.opacity, args.passes, variants) for p in args.runs]
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        print(f"{r['run']} (final_hole_fill {r['fraction']}, opacity {r['opacity']}, {r['passes']} passes, "
              f"{r['kept_frames']} kept frames)")
        for name, v in r["variants"].items():
            extra = "" if name == "none" else (
                f"; added {v['added']} in {v['hole_seconds'] or 0:.1f} s, fit {'kept' if v['fit_kept'] else 'not kept'}"
                f" (ratio {v['held_out_ratio'] if v['held_out_ratio'] is None else round(v['held_out_ratio'], 3)}, "
                f"{v['fit_seconds'] or 0:.1f} s)")
            print(f"  {name:10s} PSNR {v['psnr']:.2f} dB (last quarter {v['psnr_last_quarter']:.2f}); "
                  f"{v['gaussians']} Gaussians{extra}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
