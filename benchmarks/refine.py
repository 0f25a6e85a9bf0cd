"""Refinement on finished run folders: held-out PSNR / SSIM / depth L1 before and after, time; prints JSON.

    python benchmarks/refine.py RUN_DIR[=CAPTURE] ... [--iterations 1000] [--resolution capture|working]
                                [--lrs '{"colors": 0.01}'] [--density '{"grad_threshold": 0.0002}']
                                [--anisotropic] [--densify-until N]

Each run is refined in place (map_refined.ply and metrics.json's refine section, as `splatam
refine` writes them; an interrupted refine's checkpoint is discarded first). `=CAPTURE` names the
capture of a run that does not record it. --lrs and --density override RefineSettings' Adam
learning rates (default: RefineSettings', the run's mapping rates with REFINE_LRS over them) and
density control; --anisotropic and --densify-until set those RefineSettings fields.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

from splat_core.refine import RefineJob, RefineSettings  # noqa: E402
from splat_core.refine.density import DensitySettings  # noqa: E402


def refine_one(run: str, settings: RefineSettings, resolution: str, device: str) -> dict:
    run_dir, _, capture = run.partition("=")
    start = time.perf_counter()
    job = RefineJob(run_dir, settings, resolution=resolution, capture=capture or None, restart=True,
                    device=device, checkpoint_every=0)
    while not job.done:
        job.step()
    section = job.finish()
    keep = ("size", "iterations", "keyframes", "psnr_gain_db", "seconds", "seconds_per_iteration",
            "num_gaussians_before", "num_gaussians_after", "before", "after")
    return dict(run=run_dir, total_seconds=time.perf_counter() - start, **{k: section[k] for k in keep},
                densification=[{k: d[k] for k in ("iteration", "cloned", "split", "pruned", "after")}
                               for d in section["densification"]])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR[=CAPTURE]")
    p.add_argument("--iterations", type=int, default=1000)
    p.add_argument("--resolution", default="capture", choices=["capture", "working"])
    p.add_argument("--lrs", type=json.loads, default=None, help="JSON: learning rates to override")
    p.add_argument("--density", type=json.loads, default={}, help="JSON: DensitySettings fields to override")
    p.add_argument("--anisotropic", action="store_true", help="RefineSettings.anisotropic")
    p.add_argument("--densify-until", type=int, default=None, help="RefineSettings.densify_until")
    p.add_argument("--device", default="cpu")
    args = p.parse_args()
    results = []
    for run in args.runs:
        base = RefineSettings(iterations=args.iterations, density=DensitySettings(**args.density),
                              anisotropic=args.anisotropic, densify_until=args.densify_until)
        if args.lrs:
            from splat_core.refine.run_data import load_run_data
            mapping = load_run_data(run.partition("=")[0]).config.mapping
            base = dataclasses.replace(base, lrs={**base.resolved(mapping).lrs, **args.lrs})
        results.append(refine_one(run, base, args.resolution, args.device))
    print(json.dumps(dict(machine=machine(), resolution=args.resolution, iterations=args.iterations,
                          lrs=args.lrs, density=args.density, runs=results), indent=1))


if __name__ == "__main__":
    main()
