"""`splatam capture nerfcapture --out DIR [--frames N]`: record the NeRFCapture app's live stream
as a capture folder in SplaTAM's layout, which `--input DIR` reads back.

Ends after N frames, after --idle-timeout seconds without a frame, or on Ctrl-C; what arrived is
kept either way (transforms.json is rewritten atomically after every frame).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from splat_core.errors import InputError

from app.console_commands import command
from app.run_setup import add_idle_timeout, ctrl_c_ends


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", choices=["nerfcapture"], help="the stream to record: the NeRFCapture iPhone app (DDS)")
    p.add_argument("--out", required=True, help="capture folder to create (must be new or empty)")
    p.add_argument("--frames", type=int, default=None, help="stop after N frames (default: Ctrl-C or idle)")
    add_idle_timeout(p)
    p.add_argument("--quiet", action="store_true", help="no progress line")


def main(args) -> int:
    from tqdm import tqdm

    from splat_core.io.nerfcapture_stream import NeRFCaptureStream, waiting_message

    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames {args.frames}: expected a positive number")
    out = Path(args.out)
    stream = NeRFCaptureStream(out, idle_timeout=args.idle_timeout, max_frames=args.frames)
    if not args.quiet:
        print(waiting_message(), file=sys.stderr, flush=True)
    bar = tqdm(total=args.frames, unit="frame", desc=f"recording to {out}", disable=args.quiet,
               dynamic_ncols=True, file=sys.stderr)
    try:
        with ctrl_c_ends(stream, "keeping the frames received so far"):
            while not stream.wait_ended(0.25):
                bar.update(len(stream) - bar.n)
                if stream.rejected:
                    bar.set_postfix(rejected=stream.rejected, refresh=False)
    finally:
        stream.close()
        bar.update(len(stream) - bar.n)
        bar.close()
    if stream.error is not None:
        raise InputError(f"{out}: recording stopped after {len(stream)} frames: {stream.error}")
    if len(stream) == 0:
        raise InputError(stream.no_frame_message())
    note = f"; {stream.rejected} rejected, last: {stream.last_rejection}" if stream.rejected else ""
    print(f"{len(stream)} frames recorded in {out} ({stream.end_reason}{note}); "
          f"run SLAM on it with: {command('splatam')} run --input {shlex.quote(str(out))} --out RUN_DIR")
    return 0
