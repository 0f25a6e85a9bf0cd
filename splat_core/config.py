"""Typed configuration in two layers: a budget (what the machine affords) and a format layer
(what the capture is). YAML presets in `configs/`, composed with '+', unknown keys are errors.

    load_config("cpu", format="record3d")   a budget, over the format layer of the capture
    load_config("splatam")                  the paper's Replica settings (the `splatam` budget)
    load_config("splatam_tum")              a paper preset: the paper's TUM settings (configs/paper/)
    load_config("cpu+record3d")             a format layer named explicitly (replaces the detected one)
    load_config("my.yaml")                  any file; it may name `base: splatam` to start from a preset

Budgets (configs/*.yaml: cpu, cpu_dense, splatam, splatam_s) set iterations, learning rates,
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


@dataclass
class TrackingConfig:
    iterations: int = 40
    lr_rotation: float = 4e-4             # Adam on the w2c quaternion
    lr_translation: float = 2e-3          # Adam on the w2c translation
    silhouette_threshold: float = 0.99    # only pixels the map already explains are used
    depth_weight: float = 1.0
    color_weight: float = 0.5
    resolution_scale: float = 1.0         # track at this fraction of the working resolution
    coarse_iterations: int = 0            # first this many iterations at coarse_scale (coarse to fine)
    coarse_scale: float = 0.5
    depth_loss_threshold: float | None = None  # if set: double the iterations once while above (per valid pixel, metres)
    use_reference_poses: bool = False     # skip tracking, use the capture's poses (mapping only)
    compat_post_step_candidate: bool = False  # the original code's off-by-one best-pose snapshot
    early_stop_tolerance: float = 0.0     # stop when the pose update is below this (m / rad); 0 = never
    outlier_factor: float | None = None   # drop pixels whose depth error exceeds this x the median error
    align_iterations: int = 0             # Gauss-Newton pre-alignment to the rendered map (direct_align.py), per level; 0 = off
    align_levels: int = 3                 # pyramid levels of that alignment
    align_passes: int = 1                 # renders (re-linearisations) of that alignment
    align_color_weight: float = 1.0       # photometric term's weight against point-to-plane depth
    align_depth_noise: bool = False       # divide its depth residuals by a structured-light noise model sigma(z)
    align_stride: int = 1                 # that alignment uses every n-th live pixel (x and y) at full resolution
    align_min_points: int = 4096          # ... but a smaller stride where that would leave fewer pixels
    pixels: str = "all"                   # pixels of the tracking loss: all | random | gradient | depth_edges (pixel_selection.py)
    pixel_tile: int = 8                   # ... chosen per pixel_tile x pixel_tile block
    pixels_per_tile: int = 1
    min_pixels: int = 1024                # ... but smaller blocks where that would leave fewer pixels


@dataclass
class MappingConfig:
    iterations: int = 60
    first_frame_iterations: int | None = None   # None = same as iterations
    window_size: int = 24
    map_every: int = 1
    depth_weight: float = 1.0
    color_weight: float = 0.5
    ssim_weight: float = 0.2              # colour term = (1-w) L1 + w (1 - SSIM)
    lrs: dict = field(default_factory=lambda: dict(
        means=1e-4, colors=2.5e-3, rotations=1e-3, logit_opacities=5e-2, log_scales=1e-3))
    prune_every: int = 20
    prune_until: int = 20
    prune_opacity: float = 0.005
    prune_big_ratio: float = 0.1          # remove Gaussians larger than this x scene radius
    visible_only: bool = True             # optimise only Gaussians seen from the window (same result for the rest: zero grads)
    tile_fraction: float = 1.0            # each iteration draws and compares this fraction of the 16 x 16 tiles (random; 1 = all) ...
    min_tiles: int = 64                   # ... but at least this many (small images map on every tile)


@dataclass
class DensifyConfig:
    silhouette_threshold: float = 0.5
    depth_error_factor: float = 50.0      # "new geometry in front": error > factor x median error
    resolution_scale: float = 1.0         # densify at this fraction of the working resolution
    initial_opacity: float = 0.5


@dataclass
class KeyframeConfig:
    every: int = 5
    selection: str = "overlap"            # "overlap" (paper: top-k) or "random" (original code)
    overlap_samples: int = 1600
    overlap_border: int = 20
    overlap_within_depth: bool = False    # a point overlaps a keyframe only within the depth it measured (no: SplaTAM's test)
    memory_mb: float = 512.0              # keyframe images kept in host memory; older ones are read from a file (keyframes.py)


@dataclass
class LiveConfig:
    max_lag: int = 2                      # frames the live engine's tracker may run ahead of the newest mapped frame (live.py)


@dataclass
class LostTrackingConfig:
    """When a tracked pose is not believed (relocalise.py) and how it is relocalised."""
    enabled: bool = True
    loss_factor: float = 5.0              # lost: loss per pixel above this x the median of the recent tracked frames ...
    loss_history: int = 10                # ... over this many tracked frames
    min_history: int = 3                  # ... once that many are known
    min_coverage: float = 0.25            # lost: the map's silhouette covers less than this fraction of the loss's valid-depth pixels
    max_speed: float = 3.0                # lost: the camera moved faster than this (m/s) since the last tracked frame ...
    max_turn_rate_deg: float = 360.0      # ... or turned faster (degrees/s); the time from the timestamps (--stride, skipped frames)
    recent_keyframes: int = 2             # relocalisation starts: the last tracked pose, this many newest keyframes ...
    spread_keyframes: int = 3             # ... and this many keyframes spread over the run
    align_iterations: int = 10            # relocalisation aligns from each start by Gauss-Newton (at least this many iterations per level) ...
    align_passes: int = 3                 # ... rendering the map again this many times, so a jump is walked in steps


@dataclass
class LoopClosureConfig:
    """Online loop closure (splat_core/loop/, docs/loop-closure.md); off in the paper presets."""
    enabled: bool = False
    min_gap_frames: int = 100             # a candidate keyframe is at least this many frames older than the current one
    min_visible: float = 0.15             # candidate: this fraction of the current depth is explained by its old Gaussians ...
    min_orb_matches: int = 25             # ... or ORB matches (ratio test) with it reach this many
    max_candidates: int = 3               # verified per keyframe (best first)
    min_inliers: int = 12                 # 3D-3D RANSAC inliers (ORB matches with depth) to accept
    min_inlier_ratio: float = 0.25
    inlier_distance: float = 0.04         # metres, RANSAC inlier threshold
    min_depth_agreement: float = 0.5      # the old keyframe's depth agrees with the current one at the loop's pose
    min_overlap: float = 0.3              # alignment: fraction of the frame's depth the old map explains
    max_rmse: float = 0.03                # alignment: point-to-plane RMS (metres) at most
    max_disagreement: float = 0.05        # RANSAC and alignment agree within this (metres) ...
    max_disagreement_deg: float = 3.0     # ... and degrees
    min_correction: float = 0.03          # optimise the graph only when the loop disagrees by this (metres) ...
    min_correction_deg: float = 1.0       # ... or degrees with the current poses (1 cm: 7-Scenes' first 300 frames 1.30 -> 1.55 cm)
    odometry_sigma: float = 0.01          # metres per keyframe step (+ odometry_sigma_rel x the step's length)
    odometry_sigma_rel: float = 0.05
    odometry_sigma_deg: float = 0.3
    remap_iterations: int = 20            # mapping iterations over the loop's keyframes after a correction
    cooldown_keyframes: int = 2           # keyframes without detection after an accepted loop


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
            (self.tracking.align_iterations >= 0, "tracking.align_iterations must be >= 0"),
            (self.tracking.pixels in ("all", "random", "gradient", "depth_edges"),
             "tracking.pixels must be all, random, gradient or depth_edges"),
            (self.tracking.pixel_tile >= 1 and self.tracking.pixels_per_tile >= 1 and self.tracking.align_stride >= 1,
             "tracking.pixel_tile, tracking.pixels_per_tile and tracking.align_stride must be >= 1"),
            (self.tracking.align_levels >= 1 and self.tracking.align_passes >= 1,
             "tracking.align_levels and tracking.align_passes must be >= 1"),
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
             and self.loop_closure.max_candidates >= 0 and self.loop_closure.remap_iterations >= 0,
             "loop_closure: min_gap_frames >= 1, min_inliers >= 3, max_candidates and remap_iterations >= 0"),
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


def _merge(target, values: dict, where: str):
    """Apply a nested dict onto a dataclass instance; unknown keys are errors."""
    names = {f.name: f for f in dataclasses.fields(target)}
    for key, value in values.items():
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
    """Rebuild a resolved config (e.g. a run folder's config.yaml)."""
    config = Config()
    _merge(config, dict(data), "config")
    return config.validate()
