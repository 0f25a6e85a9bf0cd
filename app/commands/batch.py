"""`splatam batch`: run many captures, each an ordinary `splatam run` in its own process, on a
local Dask cluster on 127.0.0.1 or on a running cluster (--scheduler ADDRESS); resumable, with
DIR/summary.{csv,json,md} and DIR/index.html (docs/batch.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from splat_core.errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("captures", nargs="*", metavar="CAPTURE", help="capture folders or .r3d/.zip files")
    p.add_argument("--list", default=None, metavar="FILE", help="a file with one capture path per line ('#' comments; "
                   "relative paths from the file's folder)")
    p.add_argument("--out", required=True, metavar="DIR", help="batch folder: DIR/<capture name>/ run folders, "
                   "DIR/summary.csv|json|md, DIR/index.html")
    p.add_argument("--config", default=None, help="as splatam run --config (default: as splatam run: cpu on a CPU, gpu on a GPU)")
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"], help="as splatam run (default sequential)")
    p.add_argument("--resolution", default=None, metavar="WxH|L|native", help="as splatam run --resolution")
    p.add_argument("--max-frames", type=int, default=None, help="process at most N frames of each capture")
    p.add_argument("--stride", type=int, default=1, help="use every K-th frame")
    p.add_argument("--format", default=None, help="capture format of every capture (default: detected per capture)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="auto: GPUs when the local machine has them (with --scheduler: the CPU unless --gpus-per-run)")
    p.add_argument("--refine", type=int, default=0, metavar="N", help="then splatam refine --iterations N")
    p.add_argument("--export", default="", metavar="FMT,...", help="then splatam export --format FMT for each "
                   "(ply, splat, spz, compressed-ply, html, and any format splatam export accepts, e.g. colmap, "
                   "nerfstudio, mesh) into DIR/<name>/export/")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running Dask scheduler "
                   "(tcp://host:8786); default: a local cluster on 127.0.0.1")
    p.add_argument("--workers", type=int, default=None, help="local cluster: runs at once (default: what the "
                   "machine's cores and memory afford; one per GPU on a GPU machine)")
    p.add_argument("--cores-per-run", type=int, default=None, help="CPU threads of one run, asked of a worker as "
                   "its CPU resource (default: the cores divided among the workers)")
    p.add_argument("--gpus-per-run", type=int, default=None, help="GPUs one run asks for (resource GPU; default 1 "
                   "on a GPU run)")
    p.add_argument("--retry-failed", action="store_true", help="rerun captures that failed in an earlier batch")
    p.add_argument("--quiet", action="store_true", help="no progress bar or per-capture lines")


def main(args) -> int:
    from app.batch.cluster import require_dask
    from app.batch.captures import list_captures
    from app.batch.driver import Batch
    from app.batch.task import RunOptions

    require_dask()
    captures = list_captures(args.captures, args.list)
    out = Path(args.out).expanduser()
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out must be a folder")
    for flag, value in (("--max-frames", args.max_frames), ("--stride", args.stride)):
        if value is not None and value < 1:
            raise InputError(f"{flag} {value}: expected a positive integer")
    if args.refine < 0:
        raise InputError(f"--refine {args.refine}: expected a number of iterations >= 0")
    exports = tuple(dict.fromkeys(f.strip().lower() for f in args.export.split(",") if f.strip()))
    from app.batch.state import HANDOFF_OUTPUTS
    from app.exports import FORMATS
    known = tuple(FORMATS) + tuple(f for f in HANDOFF_OUTPUTS if f not in FORMATS)
    for fmt in exports:
        if fmt not in known:
            raise InputError(f"--export {fmt}: unknown format; expected some of {', '.join(known)}")
    if args.config and Path(args.config).suffix in (".yaml", ".yml"):
        if not Path(args.config).is_file():
            raise InputError(f"{args.config}: --config: no such file")
        args.config = str(Path(args.config).resolve())    # workers may run elsewhere
    opts = RunOptions(config=args.config, engine=args.engine, resolution=args.resolution, max_frames=args.max_frames,
                      stride=args.stride, device=args.device, format=args.format, refine=args.refine, exports=exports,
                      cores=args.cores_per_run)
    layout_args = dict(device=args.device, cores_per_run=args.cores_per_run, gpus_per_run=args.gpus_per_run)
    if args.scheduler is None:
        layout_args["workers"] = args.workers
    elif args.workers is not None:
        raise InputError("--workers applies to the local cluster; with --scheduler, the cluster has its own workers")
    return Batch(captures, out, opts, retry_failed=args.retry_failed, quiet=args.quiet).run(args.scheduler, layout_args)
