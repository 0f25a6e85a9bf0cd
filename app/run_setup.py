"""One run set-up for `splatam run` and `splatam-viewer`: settings layers, the input, the Pipeline.

    run = setup_run("capture/", out=Path("runs/a"), config="cpu", engine="sequential")
    pipe = run.start()          # a live stream: waits for its first frame (callers handle Ctrl-C)
    for line in run.lines(): print(line)

`setup_run` is quick: it finds the capture's format, builds the config (the budget over that
format's layer, then --resolution / --min-confidence) and opens the source. `start` builds the
Pipeline, which for nerfcapture:// waits for the first frame.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from splat_core.config import describe_default_presets
from splat_core.errors import InputError

from .console_commands import command

STREAM = "nerfcapture://"


def add_idle_timeout(p: argparse.ArgumentParser) -> None:
    p.add_argument("--idle-timeout", type=float, default=30.0, metavar="S",
                   help="nerfcapture://: end after S seconds without a frame (default 30; 0 = never)")


@contextmanager
def ctrl_c_ends(stream, what: str):
    """The first Ctrl-C ends the stream (the command then finishes normally); a second one aborts."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum, frame):
        signal.signal(signal.SIGINT, previous)
        print(f"\nCtrl-C: ending the stream, {what} (Ctrl-C again to abort)", file=sys.stderr, flush=True)
        stream.stop()
    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def add_run_arguments(p: argparse.ArgumentParser, engine_default: str) -> None:
    """The options `splatam run` and `splatam-viewer` share."""
    p.add_argument("--format", default=None, help="capture format (default: detected)")
    p.add_argument("--config", default=None, help="budget preset (cpu, cpu_dense, gpu, splatam, splatam_s), paper preset "
                   f"(splatam_tum, ...), names joined by '+' or a YAML file (default: {describe_default_presets()}); "
                   "the detected format's layer applies by itself; every key: docs/settings.md")
    p.add_argument("--resolution", default=None, metavar="WxH|L|native",
                   help="working resolution: WxH pixels in the capture's aspect ratio (portrait stays portrait), "
                   "a long side L, or native (default: the preset's)")
    p.add_argument("--min-confidence", type=int, default=None, choices=(0, 1, 2),
                   help="Record3D / Stray Scanner: keep LiDAR depth with confidence >= N (0 low, 1 medium, 2 high; "
                   "default 2)")
    p.add_argument("--max-frames", type=int, default=None, help="process at most N frames")
    p.add_argument("--stride", type=int, default=1, help="use every K-th frame")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    other = "sequential" if engine_default == "live" else "live"
    p.add_argument("--engine", default=engine_default, choices=[engine_default, other],
                   help="sequential: track, then map, frame by frame (deterministic); live: tracking runs ahead "
                   f"while a mapper thread maps (faster, not bitwise reproducible); default {engine_default}")
    p.add_argument("--realtime", type=positive_fps, nargs="?", const=0.0, default=None, metavar="FPS",
                   help="play a capture back at its own frame rate (its timestamps; 30 frames/s without usable "
                   "ones), or at FPS, handing SLAM the newest frame and dropping the rest, as a live stream does")
    p.add_argument("--loop-closure", default=None, choices=["on", "off"],
                   help="close loops online (docs/loop-closure.md; default: the preset's: on in cpu and gpu, off in the paper presets)")


def positive_fps(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text}: expected a positive frame rate")
    return value


def input_format(input_path, format: str | None) -> str:
    """The format whose layer applies: the synthetic scene, the stream, or the capture's."""
    if input_path is None:
        return "synthetic"
    if str(input_path).startswith(STREAM):
        return "nerfcapture"
    if format:
        return format.lower()
    from splat_core.io.detect import detect_format
    return detect_format(Path(input_path).expanduser())


def config_summary(config) -> str:
    from splat_core.run.resolution import describe_resolution

    return (f"{config.name}: track {config.tracking.iterations} it, map {config.mapping.iterations} it, "
            f"window {config.mapping.window_size}, resolution {describe_resolution(config.resolution)}")


def load_run_config(spec: str | None, format_name: str, device, resolution: str | None = None,
                    min_confidence: int | None = None, loop_closure: str | None = None, engine: str = "sequential"):
    """The budget (`spec`, or the default preset of `device` and `engine`) over `format_name`'s layer,
    then the CLI's --resolution and --min-confidence."""
    from splat_core.config import default_preset, load_config
    from splat_core.run.resolution import parse_resolution

    overrides = {}
    if resolution is not None:
        overrides["resolution"] = parse_resolution(resolution)
    if min_confidence is not None:
        overrides["min_confidence"] = min_confidence
    if loop_closure is not None:
        overrides["loop_closure"] = {"enabled": loop_closure == "on"}
    return load_config(spec or default_preset(device, engine), overrides, format=format_name)


@dataclass
class RunSetup:
    source: object                  # the FrameSource
    config: object                  # the resolved Config (both layers)
    out: Path | None
    device: str                     # cpu or cuda
    engine: str
    max_frames: int | None = None
    stride: int = 1
    resume: bool = False
    pipeline: object = None
    realtime: bool = False          # a capture played back in real time (a LiveSource, but no stream)

    @property
    def live(self) -> bool:
        return bool(getattr(self.source, "live", False))

    def waiting_message(self) -> str:
        from splat_core.io.nerfcapture_stream import waiting_message
        return waiting_message()

    def start(self):
        """The Pipeline (for a live stream this waits for the first frame)."""
        from splat_core.run import Pipeline

        self.pipeline = Pipeline(self.source, self.config, self.out, device=self.device, max_frames=self.max_frames,
                                 stride=self.stride, resume=self.resume, engine=self.engine)
        return self.pipeline

    def lines(self) -> list[str]:
        """What the commands print before the run: the input, the settings layers, the run."""
        from splat_core.config import describe_layers
        from splat_core.run.resolution import source_sizes

        pipe = self.pipeline
        (cw, ch), (dw, dh) = source_sizes(self.source)
        grid = f"colour {cw}x{ch}" + (f", depth {dw}x{dh}" if (dw, dh) != (cw, ch) else "")
        return [self.source.describe(), f"settings: {describe_layers(self.config)}",
                f"config {config_summary(self.config)}; {self.engine} engine; device {pipe.device}; "
                f"{pipe.total or 'live'} frames at {pipe.intrinsics.width}x{pipe.intrinsics.height} ({grid}) "
                f"-> {self.out}"] + [f"note: {n}" for n in pipe.notes]


def setup_run(input_path, *, out: Path | None, format: str | None = None, config: str | None = None,
              resolution: str | None = None, min_confidence: int | None = None, device: str = "auto",
              engine: str = "sequential", max_frames: int | None = None, stride: int = 1, resume: bool = False,
              idle_timeout: float | None = None, loop_closure: str | None = None,
              realtime: float | None = None) -> RunSetup:
    """Settings and input of a run (`input_path` None or "synthetic": the synthetic scene; nerfcapture://: the
    live stream, recorded to OUT/capture and ended after `idle_timeout` seconds without a frame).
    `realtime` (not None): play the capture back in real time, at that frame rate (0: its own)."""
    from splat_core.run import open_input, resolve_device
    from splat_core.run.run_folder import RunFolder

    if out is not None:
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise InputError(f"{out}: --out must be a folder")
        # a folder with a checkpoint or a finished run's metrics is taken; one killed before its
        # first checkpoint (only checkpoint/keyframes.bin) holds nothing worth keeping
        folder = RunFolder(out)
        if not resume and (folder.has_checkpoint() or folder.is_finished()):
            raise InputError(f"{out}: already holds a run; choose another --out "
                             f"(or continue it: {command('splatam')} run --resume)")
    if input_path == "synthetic":
        input_path = None
    if realtime is not None:
        if str(input_path).startswith(STREAM):
            raise InputError("--realtime plays a capture back; nerfcapture:// already arrives in real time")
        if resume or stride != 1:
            raise InputError("--realtime does not go with --resume or --stride (playback drops frames by itself, "
                             "and which ones depends on timing)")
    dev = resolve_device(device)
    format_name = input_format(input_path, format)
    cfg = load_run_config(config, format_name, dev, resolution, min_confidence, loop_closure, engine)
    if input_path is None or str(input_path).startswith(STREAM):
        if min_confidence is not None:
            raise InputError(f"--min-confidence: {input_path or 'the synthetic scene'} has no LiDAR confidence maps "
                             "(it applies to Record3D and Stray Scanner captures)")
        options = dict(capture_dir=RunFolder(out).capture_dir, idle_timeout=idle_timeout) if input_path else {}
        source = open_input(input_path, **options)
    else:
        options = {} if cfg.min_confidence is None else dict(min_confidence=cfg.min_confidence)
        source = open_input(input_path, format=format, **options)
    if realtime is not None:
        from splat_core.io.playback import RealtimePlayback

        source = RealtimePlayback(source, realtime or None, max_frames=max_frames)
        max_frames = None           # the playback ends with the capture's first max_frames frames
    return RunSetup(source, cfg, out, dev.type, engine, max_frames, stride, resume, realtime=realtime is not None)


def setup_from_args(args, *, out: Path | None, idle_timeout: float | None = None, resume: bool = False) -> RunSetup:
    """`setup_run` with the options of add_run_arguments."""
    return setup_run(args.input, out=out, format=args.format, config=args.config, resolution=args.resolution,
                     min_confidence=args.min_confidence, device=args.device, engine=args.engine,
                     max_frames=args.max_frames, stride=args.stride, resume=resume, idle_timeout=idle_timeout,
                     loop_closure=getattr(args, "loop_closure", None), realtime=getattr(args, "realtime", None))
