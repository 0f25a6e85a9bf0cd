"""`splatam run`: SLAM headless on a capture, with a progress bar, writing a run folder."""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import nullcontext
from pathlib import Path

from app.commands.capture import add_idle_timeout, ctrl_c_ends
from splat_core.errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--input", required=True, help="capture folder or .r3d/.zip file ('synthetic' for the demo scene, "
                   "nerfcapture:// for the NeRFCapture iPhone app's live stream, recorded to OUT/capture)")
    p.add_argument("--out", required=True, help="run folder to write")
    p.add_argument("--format", default=None, help="capture format (default: detected)")
    p.add_argument("--config", default=None, help="preset name(s) joined by '+' or a YAML file "
                   "(default: cpu on a CPU, splatam on a GPU)")
    p.add_argument("--max-frames", type=int, default=None, help="process at most N frames")
    p.add_argument("--stride", type=int, default=1, help="use every K-th frame")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"],
                   help="sequential: track, then map, frame by frame (deterministic; the default); live: "
                   "tracking runs ahead while a mapper thread maps (faster, not bitwise reproducible)")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_idle_timeout(p)


def default_config_name(device) -> str:
    return "splatam" if device.type == "cuda" else "cpu"


def main(args) -> int:
    from splat_core.config import load_config
    from splat_core.pipeline import open_input, resolve_device

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out must be a folder")
    if not args.resume and (out / "checkpoint").exists():
        raise InputError(f"{out}: already holds a run; pass --resume to continue it or choose another --out")
    device = resolve_device(args.device)
    config = load_config(args.config or default_config_name(device))
    live = args.input.startswith("nerfcapture://")
    options = dict(capture_dir=out / "capture", idle_timeout=args.idle_timeout) if live else {}
    source = open_input(None if args.input == "synthetic" else args.input, format=args.format, **options)
    if live and not args.quiet:
        from splat_core.io.nerfcapture_stream import waiting_message
        print(waiting_message(), file=sys.stderr, flush=True)
    try:
        with ctrl_c_ends(source, "finishing this frame and writing the run") if live else nullcontext():
            return _run(args, source, config, out)
    finally:
        source.close()


def _run(args, source, config, out) -> int:
    from tqdm import tqdm

    from splat_core.pipeline import Pipeline, config_summary

    pipe = Pipeline(source, config, out, device=args.device, max_frames=args.max_frames,
                    stride=args.stride, resume=args.resume, engine=args.engine)
    if not args.quiet:
        print(f"{source.describe()}\nconfig {config_summary(config)}; {args.engine} engine; device {pipe.device}; "
              f"{pipe.total or 'live'} frames at {pipe.intrinsics.width}x{pipe.intrinsics.height} -> {out}",
              file=sys.stderr)
        for note in pipe.notes:
            print(f"note: {note}", file=sys.stderr)
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
        if r.lost or pipe.lost:
            post["lost"] = f"{len(pipe.lost)}" + (" (relocalising)" if r.lost else "")
        bar.set_postfix(post, refresh=False)
        bar.update(pipe.cursor - bar.n)
    bar.close()
    source.close()
    if pipe.streaming and not args.quiet:
        s = source.stats()
        print(f"stream ended ({s['stream_end']}): {s['received']} frames received and recorded in {s['capture']}, "
              f"{s['dropped']} not processed, {s['rejected']} rejected", file=sys.stderr)
    metrics = pipe.finish()
    summary = {k: metrics[k] for k in ("frames", "frames_skipped", "frames_lost", "ate_rmse_cm", "psnr", "depth_l1_cm",
                                       "wall_seconds_per_frame", "num_gaussians", "received", "dropped") if k in metrics}
    print(json.dumps(summary))
    return 0
