"""mapping.final_color_fit on finished runs: the engine's end-of-run colour fit (splat_core.color_fit)
applied to each run folder's map, and the PSNR of record (every eval_every-th frame at the estimated
pose, every pixel, as metrics.json's psnr) before and after.

    python benchmarks/color_fit.py RUN [RUN ...] [--json] [--min-improvement F | --always]

The held-out test (mapping.final_color_fit_min_improvement; the run's setting unless
--min-improvement gives another) decides whether the fit is applied; --always applies it
regardless; --always --prior 0 is the fit before both (least squares, always applied).

The fit runs after a run's last frame (SplaTAM.finish) over the frames kept for it, none of them
an evaluated frame (color_fit.FitSamples: re-read here from the capture) and moves no pose (tests/core/test_color_fit.py: a run with the
setting has the plain run's trajectory, and its colours are the plain map's under the reported
gain and offset), so applying it to a run folder of the same configuration without the setting
gives the map and PSNR a run with it would have written. A run made with the setting is measured
from its colours before the fit (its checkpoint keeps them; a run from before that: metrics.json's
fit undone; with the hole fill, its Gaussians removed too). Writes nothing.
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


def run_psnr(run, source, renderer) -> tuple[float, list[float]]:
    import torch

    from splat_core import metrics as M
    from splat_core.refine.run_data import frame_views

    picks = [k for k in range(len(run.records)) if M.is_evaluated(k, run.config.eval_every)
             and not run.records[k].get("lost")]
    out = []
    with torch.no_grad():
        for k in picks:
            view = frame_views(run, source, run.intrinsics, [k])[0]
            rendered = renderer.render_visible(run.map.tensors(detach=True), run.intrinsics, view.w2c)
            out.append(float(M.psnr(rendered.color, view.color)))
    return float(np.mean(out)), out


def fit_samples(run, source, keep_depth: bool = False):
    """The frames SplaTAM.track keeps for the fit (color_fit.FitSamples; with their depth for the
    hole fill: `keep_depth`), re-read from the capture at the working resolution."""
    from splat_core.color_fit import FitSamples, is_fit_frame
    from splat_core.refine.run_data import frame_views

    samples = FitSamples(run.intrinsics, run.config.eval_every, keep_depth=keep_depth)
    for k in range(len(run.records)):
        if is_fit_frame(k, run.config.eval_every):
            view = frame_views(run, source, run.intrinsics, [k])[0]
            samples.offer(k, view.color.cpu().numpy(), view.depth.cpu().numpy())
    return samples


def restore_before_finish(path, run) -> bool:
    """A run made with the end-of-run passes: its map put back as it was before them (the checkpoint
    keeps that map, or, before the refinement, the Gaussians' count and colours; a run from before
    those: metrics.json's fit undone). False: a run without them (its map is as it was)."""
    import torch

    from splat_core.gaussians import GaussianMap
    from splat_core.run.run_folder import RunFolder
    from splat_core.slam_checkpoint import map_before_finish

    folder = RunFolder(path)
    before = map_before_finish(folder.load_checkpoint().arrays)
    if before is not None:
        run.map = GaussianMap.from_numpy(before, dtype=run.map.dtype)
        return True
    record = (folder.read_metrics() or {}).get("final_color_fit")
    if record is None:
        return False
    colors = run.map.params["colors"]
    colors.data.copy_((colors.detach() - torch.tensor(record["offset"], dtype=colors.dtype))
                      / torch.tensor(record["gain"], dtype=colors.dtype))
    return True


def measure(path, min_improvement="run", prior=None) -> dict:
    from splat_core.color_fit import fit_map_colors
    from splat_core.refine.run_data import load_run_data, open_run_capture
    from splat_core.render import Renderer

    run = load_run_data(path)
    restore_before_finish(path, run)
    source = open_run_capture(run)
    renderer = Renderer(near=run.config.near_plane)
    before, _ = run_psnr(run, source, renderer)
    start = time.perf_counter()
    samples = fit_samples(run, source)
    lost = lambda k: run.records[k].get("lost")  # noqa: E731
    if min_improvement == "run":
        min_improvement = run.config.mapping.final_color_fit_min_improvement
    prior = run.config.mapping.final_color_fit_prior if prior is None else prior
    record = fit_map_colors(run.map, samples.views(run.w2cs, lost), samples.intrinsics, renderer, min_improvement,
                            prior)
    seconds = time.perf_counter() - start
    after, _ = run_psnr(run, source, renderer)
    return dict(run=str(path), psnr_before=before, psnr_after=after, fit_seconds=seconds, **record)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--min-improvement", type=float, default=None,
                    help="the held-out test's threshold (default: the run's mapping.final_color_fit_min_improvement)")
    ap.add_argument("--always", action="store_true", help="apply the fit without the held-out test")
    ap.add_argument("--prior", type=float, default=None,
                    help="the fit's pull towards identity (default: the run's mapping.final_color_fit_prior)")
    args = ap.parse_args(argv)
    threshold = None if args.always else "run" if args.min_improvement is None else args.min_improvement
    rows = [measure(p, threshold, args.prior) for p in args.runs]
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        print(f"{r['run']}: PSNR {r['psnr_before']:.2f} -> {r['psnr_after']:.2f} dB; gain "
              f"{np.round(r['gain'], 3).tolist()} offset {np.round(r['offset'], 3).tolist()} over "
              f"{r['views']} frames kept for it, none evaluated ({r['fit_seconds']:.1f} s, reading them included); "
              f"held-out error ratio {r['held_out_ratio']:.3f}: {'kept' if r['kept'] else 'not kept'} "
              f"(fitted gain {np.round(r['fitted_gain'], 3).tolist()} offset {np.round(r['fitted_offset'], 3).tolist()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
