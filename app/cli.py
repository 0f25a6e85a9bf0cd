"""Entry points: `splatam` (headless subcommands) and `splatam-viewer` (the web viewer).

Each subcommand lives in `app/commands/<name>.py` with `add_arguments(parser)` and
`main(args) -> int`; heavy imports happen inside `main` so `--help` stays fast. User errors
(`InputError`) print one line and exit 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Torch and Numba each bring an OpenMP runtime; busy-waiting threads of one slow the other.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from splat_core.errors import InputError

SUBCOMMANDS = {
    "run": ("app.commands.run", "run SLAM headless on a capture and write a run folder"),
    "capture": ("app.commands.capture", "record the NeRFCapture iPhone app's live stream as a capture folder"),
    "info": ("app.commands.info", "describe a capture: format, frames, intrinsics, depth, poses"),
    "convert": ("app.commands.convert", "convert any supported capture to the TUM RGB-D layout"),
    "export": ("app.commands.export", "export a run's map as .ply, .splat, .spz, compressed .ply or .html"),
    "render": ("app.commands.render_path", "render images of a map along a camera trajectory"),
    "refine": ("app.commands.refine", "refine a finished run's map over all keyframes at the capture's resolution"),
    "batch": ("app.commands.batch", "run many captures on a local or multi-node Dask cluster, with a summary and report"),
}


def _run(module_name: str, args: argparse.Namespace) -> int:
    try:
        return int(importlib.import_module(module_name).main(args) or 0)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def splatam_main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="splatam", description="SplaTAM: RGB-D SLAM with 3D Gaussians")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module_name).add_arguments(p)
        p.set_defaults(_module=module_name)
    args = parser.parse_args(argv)
    return _run(args._module, args)


def viewer_main(argv=None) -> int:
    module_name = "app.commands.viewer"
    parser = argparse.ArgumentParser(prog="splatam-viewer",
                                     description="Live SplaTAM SLAM in the browser (viser)")
    importlib.import_module(module_name).add_arguments(parser)
    return _run(module_name, parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(splatam_main())
