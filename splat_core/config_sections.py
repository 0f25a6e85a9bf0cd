"""The config's sections, one dataclass each (tracking, mapping, densify, keyframes, live engine,
lost tracking, loop closure); config.py composes them into Config and reads presets."""

from __future__ import annotations

from dataclasses import dataclass, field


ALIGN_BACKENDS = ("auto", "numba", "torch")


@dataclass
class AlignConfig:
    """tracking.align: the Gauss-Newton pre-alignment to the rendered map (align/)."""
    iterations: int = 0                   # per pyramid level; 0 = off
    levels: int = 3                       # pyramid levels
    passes: int = 1                       # renders (re-linearisations)
    color_weight: float = 1.0             # photometric term's weight against point-to-plane depth
    depth_noise: bool = False             # divide its depth residuals by a structured-light noise model sigma(z)
    stride: int = 1                       # every n-th live pixel (x and y) at full resolution ...
    min_points: int = 4096                # ... but a smaller stride where that would leave fewer pixels
    backend: str = "auto"                 # numba (CPU, align/numba_backend.py) | torch (the map's device, align/torch_backend.py) | auto: torch on CUDA, else numba


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
    align: AlignConfig = field(default_factory=AlignConfig)   # Gauss-Newton pre-alignment (tracking.align.*)
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
    orb_by_map: int = 8                   # ORB-matched per keyframe: the old keyframes the map names most ...
    orb_sample: int = 8                   # ... and this many others spread over the run (random offset):
                                          # per-keyframe cost stays bounded however long the run
    feature_cache: int = 32               # keyframes whose ORB features stay in memory (recomputed otherwise)
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
    map_route: bool = False               # verify candidates RANSAC cannot measure by aligning from the tracked
                                          # pose against the old map: not independent of tracking (on 7-Scenes
                                          # the two corrections it applied made the first 300 frames worse)
