"""Entry points: `splatam` (headless subcommands) and `splatam-viewer` (the web viewer).

Each subcommand lives in `app/commands/<name>.py` with `add_arguments(parser)` and
`main(args) -> int`; heavy imports happen inside `main` so `--help` stays fast. User errors
(`InputError`) print one line and exit 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Torch's OpenMP runtime (Numba's kernels run on it too): how its idle threads wait, set before torch loads.
from splat_core.openmp_env import openmp_defaults

openmp_defaults()

from splat_core.errors import InputError  # noqa: E402

SUBCOMMANDS = {
    "run": ("app.commands.run", "run SLAM headless on a capture and write a run folder"),
    "capture": ("app.commands.capture", "record the NeRFCapture iPhone app's live stream as a capture folder"),
    "info": ("app.commands.info", "describe a capture: format, frames, intrinsics, depth, poses"),
    "convert": ("app.commands.convert", "convert any supported capture to the TUM RGB-D layout"),
    "export": ("app.commands.export", "export a run's map (.ply, .splat, .spz, compressed .ply, .html), "
               "or hand it off: a COLMAP model, a nerfstudio dataset, a mesh"),
    "render": ("app.commands.render_path", "render images of a map along a camera trajectory"),
    "refine": ("app.commands.refine", "refine a finished run's map over all keyframes at the capture's resolution"),
    "batch": ("app.commands.batch", "run many captures on a local or multi-node Dask cluster, with a summary and report"),
    "config": ("app.commands.config", "show the resolved settings of a preset, a '+'-composition or a YAML file "
               "(splatam config show [NAME])"),
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


def parse_or_suggest(parser: argparse.ArgumentParser, argv, subparsers: dict | None = None):
    """parse_args, but an unknown option is reported by the subcommand's own parser (its usage) with the
    closest option it has ("did you mean --max-frames?"), before any complaint about missing ones; an
    unknown subcommand in one line with the closest one ("did you mean run?"), exit status 2."""
    import difflib

    words = list(sys.argv[1:] if argv is None else argv)
    target = parser
    if subparsers:
        name = next((w for w in words if not w.startswith("-")), None)
        if name is not None and name not in subparsers:
            close = difflib.get_close_matches(name, subparsers, n=1, cutoff=0.5)
            parser.exit(2, f"{parser.prog}: unknown command {name!r}: "
                           + (f"did you mean {close[0]}?\n" if close else f"expected one of {', '.join(subparsers)}\n"))
        target = subparsers.get(name, parser)
    options = [o for action in target._actions for o in action.option_strings]
    unknown = [w for w in words if w.startswith("--") and w != "--"
               and not any(o.startswith(w.split("=")[0]) for o in options)]
    if unknown:
        hints = []
        for word in unknown:
            close = difflib.get_close_matches(word.split("=")[0], options, n=1, cutoff=0.6)
            if close:
                hints.append(f"{word}: did you mean {close[0]}?")
        target.error(f"unrecognized arguments: {' '.join(unknown)}" + (f" ({'; '.join(hints)})" if hints else ""))
    return parser.parse_args(words)


def splatam_main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="splatam", description="SplaTAM: RGB-D SLAM with 3D Gaussians")
    sub = parser.add_subparsers(dest="command", required=True)
    subparsers = {}
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module_name).add_arguments(p)
        p.set_defaults(_module=module_name)
        subparsers[name] = p
    args = parse_or_suggest(parser, argv, subparsers)
    return _run(args._module, args)


def viewer_main(argv=None) -> int:
    module_name = "app.commands.viewer"
    parser = argparse.ArgumentParser(prog="splatam-viewer",
                                     description="Live SplaTAM SLAM in the browser (viser)")
    importlib.import_module(module_name).add_arguments(parser)
    return _run(module_name, parse_or_suggest(parser, argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(splatam_main())
