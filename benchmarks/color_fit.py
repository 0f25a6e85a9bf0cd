"""mapping.final_color_fit on finished runs: the engine's end-of-run colour fit (splat_core.color_fit)
applied to each run folder's map, and the PSNR of record (every eval_every-th frame at the estimated
pose, every pixel, as metrics.json's psnr) before and after.

    python benchmarks/color_fit.py RUN [RUN ...] [--json]

The fit runs after a run's last frame (SplaTAM.finish) over the frames kept for it, none of them
an evaluated frame (color_fit.FitSamples: re-read here from the capture) and moves no pose (tests/core/test_color_fit.py: a run with the
setting has the plain run's trajectory, and its colours are the plain map's under the reported
gain and offset), so applying it to a run folder of the same configuration without the setting
gives the map and PSNR a run with it would have written. A run made with the setting is measured
from its colours before the fit (its checkpoint keeps them; a run from before that: metrics.json's
fit undone). Writes nothing.
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


def fit_samples(run, source):
    """The frames SplaTAM.track keeps for the fit (color_fit.FitSamples), re-read from the capture
    at the working resolution."""
    from splat_core.color_fit import FitSamples, is_fit_frame
    from splat_core.refine.run_data import frame_views

    samples = FitSamples(run.intrinsics, run.config.eval_every)
    for k in range(len(run.records)):
        if is_fit_frame(k, run.config.eval_every):
            samples.offer(k, frame_views(run, source, run.intrinsics, [k])[0].color.cpu().numpy())
    return samples


def colors_before_fit(path, run):
    """A run made with the setting: its map's colours before the fit (the checkpoint keeps them;
    a run from before it did: the fit of metrics.json undone). None: a run without it."""
    import torch

    from splat_core.run.run_folder import RunFolder

    folder = RunFolder(path)
    before = folder.load_checkpoint().arrays.get("fit_colors_before")
    if before is not None:
        return torch.as_tensor(before)
    record = (folder.read_metrics() or {}).get("final_color_fit")
    if record is None:
        return None
    colors = run.map.params["colors"].detach()
    return (colors - torch.tensor(record["offset"], dtype=colors.dtype)) / torch.tensor(record["gain"], dtype=colors.dtype)


def measure(path) -> dict:
    from splat_core.color_fit import fit_map_colors
    from splat_core.refine.run_data import load_run_data, open_run_capture
    from splat_core.render import Renderer

    run = load_run_data(path)
    before_fit = colors_before_fit(path, run)
    if before_fit is not None:
        run.map.params["colors"].data.copy_(before_fit)
    source = open_run_capture(run)
    renderer = Renderer(near=run.config.near_plane)
    before, _ = run_psnr(run, source, renderer)
    start = time.perf_counter()
    samples = fit_samples(run, source)
    lost = lambda k: run.records[k].get("lost")  # noqa: E731
    record = fit_map_colors(run.map, samples.views(run.w2cs, lost), samples.intrinsics, renderer)
    seconds = time.perf_counter() - start
    after, _ = run_psnr(run, source, renderer)
    return dict(run=str(path), psnr_before=before, psnr_after=after, fit_seconds=seconds, **record)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [measure(p) for p in args.runs]
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        print(f"{r['run']}: PSNR {r['psnr_before']:.2f} -> {r['psnr_after']:.2f} dB; gain "
              f"{np.round(r['gain'], 3).tolist()} offset {np.round(r['offset'], 3).tolist()} over "
              f"{r['views']} frames kept for it, none evaluated ({r['fit_seconds']:.1f} s, reading them included)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
