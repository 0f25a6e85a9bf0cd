"""Typed configuration in two layers: a budget (what the machine affords) and a format layer
(what the capture is). YAML presets in `configs/`, composed with '+', unknown keys are errors.

    load_config("cpu", format="record3d")   a budget, over the format layer of the capture
    load_config("splatam")                  the paper's Replica settings (the `splatam` budget)
    load_config("splatam_tum")              a paper preset: the paper's TUM settings (configs/paper/)
    load_config("cpu+record3d")             a format layer named explicitly (replaces the detected one)
    load_config("my.yaml")                  any file; it may name `base: splatam` to start from a preset

Budgets (configs/*.yaml: cpu, cpu_dense, gpu, splatam, splatam_s) set iterations, learning rates,
resolution and window. Format layers (configs/formats/<format>.yaml, one per capture format,
applied by themselves for the detected format) may set only FORMAT_KEYS: depth range, confidence,
depth upsampling, keyframe rules. The layer is applied first, so a budget's iteration counts hold
under every format. Paper presets (configs/paper/) are the paper's per-dataset combinations.

Every value a file gives is checked against its field's type (config_schema.py; the fields and their
documentation: config_sections.py, docs/settings.md). DEFAULT_PRESETS is the one place that says
which preset a run uses without --config, per device and engine.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import yaml

from .config_schema import check, field_types, section, setting
from .errors import InputError

# configs/ in a source checkout; shipped as splat_core/presets/ in an installed wheel.
CONFIG_DIR = next((d for d in (Path(__file__).resolve().parent / "presets",
                               Path(__file__).resolve().parent.parent / "configs") if d.is_dir()),
                  Path(__file__).resolve().parent.parent / "configs")


from .config_sections import (ALIGN_BACKENDS, KEYFRAME_SELECTIONS, TRACKING_PIXELS, AlignConfig,  # noqa: F401
                              DensifyConfig, KeyframeConfig, LiveConfig, LoopClosureConfig, LostTrackingConfig,
                              MappingConfig, TrackingConfig)

# The preset a run uses without --config, by device (torch.device.type) and engine: `splatam run`,
# `splatam-viewer`, `splatam batch` (through run), `splatam info` and `splatam config show` read it here.
DEFAULT_PRESETS = {("cpu", "sequential"): "cpu", ("cpu", "live"): "live",
                   ("cuda", "sequential"): "gpu", ("cuda", "live"): "gpu"}
DEVICE_WORDS = {"cpu": "a CPU", "cuda": "an NVIDIA GPU"}


def default_preset(device, engine: str = "sequential") -> str:
    """The preset for `device` (a torch.device or its type: cpu, cuda) and `engine` (sequential, live)."""
    key = (getattr(device, "type", device), engine)
    if key not in DEFAULT_PRESETS:
        raise InputError(f"no default preset for device {key[0]} and the {engine} engine: give --config")
    return DEFAULT_PRESETS[key]


def describe_default_presets() -> str:
    """The defaults in words, for --help and docs: 'cpu on a CPU, gpu on an NVIDIA GPU'."""
    engines = list(dict.fromkeys(engine for _, engine in DEFAULT_PRESETS))
    phrases = {e: ", ".join(f"{DEFAULT_PRESETS[(d, e)]} on {DEVICE_WORDS.get(d, d)}"
                            for d, e2 in DEFAULT_PRESETS if e2 == e) for e in engines}
    if len(set(phrases.values())) == 1:
        return phrases[engines[0]]
    return "; ".join(f"{e} engine: {p}" for e, p in phrases.items())


@dataclass
class Config:
    name: str = setting("splatam", "the preset, '+'-composition or file the config came from (set by the loader)")
    format_layer: str | None = setting(None, "the format layer applied (configs/formats/; set by the loader), "
                                       "or null")
    resolution: list[int] | int | None = setting(None, "working pixels: [width, height] as a pixel budget in the "
                                                 "capture's aspect ratio, or a long side (docs/resolution.md); "
                                                 "null = the capture's", unit="pixels",
                                                 trades="fewer: faster; below 320x240 one-pixel Gaussians bias "
                                                 "the rendered depth and tracking jitters")
    depth_upsampling: float | None = setting(1.0, "work at most this x the depth grid where colour is larger "
                                             "(null: up to colour)", unit="x depth grid",
                                             trades="larger: more pixels from the colour image, slower "
                                             "(docs/resolution.md)")
    max_depth: float | None = setting(None, "ignore depth beyond this", unit="metres")
    min_confidence: int | None = setting(None, "phones: keep depth with LiDAR confidence >= this (0-2; null: the "
                                         "reader's, 2)")
    isotropic: bool = setting(True, "one scale per Gaussian (SplaTAM's); false: three scales and a rotation")
    near_plane: float = setting(0.01, "the renderer's near plane: Gaussians closer to the camera are not drawn",
                                unit="metres")
    scene_radius_depth_ratio: float = setting(3.0, "scene radius = the first frame's largest depth / this "
                                              "(mapping.prune_big_ratio is relative to it)")
    seed: int = setting(0, "seed of the random choices (pixels, tiles, keyframe selection, RANSAC)")
    estimate_registration: bool = setting(
        True, "a capture whose camera file says colour and depth are not registered, and gives no colour camera: "
        "estimate the colour camera from the capture's edges (splatam info --estimate-registration) and register "
        "every frame; false: colour stays where it is and tracking uses depth alone",
        trades="true: 2-4 s at the start; on 7-Scenes colour lines up with depth again (PSNR +2.6 dB, and "
        "colour in tracking: docs/benchmarks.md, Two cameras)")
    checkpoint_every: int = setting(25, "write a checkpoint every n frames (--resume continues from it); 0 = never",
                                    unit="frames", trades="smaller: more writing, less lost when a run stops")
    eval_every: int = setting(5, "render metrics on every n-th frame at the end of a run", unit="frames",
                              trades="smaller: a longer finish, metrics on more frames")
    tracking: TrackingConfig = section(TrackingConfig, "the camera pose of each frame against the map (tracking.py)")
    mapping: MappingConfig = section(MappingConfig, "optimising the map over a window of keyframes (mapping.py)")
    densify: DensifyConfig = section(DensifyConfig, "where new Gaussians are added (densify.py)")
    keyframes: KeyframeConfig = section(KeyframeConfig, "which frames are kept and which of them map (keyframes.py)")
    live: LiveConfig = section(LiveConfig, "the live engine (run/live.py)")
    lost_tracking: LostTrackingConfig = section(LostTrackingConfig, "when a pose is not believed, and "
                                                "relocalisation (relocalise.py)")
    loop_closure: LoopClosureConfig = section(LoopClosureConfig, "online loop closure (loop/)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def validate(self) -> "Config":
        checks = [
            (self.tracking.iterations >= 0, "tracking.iterations must be >= 0"),
            (self.tracking.align.iterations >= 0, "tracking.align.iterations must be >= 0"),
            (self.tracking.align.backend in ALIGN_BACKENDS, "tracking.align.backend must be auto, numba or torch"),
            (self.tracking.pixels in TRACKING_PIXELS,
             "tracking.pixels must be all, random, gradient or depth_edges"),
            (self.tracking.pixel_tile >= 1 and self.tracking.pixels_per_tile >= 1 and self.tracking.align.stride >= 1,
             "tracking.pixel_tile, tracking.pixels_per_tile and tracking.align.stride must be >= 1"),
            (self.tracking.align.levels >= 1 and self.tracking.align.passes >= 1,
             "tracking.align.levels and tracking.align.passes must be >= 1"),
            (self.mapping.iterations >= 0, "mapping.iterations must be >= 0"),
            (self.mapping.window_size >= 2, "mapping.window_size must be >= 2"),
            (0 < self.mapping.tile_fraction <= 1 and self.mapping.min_tiles >= 0,
             "mapping.tile_fraction must be in (0, 1] and mapping.min_tiles >= 0"),
            (0 < self.mapping.first_frame_tile_fraction <= 1, "mapping.first_frame_tile_fraction must be in (0, 1]"),
            (self.live.max_lag >= 0, "live.max_lag must be >= 0"),
            ((self.live.hurry_coverage is None or 0 <= self.live.hurry_coverage <= 1) and self.live.hurry_iterations >= 1,
             "live.hurry_coverage must be in [0, 1] or null, live.hurry_iterations >= 1"),
            (min(self.lost_tracking.loss_factor, self.lost_tracking.max_speed,
                 self.lost_tracking.max_turn_rate_deg) > 0 and 0 <= self.lost_tracking.min_coverage <= 1,
             "lost_tracking: loss_factor, max_speed and max_turn_rate_deg must be > 0, min_coverage in [0, 1]"),
            (min(self.lost_tracking.loss_history, self.lost_tracking.min_history) >= 1
             and min(self.lost_tracking.recent_keyframes, self.lost_tracking.spread_keyframes,
                     self.lost_tracking.loss_trend) >= 0,
             "lost_tracking: loss_history and min_history must be >= 1, recent/spread_keyframes and loss_trend >= 0"),
            (self.loop_closure.min_gap_frames >= 1 and self.loop_closure.min_inliers >= 3
             and min(self.loop_closure.max_candidates, self.loop_closure.remap_iterations, self.loop_closure.orb_by_map,
                     self.loop_closure.orb_sample) >= 0 and self.loop_closure.feature_cache >= 1,
             "loop_closure: min_gap_frames >= 1, min_inliers >= 3, feature_cache >= 1, max_candidates, "
             "remap_iterations, orb_by_map and orb_sample >= 0"),
            (self.mapping.map_every >= 1, "mapping.map_every must be >= 1"),
            (self.keyframes.every >= 1 and self.keyframes.from_end >= 1,
             "keyframes.every and keyframes.from_end must be >= 1"),
            (self.tracking.max_gap_ratio >= 1, "tracking.max_gap_ratio must be >= 1"),
            (self.keyframes.memory_mb >= 0, "keyframes.memory_mb must be >= 0"),
            (self.keyframes.selection in KEYFRAME_SELECTIONS, "keyframes.selection must be overlap or random"),
            (0 < self.tracking.resolution_scale <= 1, "tracking.resolution_scale must be in (0, 1]"),
            (0 < self.densify.resolution_scale <= 1, "densify.resolution_scale must be in (0, 1]"),
            (_valid_resolution(self.resolution), "resolution must be [width, height], a long side or null"),
            (self.depth_upsampling is None or self.depth_upsampling >= 1, "depth_upsampling must be >= 1 or null"),
            (self.min_confidence in (None, 0, 1, 2), "min_confidence must be 0, 1, 2 or null"),
            (self.scene_radius_depth_ratio > 0, "scene_radius_depth_ratio must be > 0"),
            (set(self.mapping.lrs) == {"means", "colors", "rotations", "logit_opacities", "log_scales"},
             "mapping.lrs needs means, colors, rotations, logit_opacities, log_scales"),
        ]
        for ok, message in checks:
            if not ok:
                raise InputError(f"config {self.name}: {message}")
        return self


def _valid_resolution(r) -> bool:
    if r is None or (isinstance(r, int) and not isinstance(r, bool)):
        return r is None or r > 0
    return isinstance(r, (list, tuple)) and len(r) == 2 and all(
        isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in r)


# Keys that moved: (the dataclass they were in, old key) -> the new key (an error naming it).
MOVED_KEYS = {(TrackingConfig, f"align_{k}"): f"tracking.align.{k}" for k in
              ("iterations", "levels", "passes", "color_weight", "depth_noise", "stride", "min_points")}


def _merge(target, values: dict, where: str, prefix: str = ""):
    """Apply a nested dict onto a dataclass instance: unknown keys and values of the wrong type are
    errors naming `where` (the file) and the key's dotted path."""
    names = {f.name: f for f in dataclasses.fields(target)}
    hints = field_types(type(target))
    for key, value in values.items():
        path = f"{prefix}{key}"
        if (type(target), key) in MOVED_KEYS:
            new = MOVED_KEYS[(type(target), key)]
            raise InputError(f"{where}: config key tracking.{key} is now {new} (a nested section: "
                             f"tracking: {{align: {{{new.rsplit('.', 1)[1]}: ...}}}})")
        if key not in names:
            raise InputError(f"{where}: unknown config key {key!r}" + (f" in {prefix[:-1]}" if prefix else "")
                             + f" (known: {', '.join(sorted(names))})")
        current = getattr(target, key)
        if dataclasses.is_dataclass(current):
            check(value, dict, path, where)
            _merge(current, value, where, f"{path}.")
        elif isinstance(current, dict):
            check(value, dict, path, where)
            unknown = set(value) - set(current)
            if unknown:
                raise InputError(f"{where}: unknown keys in {path}: {sorted(unknown)}")
            for k, v in value.items():
                check(v, (get_args(hints[key]) or (str, object))[1], f"{path}.{k}", where)
            setattr(target, key, {**current, **value})
        else:
            check(value, hints[key], path, where)
            setattr(target, key, value)


# Where '+'-joined names are looked up: budgets, paper presets, format layers.
LAYER_DIRS = ("", "paper", "formats")
# What a format layer may set: what the capture is, never what the machine affords.
FORMAT_KEYS = ("max_depth", "min_confidence", "depth_upsampling", "keyframes")
# Sources whose format layer has another name.
FORMAT_ALIASES = {"nerfcapture-stream": "nerfcapture"}


def _preset_path(name: str) -> Path:
    for sub in LAYER_DIRS:
        candidate = CONFIG_DIR / sub / f"{name}.yaml"
        if candidate.is_file():
            return candidate
    return Path(name)


def format_layer_path(format_name: str | None) -> Path | None:
    """configs/formats/<format>.yaml for a capture format (FrameSource.format_name), if there is one."""
    if not format_name:
        return None
    path = CONFIG_DIR / "formats" / f"{FORMAT_ALIASES.get(format_name, format_name)}.yaml"
    return path if path.is_file() else None


def _is_format_layer(path: Path) -> bool:
    return path.is_file() and path.resolve().parent == CONFIG_DIR / "formats"


def preset_names() -> list[str]:
    return [p.stem for sub in LAYER_DIRS for p in sorted((CONFIG_DIR / sub).glob("*.yaml"))]


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: no such config file or preset (presets: {', '.join(preset_names())})")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of config keys")
    return data


def _apply(config: Config, spec: str, seen: tuple = ()) -> None:
    path = _preset_path(spec)
    if str(path) in seen:
        raise InputError(f"{path}: 'base' chain loops")
    data = _read_yaml(path)
    base = data.pop("base", None)
    if base is not None:
        check(base, str, "base", str(path))
    layer = _is_format_layer(path)
    if layer:
        wrong = sorted(set(data) - set(FORMAT_KEYS))
        if wrong:
            raise InputError(f"{path}: a format layer may set only {', '.join(FORMAT_KEYS)}, not {', '.join(wrong)} "
                             "(iterations, learning rates and resolution belong to the budget presets)")
        if base and not _is_format_layer(_preset_path(base)):
            raise InputError(f"{path}: a format layer's base must be another format layer, not {base}")
    if base:
        _apply(config, base, seen + (str(path),))
    if layer:
        config.format_layer = path.stem
    _merge(config, data, str(path))


def load_config(spec: str | None = None, overrides: dict | None = None, *, format: str | None = None) -> Config:
    """Build a Config: the format layer of capture format `format` (unless `spec` names a format
    layer itself), then the presets / files of `spec` joined by '+', then `overrides` (a nested dict)."""
    spec = spec or "splatam"
    parts = [part.strip() for part in spec.split("+")]
    config = Config()
    layer = format_layer_path(format)
    if layer is not None and not any(_is_format_layer(_preset_path(part)) for part in parts):
        _apply(config, str(layer))
    for part in parts:
        _apply(config, part)
    if overrides:
        _merge(config, overrides, "overrides")
    config.name = spec
    return config.validate()


def format_layer_settings(name: str | None, seen: tuple = ()) -> dict:
    """What format layer `name` sets, its base's settings first, flattened ({"max_depth": 5.0, "keyframes.every": 2})."""
    path = format_layer_path(name)
    if path is None or path in seen:
        return {}
    data = _read_yaml(path)
    base = data.pop("base", None)
    flat = format_layer_settings(str(base), seen + (path,)) if base else {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    return flat


def describe_layers(config: Config) -> str:
    """One line: which budget and which format layer make `config` (printed by run, viewer, info)."""
    if not config.format_layer:
        return f"budget {config.name}, no format layer"

    def resolved(key):
        value = config
        for part in key.split("."):
            value = getattr(value, part)
        return value

    settings = format_layer_settings(config.format_layer)
    what = ", ".join(f"{k} {v}" if resolved(k) == v else f"{k} {resolved(k)} (the layer's {v}, replaced by {config.name})"
                     for k, v in settings.items()) or "nothing to change"
    return f"budget {config.name} + format layer {config.format_layer} ({what})"


def config_from_dict(data: dict) -> Config:
    """Rebuild a resolved config (e.g. a run folder's config.yaml). A run folder written before
    tracking.align was a section (flat tracking.align_* keys) is read with those keys moved."""
    data = dict(data)
    tracking = data.get("tracking")
    if isinstance(tracking, dict):
        tracking = dict(tracking)
        moved = {new.rsplit(".", 1)[1]: tracking.pop(old) for (cls, old), new in MOVED_KEYS.items()
                 if cls is TrackingConfig and old in tracking}
        if moved:
            tracking["align"] = {**tracking.get("align", {}), **moved}
        data["tracking"] = tracking
    config = Config()
    _merge(config, data, "config")
    return config.validate()
