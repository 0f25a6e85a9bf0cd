"""`splatam config show [NAME]`: the resolved settings of a preset, a '+'-composition or a YAML file,
as YAML, without a capture: every key with the value a run would use (what it records in its
config.yaml). The output is itself a config file (`--config shown.yaml`). Every key: docs/settings.md.

    splatam config show                      the default preset of this machine's device
    splatam config show cpu --format record3d   the cpu budget over the record3d format layer
    splatam config show my.yaml --device cuda
"""

from __future__ import annotations

import argparse

from splat_core.config import describe_default_presets

ACTIONS = ("show",)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=ACTIONS, help="show: print the resolved config as YAML")
    p.add_argument("name", nargs="?", default=None, metavar="NAME",
                   help="a preset (budget, paper preset or format layer), names joined by '+', or a YAML file "
                        f"(default: the device's default preset, {describe_default_presets()})")
    p.add_argument("--format", default=None, help="capture format whose layer applies, as for a capture of that "
                   "format (record3d, tum, ...; default: none)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="the device whose default preset applies when NAME is not given (auto: cuda when torch "
                        "sees a GPU)")
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"],
                   help="the engine whose default preset applies when NAME is not given (default sequential, as "
                        "splatam run; the viewer's is live)")


def main(args) -> int:
    import yaml

    from splat_core.config import (CONFIG_DIR, DEVICE_WORDS, default_preset, describe_layers, format_layer_path,
                                   load_config)
    from splat_core.errors import InputError

    if args.format and format_layer_path(args.format.lower()) is None:
        known = ", ".join(sorted(p.stem for p in (CONFIG_DIR / "formats").glob("*.yaml")))
        raise InputError(f"--format {args.format}: no format layer of that name (configs/formats/: {known})")
    header = []
    name = args.name
    if name is None:
        device = args.device
        if device == "auto":
            from splat_core.run import resolve_device
            device = resolve_device("auto").type
        name = default_preset(device, args.engine)
        header.append(f"the default preset on {DEVICE_WORDS.get(device, device)} with the {args.engine} engine")
    config = load_config(name, format=args.format.lower() if args.format else None)
    header.append(describe_layers(config))
    print("".join(f"# {line}\n" for line in header) + yaml.safe_dump(config.to_dict(), sort_keys=False), end="")
    return 0
