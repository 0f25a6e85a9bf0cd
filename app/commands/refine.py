"""`splatam refine`: optimise a finished run's map over all its keyframes, at the capture's resolution."""

from __future__ import annotations

import argparse
import json
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN_DIR", help="a finished run folder (map.ply, config.yaml, checkpoint/)")
    p.add_argument("--iterations", type=int, default=1000, help="optimisation steps, one keyframe each (default 1000)")
    p.add_argument("--resolution", default="capture", choices=["capture", "working"],
                   help="capture: re-read the keyframes from the capture at its resolution (default); "
                   "working: the keyframes as the run stored them")
    p.add_argument("--input", default=None, metavar="CAPTURE",
                   help="the run's capture, when the run does not record it or it has moved")
    p.add_argument("--anisotropic", action="store_true",
                   help="give each Gaussian three scales and a rotation to optimise (SLAM's map is isotropic)")
    p.add_argument("--restart", action="store_true", help="discard an interrupted refine's checkpoint")
    p.add_argument("--checkpoint-every", type=int, default=100, help="iterations between checkpoints (0: never)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def main(args) -> int:
    from tqdm import tqdm

    from splat_core.run import resolve_device
    from splat_core.refine import RefineJob, RefineSettings

    settings = RefineSettings(iterations=args.iterations, anisotropic=args.anisotropic)
    job = RefineJob(args.run, settings, resolution=args.resolution,
                    capture=args.input, restart=args.restart, device=resolve_device(args.device),
                    checkpoint_every=args.checkpoint_every)
    if not args.quiet:
        resumed = f", resuming at iteration {job.iteration}" if job.iteration else ""
        print(f"refining {job.gaussians_before:,} Gaussians over {len(job.refiner.views)} keyframes at "
              f"{job.intrinsics.width}x{job.intrinsics.height} ({args.resolution}){resumed}; held-out frames: "
              f"{len(job.run.heldout_indices) if job.source is not None else 0}", file=sys.stderr)
    bar = tqdm(total=job.total, initial=job.iteration, unit="it", disable=args.quiet, dynamic_ncols=True,
               file=sys.stderr)
    try:
        while not job.done:
            loss = job.step()
            bar.set_postfix({"loss": f"{loss:.4f}", "gaussians": len(job.refiner.map)}, refresh=False)
            bar.update(1)
    except KeyboardInterrupt:
        bar.close()
        job.save_checkpoint()
        print(f"stopped at iteration {job.iteration}; run the same command again to resume", file=sys.stderr)
        raise
    bar.close()
    section = job.finish()
    summary = {k: section[k] for k in ("iterations", "size", "psnr_gain_db", "seconds_per_iteration",
                                       "num_gaussians_after")}
    summary.update({f"{when}_{k}": section[when][k] for when in ("before", "after") for k in ("psnr", "ssim", "depth_l1_cm")})
    print(json.dumps(summary))
    return 0
