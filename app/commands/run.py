"""`splatam run`: SLAM headless on a capture, with a progress bar, writing a run folder."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from contextlib import nullcontext
from pathlib import Path

from app.console_commands import command
from app.run_setup import add_idle_timeout, add_run_arguments, ctrl_c_ends, setup_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--input", required=True, help="capture folder or .r3d/.zip file ('synthetic' for the demo scene, "
                   "nerfcapture:// for the NeRFCapture iPhone app's live stream, recorded to OUT/capture)")
    p.add_argument("--out", required=True, help="run folder to write")
    add_run_arguments(p, engine_default="sequential")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_idle_timeout(p)


def main(args) -> int:
    run = setup_from_args(args, out=Path(args.out), idle_timeout=args.idle_timeout, resume=args.resume)
    if run.live and not run.realtime and not args.quiet:
        print(run.waiting_message(), file=sys.stderr, flush=True)
    try:
        with ctrl_c_ends(run.source, "finishing this frame and writing the run") if run.live else nullcontext():
            return _run(args, run)
    finally:
        run.source.close()


def _run(args, run) -> int:
    from tqdm import tqdm

    pipe, source = run.start(), run.source
    if not args.quiet:
        print("\n".join(run.lines()), file=sys.stderr)
    bar = tqdm(total=pipe.total, initial=pipe.cursor, unit="frame", disable=args.quiet,
               dynamic_ncols=True, file=sys.stderr)
    pipe.warn = lambda message: bar.write(f"warning: {message}", file=sys.stderr)   # above the bar
    while (r := pipe.step()) is not None:
        ate = pipe.ate_cm() if r.index % 5 == 0 or r.index + 1 == pipe.total else None
        post = {"s/frame": f"{pipe.records[-1]['wall_seconds']:.2f}", "gaussians": r.num_gaussians}
        if ate is not None:
            post["ATE cm"] = f"{ate:.2f}"
        if pipe.streaming:
            post["dropped"] = source.dropped
        if pipe.skipped:
            post["skipped"] = len(pipe.skipped)
        for loop in r.loops:
            if not args.quiet:
                bar.write(f"loop closed: keyframe {loop.keyframes[0]} <-> {loop.keyframes[1]} (frames "
                          f"{loop.frames[0]} <-> {loop.frames[1]}), correction {loop.correction_cm:.1f} cm",
                          file=sys.stderr)
        if (loops := pipe.loops()) is not None:
            post["loops"] = len(loops)
        if r.lost or pipe.lost:
            post["lost"] = f"{len(pipe.lost)}" + (" (relocalising)" if r.lost else "")
        bar.set_postfix(post, refresh=False)
        bar.update(pipe.cursor - bar.n)
    bar.close()
    source.close()
    if run.realtime and not args.quiet:
        print(source.end_message(), file=sys.stderr)
    elif pipe.streaming and not args.quiet:
        s = source.stats()
        print(f"stream ended ({s['stream_end']}): {s['received']} frames received and recorded in {s['capture']}, "
              f"{s['dropped']} not processed, {s['rejected']} rejected", file=sys.stderr)
    metrics = pipe.finish()
    summary = {k: metrics[k] for k in ("frames", "frames_skipped", "frames_lost", "loops_closed", "ate_rmse_cm", "psnr", "depth_l1_cm",
                                       "wall_seconds_per_frame", "num_gaussians", "received", "dropped", "processed_share")
               if k in metrics}
    print(json.dumps(summary))
    if not args.quiet:
        print(f"wrote {run.out}: view it with {command('splatam-viewer')} --open {shlex.quote(str(run.out))}",
              file=sys.stderr)
    return 0
