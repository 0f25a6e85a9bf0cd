"""mapping.final_refine on finished runs: the engine's end-of-run refinement (splat_core.final_refine)
applied with several pass counts to each run folder's map as it was before the end-of-run passes,
and the PSNR of record (every eval_every-th frame at the estimated pose, every pixel, as
metrics.json's psnr) and of the held-out frames (the frames kept midway between evaluated ones,
at half resolution: what decides whether the refinement is kept) before and after.

    python benchmarks/final_refine.py RUN [RUN ...] [--passes 0.5,1,2,4] [--json]

The refinement alone: not followed by the hole fill and colour fit a run does after it (a run's
metrics.json has the whole end). Moves no pose, so it applies to any finished run folder.
Writes nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from color_fit import fit_samples, restore_before_finish, run_psnr  # noqa: E402


def measure(path, passes: list[float]) -> dict:
    from splat_core.final_refine import refine_final_map
    from splat_core.gaussians import GaussianMap
    from splat_core.refine.run_data import load_run_data, open_run_capture
    from splat_core.render import Renderer

    run = load_run_data(path)
    restore_before_finish(path, run)
    source = open_run_capture(run)
    renderer = Renderer(near=run.config.near_plane)
    before, _ = run_psnr(run, source, renderer)
    samples = fit_samples(run, source)
    held_out = samples.views(run.w2cs, lambda k: run.records[k].get("lost"))
    view_of = lambda kf: run.view(kf.color, kf.depth, run.w2cs[kf.frame_index])  # noqa: E731
    start_map = run.map.to_numpy()
    rows = []
    for p in passes:
        run.map = GaussianMap.from_numpy(start_map, dtype=run.map.dtype)
        config = dataclasses.replace(run.config, mapping=dataclasses.replace(run.config.mapping, final_refine=p))
        record = refine_final_map(run.map, run.keyframes, view_of, run.intrinsics, held_out, samples.intrinsics,
                                  renderer, config)
        after, _ = run_psnr(run, source, renderer)
        rows.append(dict(passes=p, psnr_after=after, **record))
    return dict(run=str(path), psnr_before=before, frames=len(run.records), rows=rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--passes", default="0.5,1,2,4", help="pass counts to try, comma-separated (default: %(default)s)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    results = [measure(p, [float(x) for x in args.passes.split(",")]) for p in args.runs]
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    for r in results:
        print(f"{r['run']} ({r['frames']} frames): PSNR before {r['psnr_before']:.2f} dB")
        for row in r["rows"]:
            print(f"  {row['passes']:g} pass{'' if row['passes'] == 1 else 'es'} ({row['steps']} steps over {row['keyframes']} keyframes, "
                  f"{row['seconds']:.1f} s): PSNR {row['psnr_after']:.2f} dB; held-out ({row['held_out_frames']} frames) "
                  f"{row['held_out_psnr_before']:.2f} -> {row['held_out_psnr_after']:.2f} dB: "
                  f"{'kept' if row['kept'] else 'put back'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
