"""The config's sections, one dataclass each (tracking, mapping, densify, keyframes, live engine,
lost tracking, loop closure); config.py composes them into Config and reads presets.

Each field is a `setting(default, what it does, unit=, trades=)` (config_schema.py): its type
annotation is checked against what a YAML file gives, and docs/settings.md is generated from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from .config_schema import section, setting

AlignBackend = Literal["auto", "numba", "torch"]
TrackingPixels = Literal["all", "random", "gradient", "depth_edges"]
KeyframeSelection = Literal["overlap", "random"]
LiveMapping = Literal["newest", "keyframes"]
KeyframeClock = Literal["capture", "processed"]
LiveCheckpoint = Literal["drain", "published"]
PaceSources = Literal["live", "all"]
ALIGN_BACKENDS = get_args(AlignBackend)
TRACKING_PIXELS = get_args(TrackingPixels)
KEYFRAME_SELECTIONS = get_args(KeyframeSelection)


@dataclass
class AlignConfig:
    """tracking.align: the Gauss-Newton pre-alignment to the rendered map (align/)."""
    iterations: int = setting(0, "Gauss-Newton iterations per pyramid level; 0 = no alignment", unit="iterations",
                              trades="more: slower tracking, converges from further away (cpu and gpu: 10)")
    levels: int = setting(3, "pyramid levels of the alignment", unit="levels",
                          trades="more: catches larger motions, at a little more cost")
    passes: int = setting(1, "renders of the map (re-linearisations) during the alignment", unit="renders",
                          trades="more: slower; a pose far off is walked in steps")
    color_weight: float = setting(1.0, "the photometric term's weight against the point-to-plane depth term")
    depth_noise: bool = setting(False, "divide the depth residuals by a structured-light noise model sigma(z), so "
                                "far, noisy depth does not outvote near surfaces")
    stride: int = setting(1, "use every n-th live pixel in x and y at full resolution ...", unit="pixels",
                          trades="larger: faster alignment on fewer pixels (cpu: 4, gpu: 2)")
    min_points: int = setting(4096, "... but a smaller stride where that would leave fewer pixels", unit="pixels")
    exposure: bool = setting(False, "scale the rendered grey levels by one gain per frame (the live image's "
                             "brightness over the map's, on the pixels both see) before the photometric term, so "
                             "an auto-exposure change is not taken for motion",
                             trades="true on 7-Scenes: closer to the SfM reference, further from the KinectFusion one; SUN3D unchanged "
                             "(docs/benchmarks.md, Three lenses)")
    tolerance: float = setting(1e-7, "a pyramid level's Gauss-Newton iterations stop when a step changes no entry "
                               "of the 4 x 4 pose by this much (radians, metres)", trades="larger: fewer iterations "
                               "per frame, a pose that stops short of the solve's minimum (cpu, live: 1e-4)")
    reuse_render: int = setting(0, "frames after the one it was made for that the alignment's dense render of a map "
                                "version serves again (the map's culled Gaussians too), aligned from the render's "
                                "pose; a new map version renders anew; 0: a render per frame", unit="frames",
                                trades="more: fewer renders, an alignment against a render from further away "
                                "(live: 4)")
    reuse_rival: bool = setting(True, "on a frame aligned against a reused render: score the prediction with a "
                                "sparse-pixel render of its own, so the aligned pose is kept only if it beats it "
                                "(false: keep the aligned pose; the polish and the lost-tracking check still judge it)",
                                trades="false: one render less on those frames, no fallback to the prediction")
    reuse_rival_beyond: float = setting(0.0, "with reuse_rival false: score the prediction anyway on a frame whose "
                                        "aligned camera centre is further than this from the prediction's (an "
                                        "alignment gone astray against a render from further away); 0: never",
                                        unit="m", trades="less: the prediction's render on more frames (live: 0.01)")
    backend: AlignBackend = setting("auto", "numba (CPU, align/numba_backend.py), torch (the map's "
                                    "device, align/torch_backend.py), or auto: torch on CUDA, else numba")


@dataclass
class TrackingConfig:
    iterations: int = setting(40, "SplaTAM's Adam iterations on the pose per frame (after the alignment, if any)",
                              unit="iterations", trades="more: slower, a pose nearer the loss's minimum (the paper: 40; "
                              "cpu: 2 after the alignment)")
    lr_rotation: float = setting(4e-4, "Adam's learning rate on the w2c quaternion", trades="larger: longer first "
                                 "steps (Adam's are about a rate long); after an alignment the paper's rates shook "
                                 "the pose more than they corrected it (cpu, gpu: an eighth)")
    lr_translation: float = setting(2e-3, "Adam's learning rate on the w2c translation")
    silhouette_threshold: float = setting(0.99, "only pixels the map already explains (silhouette above this) "
                                          "enter the tracking loss", unit="fraction")
    depth_weight: float = setting(1.0, "weight of the depth L1 term in the tracking loss")
    color_weight: float = setting(0.5, "weight of the colour L1 term in the tracking loss")
    resolution_scale: float = setting(1.0, "track at this fraction of the working resolution", unit="fraction",
                                      trades="smaller: faster, a less precise pose")
    coarse_iterations: int = setting(0, "first this many iterations at coarse_scale (coarse to fine)",
                                     unit="iterations", trades="cheaper iterations at coarse_scale")
    coarse_scale: float = setting(0.5, "resolution of the coarse iterations", unit="fraction")
    depth_loss_threshold: float | None = setting(None, "if set: double the iterations once while the depth error "
                                                 "per valid pixel stays above this", unit="metres",
                                                 trades="slower on hard frames only")
    use_reference_poses: bool = setting(False, "skip tracking and use the capture's poses (mapping only)")
    compat_post_step_candidate: bool = setting(False, "the original code's off-by-one best-pose snapshot (after "
                                               "the step, not before)")
    early_stop_tolerance: float = setting(0.0, "stop when the pose update is below this; 0 = never",
                                          unit="m / rad", trades="larger: fewer iterations, may stop "
                                          "before the pose has converged")
    outlier_factor: float | None = setting(None, "drop pixels whose depth error exceeds this x the median error "
                                           "(SplaTAM's optional rule); null = keep all")
    max_gap_ratio: float = setting(4.0, "the constant-velocity prediction scales the last motion (in se(3)) by the "
                                   "capture frames to this frame over those between the two before (frames "
                                   "dropped by --realtime or a stream), at most this", unit="ratio",
                                   trades="larger: follows longer gaps, amplifies the last motion's noise more")
    align: AlignConfig = section(AlignConfig, "the Gauss-Newton pre-alignment to the rendered map (align/)")
    pixels: TrackingPixels = setting("all", "pixels of the tracking loss: all, or a few per tile chosen at random, "
                                     "by gradient or on depth edges (pixel_selection.py)",
                                     trades="sparse: far cheaper iterations on the CPU (cpu: random); gsplat draws "
                                     "the whole image anyway")
    pixel_tile: int = setting(8, "... chosen per pixel_tile x pixel_tile block", unit="pixels",
                              trades="larger: fewer pixels, faster, noisier loss")
    pixels_per_tile: int = setting(1, "... this many per block", unit="pixels")
    min_pixels: int = setting(1024, "... but smaller blocks where that would leave fewer pixels", unit="pixels")


@dataclass
class MappingConfig:
    iterations: int = setting(60, "Adam iterations on the map per mapped frame, each on one view of the window",
                              unit="iterations", trades="more: slower, a better map (16 half-image iterations map "
                              "about 1 dB better than 10 on SUN3D: docs/presets.md)")
    first_frame_iterations: int | None = setting(None, "mapping iterations on frame 0 (it anchors every later "
                                                 "pose), over first_frame_tile_fraction of the tiles; null = "
                                                 "iterations", unit="iterations")
    first_frame_tile_fraction: float = setting(1.0, "the fraction of the 16 x 16 tiles each of frame 0's mapping "
                                               "iterations draws (see tile_fraction)", unit="fraction",
                                               trades="smaller: a cheaper first mapping, which the live engine's "
                                               "tracker waits for (the `live` preset: 0.5)")
    window_size: int = setting(24, "views a mapping iteration draws from: the current frame, the latest keyframe "
                               "and overlapping keyframes", unit="views",
                               trades="larger: the map stays consistent with more of the past; the current frame "
                               "gets fewer of the iterations")
    map_every: int = setting(1, "map every n-th frame", unit="frames", trades="larger: faster, the map lags")
    depth_weight: float = setting(1.0, "weight of the depth L1 term in the mapping loss")
    color_weight: float = setting(0.5, "weight of the colour term in the mapping loss")
    ssim_weight: float = setting(0.2, "colour term = (1-w) L1 + w (1 - SSIM)", unit="fraction")
    lrs: dict[str, float] = setting(dict(means=1e-4, colors=2.5e-3, rotations=1e-3, logit_opacities=5e-2,
                                         log_scales=1e-3),
                                    "Adam's learning rate per Gaussian parameter (all five keys needed)")
    prune_every: int = setting(20, "prune transparent and huge Gaussians every n-th mapping iteration ...",
                               unit="iterations")
    prune_until: int = setting(20, "... up to this iteration", unit="iterations")
    prune_opacity: float = setting(0.005, "pruning removes Gaussians less opaque than this", unit="opacity")
    prune_big_ratio: float = setting(0.1, "pruning removes Gaussians larger than this x the scene radius",
                                     unit="x scene radius")
    visible_only: bool = setting(True, "optimise only Gaussians seen from the window: the same result (the others "
                                 "get zero gradients), at a cost that follows the visible part only")
    tile_fraction: float = setting(1.0, "each iteration draws and compares this fraction of the 16 x 16 tiles "
                                   "(random; 1 = all) ...", unit="fraction",
                                   trades="smaller: cheaper iterations on the CPU rasterizer (cpu: 0.5; SUN3D "
                                   "fragment 2: 10 half-image iterations within 0.3 dB of 8 whole-image ones at about "
                                   "0.8 of the cost); no saving with gsplat")
    min_tiles: int = setting(64, "... but at least this many (small images map on every tile)", unit="tiles")
    exposure: bool = setting(False, "compare each view with the render under that view's own colour gain and "
                             "offset per channel (least squares against the view at every iteration, pulled "
                             "towards identity by exposure_prior), so auto-exposure changes do not pull the "
                             "Gaussians' colours (mapping.py)",
                             trades="true: the map keeps one exposure across frames; the render is not fitted "
                             "to the newest frame's")
    exposure_prior: float = setting(0.01, "weight of identity (gain 1, offset 0) in that fit, per pixel of the "
                                    "view (0: free fit)", unit="fraction")
    final_refine: float = setting(
        0.0, "after the last frame (no pose moves), before the other final passes: passes over every keyframe "
        "optimising the whole map, kept only if held-out frames bear it out (final_refine.py); 0 = off",
        unit="passes", trades="more: a map fitted to the whole run, not each part to the frames that saw it last "
        "(7-Scenes +2 dB, SUN3D +0.2-0.6 at one pass), for one render and backward per keyframe and pass")
    final_color_fit: bool = setting(False, "after the last frame, one gain and offset per channel on the map's "
                                    "colours (least squares against frames kept midway between evaluated ones; "
                                    "color_fit.py): the run's average exposure, not the last frames'",
                                    trades="true: renders brighter or darker by the same three numbers; up to "
                                    "64 frames at half resolution kept (57.6 kB each at 320x240)")
    final_color_fit_min_improvement: float = setting(
        0.08, "that fit is applied only if, fitted on half of its frames, it lowers the squared colour error on "
        "the other half (and the other way round) by at least this fraction; else the map is left as it is "
        "(color_fit.py); 0: applied without that test", unit="fraction",
        trades="smaller: smaller corrections kept, which on a capture of one exposure cost the evaluated "
        "frames up to 0.16 dB (SUN3D); larger: only large exposure corrections (7-Scenes) kept")
    final_color_fit_prior: float = setting(
        0.03, "weight of identity (gain 1, offset 0) in that fit, per pixel of its frames (0: least squares)",
        unit="fraction", trades="larger: smaller corrections (its frames ask for more than evaluated ones need)")
    final_hole_fill: float = setting(
        0.0, "after the last frame (tracking finished: no pose moves), before that colour fit: Gaussians where "
        "the frames kept for the fits have no valid depth and the finished map is empty, at the farthest valid "
        "depth within this fraction of the image width, then only those optimised over the same frames "
        "(final_holes.py); 0 = off", unit="fraction of width",
        trades="larger: bigger holes get colour, at a guessed depth; on: the kept frames' depth is kept too "
        "(38.4 kB each at 320x240) and the pass adds seconds at the end")
    final_hole_fill_opacity: float = setting(0.95, "opacity of the hole fill's Gaussians", unit="opacity")
    final_hole_fill_iterations: int = setting(
        0, "passes over the kept frames optimising only the hole fill's Gaussians (colour, opacity, scale; "
        "the rest frozen); 0: as placed (the frame's colour)", unit="passes",
        trades="more: a few hundredths of a dB on 7-Scenes, nothing on SUN3D, for 3-4x the pass's seconds")


@dataclass
class DensifyConfig:
    silhouette_threshold: float = setting(0.5, "new Gaussians where the map's silhouette is below this",
                                          unit="fraction")
    depth_error_factor: float = setting(50.0, "new Gaussians in front of the map where the depth error exceeds "
                                        "this x the median error (\"new geometry in front\")")
    resolution_scale: float = setting(1.0, "densify at this fraction of the working resolution", unit="fraction",
                                      trades="smaller: fewer, larger new Gaussians: faster, a coarser map "
                                      "(splatam_s: 0.5)")
    initial_opacity: float = setting(0.5, "opacity of new Gaussians", unit="opacity")
    hole_fill: float = setting(0.0, "pixels without valid depth that the map leaves empty also get new Gaussians, "
                               "at the farthest valid depth within this fraction of the image width (a screen, "
                               "a dark or shiny patch, a depth shadow behind an edge); 0 = off (densify.py)",
                               unit="fraction of width",
                               trades="larger: bigger holes get colour, at a guessed depth")


@dataclass
class KeyframeConfig:
    every: int = setting(5, "frame 0, every n-th frame and one near the end (from_end) become keyframes", unit="frames",
                         trades="smaller: more keyframes to map from, more memory")
    from_end: int = setting(2, "on a capture of known length, the frame this many from its end is a keyframe too: 2 "
                            "(SplaTAM's) or 1, the last (`live`: one mapper step at the end, not two)", unit="frames")
    clock: KeyframeClock = setting("capture", "what `every` counts: capture frames at the run's stride (a frame "
                                   "dropped by --realtime or a stream counts; the first frame at or past every n-th "
                                   "becomes a keyframe) or processed frames; the same with every frame processed",
                                   trades="processed: fewer keyframes when frames are dropped, a map further behind "
                                   "the camera")
    selection: KeyframeSelection = setting("overlap", "the window's keyframes: the most overlapping (the paper: "
                                           "top-k) or a random subset of the overlapping ones (the original code)")
    overlap_samples: int = setting(1600, "pixels sampled to score a keyframe's overlap with the view",
                                   unit="pixels")
    overlap_border: int = setting(20, "a sample overlaps a keyframe when it lands this far inside its image",
                                  unit="pixels")
    overlap_within_depth: bool = setting(False, "a sample overlaps a keyframe only within the depth it measured "
                                         "(false: SplaTAM's test, no far limit)",
                                         trades="true: the window's cost does not grow along a corridor "
                                         "(docs/long-runs.md)")
    memory_mb: float = setting(512.0, "keyframe images kept in host memory; older ones are read from a file "
                               "(keyframes.py)", unit="MB", trades="smaller: less memory, more reads")


@dataclass
class LiveConfig:
    max_lag: int = setting(2, "frames the live engine's tracker may run ahead of the newest mapped frame (live.py)",
                           unit="frames", trades="larger: faster live tracking, a worse map (2 maps about 0.7 dB "
                           "worse than 1 on SUN3D fragment 2)")
    wait: bool = setting(True, "the live engine's tracker waits for the mapper (max_lag; and a frame lost against a "
                         "lagging map is tracked again once the map has caught up); false: it never waits after "
                         "frame 0 and tracks against the newest published map, the mapper maps the keyframes and "
                         "the newest frame of what was handed over (the `live` preset)",
                         trades="false: tracking at its own rate, frames between keyframes are not mapped")
    map: LiveMapping = setting("newest", "with wait false, what a mapper step maps: newest (the keyframes handed over "
                               "and the newest frame, optimised over the newest frame's window) or keyframes (only "
                               "keyframes: each keyframe optimised over its own window; between keyframes the "
                               "mapper idles and leaves the cores to the tracker; the `live` preset)",
                               trades="keyframes: a faster tracker, a map that is a keyframe interval behind")
    densify_between: bool = setting(False, "with map keyframes, a mapper step whose newest frame is not a keyframe "
                                    "still densifies from that frame (new Gaussians where the map lacks what it "
                                    "sees; no optimisation) and publishes the map, so the tracker's next frames "
                                    "find what came into view since the last keyframe (live.py)",
                                    trades="false: the tracker aligns against a map without what came into view "
                                    "since the last keyframe (the corridor's tracking failed: docs/benchmarks.md, "
                                    "Long runs); true: a render per mapper step more, and the tracker's reused "
                                    "render is renewed with each version")
    max_keyframe_lag: int | None = setting(None, "with wait false, the tracker waits while more than this many "
                                           "keyframes it handed over are not in the map yet (null: never)",
                                           unit="keyframes", trades="smaller: a tracker that never runs far ahead "
                                           "of its map (less drift), slower when the mapper cannot keep up")
    pace_keyframes: int | None = setting(None, "with wait false, a keyframe that falls due while this many "
                                         "keyframes handed over are not in the map yet is deferred: the first "
                                         "frame tracked after the mapper has caught up becomes the keyframe "
                                         "instead, and the tracker never waits for the mapper (keyframes come "
                                         "at the rate the mapper maps them; null: never deferred; pace_sources "
                                         "says on which inputs)", unit="keyframes",
                                         trades="set: a tracker that keeps the frame rate of a live source "
                                         "(--realtime, a stream), fewer keyframes when the mapper is slower than "
                                         "the keyframe interval")
    pace_sources: PaceSources = setting("live", "where pace_keyframes applies: live sources only (a stream, "
                                        "--realtime: a wait for the mapper drops frames) or every input (a "
                                        "capture read frame by frame too, where waiting drops nothing)",
                                        trades="all: no waits on a capture either, and fewer keyframes: SUN3D "
                                        "3-4 dB lower PSNR (docs/benchmarks.md, Live rate)")
    publish_densified: bool = setting(False, "the mapper publishes the map once more right after densifying from a "
                                      "frame, before optimising over its window: the tracker finds the newly "
                                      "seen parts a mapping step sooner", trades="true: one more copy of the map "
                                      "per keyframe; the tracker may track against Gaussians not yet optimised")
    hurry_coverage: float | None = setting(None, "where pace_keyframes applies: a keyframe's mapper step ends "
                                           "after hurry_iterations once a frame tracked after it was covered "
                                           "less than this share by its map (the camera leaves the map), so the "
                                           "keyframe owed meanwhile is mapped sooner (null: never)", trades="set: "
                                           "a map that keeps up with a pan; fewer iterations on its keyframes")
    hurry_iterations: int = setting(10, "a hurried mapper step's iterations (hurry_coverage)", unit="iterations")
    checkpoint: LiveCheckpoint = setting("drain", "a checkpoint of the live engine: drain (wait until every frame "
                                         "handed over is mapped, then save: the tracker stalls meanwhile) or "
                                         "published (the mapper saves its state after its next step, with the "
                                         "frames up to the newest one it mapped; the tracker never waits; a resume "
                                         "tracks the frames after it again; the `live` preset)",
                                         trades="published: no stall; a resume repeats the frames the mapper had "
                                         "not mapped")


@dataclass
class LostTrackingConfig:
    """When a tracked pose is not believed (relocalise.py) and how it is relocalised."""
    enabled: bool = setting(True, "detect lost frames and relocalise them (docs/lost-tracking.md)")
    loss_factor: float = setting(5.0, "lost: loss per pixel above this x the median of the recent tracked "
                                 "frames ...")
    loss_history: int = setting(10, "... over this many tracked frames", unit="frames")
    min_history: int = setting(3, "... once that many are known", unit="frames")
    loss_trend: int = setting(3, "... or, when higher, x the lowest loss per pixel of the last this many tracked "
                              "frames (a loss that rose over them all: the map ageing behind a moving camera, as "
                              "when the live mapper falls behind; 0: the median only)", unit="frames",
                              trades="0: a loss rising faster than the median follows is taken for a lost frame")
    min_coverage: float = setting(0.25, "lost: the map's silhouette covers less than this fraction of the loss's "
                                  "valid-depth pixels", unit="fraction")
    max_speed: float = setting(3.0, "lost: the camera moved faster than this since the last tracked frame ...",
                               unit="m/s")
    max_turn_rate_deg: float = setting(360.0, "... or turned faster; the time from the timestamps (--stride, "
                                       "skipped frames)", unit="degrees/s")
    recent_keyframes: int = setting(2, "relocalisation starts: the last tracked pose, this many newest "
                                    "keyframes ...", unit="keyframes")
    spread_keyframes: int = setting(3, "... and this many keyframes spread over the run", unit="keyframes",
                                    trades="more starts: relocalising a lost frame costs more, with more chances to find its pose")
    align_iterations: int = setting(10, "relocalisation aligns from each start by Gauss-Newton (at least this many "
                                    "iterations per level) ...", unit="iterations")
    align_passes: int = setting(3, "... rendering the map again this many times, so a jump is walked in steps",
                                unit="renders")


@dataclass
class LoopClosureConfig:
    """Online loop closure (splat_core/loop/, docs/loop-closure.md); off in the paper presets."""
    enabled: bool = setting(False, "close loops online (cpu and gpu: on)", trades="cost per frame within "
                            "run-to-run spread on the CPU; corrects drift on returns (docs/loop-closure.md)")
    min_gap_frames: int = setting(100, "a candidate keyframe is at least this many frames older than the current "
                                  "one", unit="frames")
    min_visible: float = setting(0.15, "candidate: this fraction of the current depth is explained by its old "
                                 "Gaussians ...", unit="fraction")
    min_orb_matches: int = setting(25, "... or ORB matches (ratio test) with it reach this many", unit="matches")
    max_candidates: int = setting(3, "candidates verified per keyframe (best first)", unit="keyframes")
    orb_by_map: int = setting(8, "ORB-matched per keyframe: the old keyframes the map names most ...",
                              unit="keyframes", trades="more: more candidates matched, more cost per keyframe")
    orb_sample: int = setting(8, "... and this many others spread over the run (random offset): per-keyframe cost "
                              "stays bounded however long the run", unit="keyframes")
    feature_cache: int = setting(32, "keyframes whose ORB features stay in memory (recomputed otherwise)",
                                 unit="keyframes", trades="larger: more memory, fewer recomputations")
    min_inliers: int = setting(12, "3D-3D RANSAC inliers (ORB matches with depth) to accept", unit="matches")
    min_inlier_ratio: float = setting(0.25, "... and at least this fraction of the ORB matches with depth", unit="fraction")
    inlier_distance: float = setting(0.04, "RANSAC inlier threshold", unit="metres")
    min_depth_agreement: float = setting(0.5, "the old keyframe's depth agrees with the current one at the loop's "
                                         "pose", unit="fraction")
    min_overlap: float = setting(0.3, "alignment: fraction of the frame's depth the old map explains",
                                 unit="fraction")
    max_rmse: float = setting(0.03, "alignment: point-to-plane RMS at most", unit="metres")
    max_disagreement: float = setting(0.05, "RANSAC and alignment agree within this ...", unit="metres")
    max_disagreement_deg: float = setting(3.0, "... and this", unit="degrees")
    min_correction: float = setting(0.03, "optimise the graph only when the loop disagrees by this with the current "
                                    "poses ... (at 1 cm: 7-Scenes' first 300 frames 1.30 -> 1.55 cm)", unit="metres")
    min_correction_deg: float = setting(1.0, "... or this", unit="degrees")
    odometry_sigma: float = setting(0.01, "pose graph: odometry noise per keyframe step (+ odometry_sigma_rel x "
                                    "the step's length)", unit="metres")
    odometry_sigma_rel: float = setting(0.05, "pose graph: odometry noise per metre of the step", unit="fraction")
    odometry_sigma_deg: float = setting(0.3, "pose graph: odometry rotation noise per keyframe step",
                                        unit="degrees")
    remap_iterations: int = setting(20, "mapping iterations over the loop's keyframes after a correction",
                                    unit="iterations", trades="more: a map more consistent with the corrected "
                                    "poses, a longer stall at each loop")
    cooldown_keyframes: int = setting(2, "keyframes without detection after an accepted loop", unit="keyframes")
    map_route: bool = setting(False, "verify candidates RANSAC cannot measure by aligning from the tracked pose "
                              "against the old map: not independent of tracking (on 7-Scenes the two corrections "
                              "it applied made the first 300 frames worse)")
