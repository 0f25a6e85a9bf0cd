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
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .errors import InputError

# configs/ in a source checkout; shipped as splat_core/presets/ in an installed wheel.
CONFIG_DIR = next((d for d in (Path(__file__).resolve().parent / "presets",
                               Path(__file__).resolve().parent.parent / "configs") if d.is_dir()),
                  Path(__file__).resolve().parent.parent / "configs")


from .config_sections import (ALIGN_BACKENDS, AlignConfig, DensifyConfig, KeyframeConfig, LiveConfig,  # noqa: F401
                              LoopClosureConfig, LostTrackingConfig, MappingConfig, TrackingConfig)


@dataclass
class Config:
    name: str = "splatam"
    format_layer: str | None = None       # the format layer applied (configs/formats/), None = none
    resolution: list | int | None = None  # [width, height] pixel budget or a long side, aspect kept (resolution.py); None = capture's
    depth_upsampling: float | None = 1.0  # work at most this x the depth grid where colour is larger (None: up to colour)
    max_depth: float | None = None        # ignore depth beyond this (metres)
    min_confidence: int | None = None     # phones: keep depth with LiDAR confidence >= this (0-2; None: the reader's, 2)
    isotropic: bool = True
    near_plane: float = 0.01
    scene_radius_depth_ratio: float = 3.0
    seed: int = 0
    checkpoint_every: int = 25            # frames; 0 = never
    eval_every: int = 5                   # render metrics on every n-th frame at the end
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    live: LiveConfig = field(default_factory=LiveConfig)
    lost_tracking: LostTrackingConfig = field(default_factory=LostTrackingConfig)
    loop_closure: LoopClosureConfig = field(default_factory=LoopClosureConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def validate(self) -> "Config":
        checks = [
            (self.tracking.iterations >= 0, "tracking.iterations must be >= 0"),
            (self.tracking.align.iterations >= 0, "tracking.align.iterations must be >= 0"),
            (self.tracking.align.backend in ALIGN_BACKENDS, "tracking.align.backend must be auto, numba or torch"),
            (self.tracking.pixels in ("all", "random", "gradient", "depth_edges"),
             "tracking.pixels must be all, random, gradient or depth_edges"),
            (self.tracking.pixel_tile >= 1 and self.tracking.pixels_per_tile >= 1 and self.tracking.align.stride >= 1,
             "tracking.pixel_tile, tracking.pixels_per_tile and tracking.align.stride must be >= 1"),
            (self.tracking.align.levels >= 1 and self.tracking.align.passes >= 1,
             "tracking.align.levels and tracking.align.passes must be >= 1"),
            (self.mapping.iterations >= 0, "mapping.iterations must be >= 0"),
            (self.mapping.window_size >= 2, "mapping.window_size must be >= 2"),
            (0 < self.mapping.tile_fraction <= 1 and self.mapping.min_tiles >= 0,
             "mapping.tile_fraction must be in (0, 1] and mapping.min_tiles >= 0"),
            (self.live.max_lag >= 0, "live.max_lag must be >= 0"),
            (min(self.lost_tracking.loss_factor, self.lost_tracking.max_speed,
                 self.lost_tracking.max_turn_rate_deg) > 0 and 0 <= self.lost_tracking.min_coverage <= 1,
             "lost_tracking: loss_factor, max_speed and max_turn_rate_deg must be > 0, min_coverage in [0, 1]"),
            (min(self.lost_tracking.loss_history, self.lost_tracking.min_history) >= 1
             and min(self.lost_tracking.recent_keyframes, self.lost_tracking.spread_keyframes) >= 0,
             "lost_tracking: loss_history and min_history must be >= 1, recent/spread_keyframes >= 0"),
            (self.loop_closure.min_gap_frames >= 1 and self.loop_closure.min_inliers >= 3
             and min(self.loop_closure.max_candidates, self.loop_closure.remap_iterations, self.loop_closure.orb_by_map,
                     self.loop_closure.orb_sample) >= 0 and self.loop_closure.feature_cache >= 1,
             "loop_closure: min_gap_frames >= 1, min_inliers >= 3, feature_cache >= 1, max_candidates, "
             "remap_iterations, orb_by_map and orb_sample >= 0"),
            (self.mapping.map_every >= 1, "mapping.map_every must be >= 1"),
            (self.keyframes.every >= 1, "keyframes.every must be >= 1"),
            (self.keyframes.memory_mb >= 0, "keyframes.memory_mb must be >= 0"),
            (self.keyframes.selection in ("overlap", "random"), "keyframes.selection must be overlap or random"),
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


def _merge(target, values: dict, where: str):
    """Apply a nested dict onto a dataclass instance; unknown keys are errors."""
    names = {f.name: f for f in dataclasses.fields(target)}
    for key, value in values.items():
        if (type(target), key) in MOVED_KEYS:
            new = MOVED_KEYS[(type(target), key)]
            raise InputError(f"{where}: config key tracking.{key} is now {new} (a nested section: "
                             f"tracking: {{align: {{{new.rsplit('.', 1)[1]}: ...}}}})")
        if key not in names:
            raise InputError(f"{where}: unknown config key {key!r} (known: {', '.join(sorted(names))})")
        current = getattr(target, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise InputError(f"{where}: {key} must be a mapping")
            _merge(current, value, f"{where}: {key}")
        elif isinstance(current, dict) and isinstance(value, dict):
            unknown = set(value) - set(current)
            if unknown:
                raise InputError(f"{where}: unknown keys in {key}: {sorted(unknown)}")
            setattr(target, key, {**current, **value})
        else:
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
    if _is_format_layer(path):
        wrong = sorted(set(data) - set(FORMAT_KEYS))
        if wrong:
            raise InputError(f"{path}: a format layer may set only {', '.join(FORMAT_KEYS)}, not {', '.join(wrong)} "
                             "(iterations, learning rates and resolution belong to the budget presets)")
        config.format_layer = path.stem
    base = data.pop("base", None)
    if base:
        _apply(config, str(base), seen + (str(path),))
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


def format_layer_settings(name: str | None) -> dict:
    """What format layer `name` sets, flattened ({"max_depth": 5.0, "keyframes.every": 2})."""
    path = format_layer_path(name)
    if path is None:
        return {}
    flat = {}
    for key, value in _read_yaml(path).items():
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
