"""Online loop closure, run after each new keyframe (inline in the sequential engine, in the mapper
thread of the live engine):

    graph.add(odometry edge: previous keyframe -> this one)
    old    = detect(this keyframe)                  old keyframes it sees again / looks like (detect.py;
                                                    ORB against a bounded set, features in an LRU cache)
    loop   = verify(this keyframe, old)             ORB + depth RANSAC, then the tracker's alignment
                                                    against the old map (verify.py); strict
    graph.add(loop edge)
    if the loop disagrees with the current poses:
        c2ws = optimise(graph)                      gtsam, robust kernels (pose_graph.py)
    return LoopFound(record, Correction)            SplaTAM moves keyframes, frame poses and Gaussians
                                                    by their keyframe's correction (anchors.py) and
                                                    re-maps the loop's keyframes briefly (the seams)

Loop closure reads SplaTAM's state through a SlamView and never writes it: SplaTAM (slam.py)
applies the correction, under whatever lock its engine chooses.

State (odometry and loop edges, rejection counts, the cool-down) goes into the checkpoint as JSON;
the anchors are the Gaussians' birth frames, already in the map. Randomness comes from a
generator seeded by (seed, frame number), and ORB features are recomputed from the keyframes' stored
images, so a resumed sequential run closes the same loops bit for bit.
"""

from __future__ import annotations

import json
from collections import OrderedDict

import numpy as np
import torch

from ..camera import invert_pose
from ..config import LoopClosureConfig
from ..gaussians import Gaussians
from ..slam_state import SlamView
from ..tracking import align_options
from . import detect, pose_graph
from .records import Correction, LoopFound, LoopRecord
from .verify import pose_difference, verify


def verification_align(view: SlamView) -> dict:
    """The tracker's alignment settings with a longer reach (at least 10 iterations per level, two
    renders): verification aligns from RANSAC's pose, farther off than a tracking prediction.
    It aligns on the host (the Numba backend) whatever tracking.align.backend says."""
    tc = view.config.tracking
    return align_options(tc, view.intrinsics, view.near, iterations=max(10, tc.align.iterations), passes=2,
                         backend="numba")


class LoopClosure:
    def __init__(self, config: LoopClosureConfig, seed: int = 0):
        self.config, self.seed = config, seed
        self.edges: list[pose_graph.Edge] = []      # odometry and loop edges between keyframe positions
        self.rejected = 0                           # candidates verification turned down
        self.rejected_by: dict[str, int] = {}       # ... per failed test (verify.Verdict.reason)
        self.quiet_until = -1                       # keyframe position before which nothing is detected
        self._features: OrderedDict[int, detect.Features] = OrderedDict()   # LRU, config.feature_cache

    # -------------------------------------------------------------- one keyframe
    def after_keyframe(self, view: SlamView, frame_index: int) -> LoopFound | None:
        """Called once keyframe `frame_index` was mapped (the sequential engine at once, the live
        engine's mapper for each keyframe of its batch, in order, possibly after newer ones were
        mapped); the loop accepted now, if any, with the correction for SplaTAM to apply."""
        kfs = list(view.keyframes)
        j = next((p for p in range(len(kfs) - 1, -1, -1) if kfs[p].frame_index == frame_index), None)
        if j is None:
            return None
        c = self.config
        self.link(kfs, j)
        if j < self.quiet_until or c.max_candidates == 0:
            return None
        frames = np.array([kf.frame_index for kf in kfs], np.int64)
        old = np.flatnonzero(frames <= frame_index - c.min_gap_frames)
        if old.size == 0:
            return None
        current = kfs[j]
        depth = current.depth
        means = view.gaussians.means.cpu().numpy()
        owner = detect.birth_keyframe(view.birth_frame.cpu().numpy(), frames)
        visible = detect.visible_by_keyframe(means, owner, len(kfs), depth, current.w2c, view.intrinsics)
        feats = self.features(j, current)
        orb = np.zeros(len(kfs))
        sample = np.random.default_rng([self.seed, frame_index, 11])
        for k in detect.orb_partners(old, visible, c.orb_by_map, c.orb_sample, sample):
            orb[k] = len(detect.match(feats, self.features(int(k), kfs[k])))
        picks = detect.candidates(j, frames, visible, orb, c.min_gap_frames, c.min_visible, c.min_orb_matches,
                                  c.max_candidates)
        if not picks:
            return None
        rng = np.random.default_rng([self.seed, frame_index, 7])
        color = current.color
        old_map = self.old_part(view, frame_index)          # the same for every candidate
        for k in picks:
            verdict = self._verify(view, kfs, j, k, feats, color, depth, old_map, rng, visible[k])
            if verdict.accepted:
                self.quiet_until = j + 1 + c.cooldown_keyframes
                return self._close(view, kfs, j, k, verdict, visible[k], orb[k])
            self.rejected += 1
            self.rejected_by[verdict.reason] = self.rejected_by.get(verdict.reason, 0) + 1
        return None

    def link(self, kfs, j: int) -> None:
        """Odometry edges up to keyframe position j: every keyframe is linked to the one before it,
        whichever keyframes loop detection runs on (the graph stays one connected chain)."""
        c = self.config
        for p in range(self.linked + 1, j + 1):
            self.edges.append(pose_graph.odometry_edge(p - 1, p, invert_pose(kfs[p - 1].w2c), invert_pose(kfs[p].w2c),
                                                       c.odometry_sigma, c.odometry_sigma_rel, c.odometry_sigma_deg))

    @property
    def linked(self) -> int:
        """The newest keyframe position that has its odometry edge (0: none yet)."""
        return max((e.b for e in self.edges if not e.robust), default=0)

    def features(self, k: int, kf) -> detect.Features:
        """Keyframe position k's ORB features, from a bounded LRU cache (recomputed from the keyframe's
        stored image, deterministic, when evicted)."""
        if k in self._features:
            self._features.move_to_end(k)
        else:
            self._features[k] = detect.orb_features(kf.images8()[0])
            while len(self._features) > self.config.feature_cache:
                self._features.popitem(last=False)
        return self._features[k]

    def old_part(self, view: SlamView, frame_index: int) -> Gaussians:
        """The Gaussians born at least min_gap_frames before frame_index (what verification aligns to)."""
        keep = view.birth_frame <= frame_index - self.config.min_gap_frames
        g = view.gaussians
        idx = torch.nonzero(keep.to(g.means.device)).flatten()
        return Gaussians(*(x[idx] for x in (g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales)))

    def _verify(self, view: SlamView, kfs, j, k, feats, color, depth, old_map, rng, visible_k):
        old_kf = kfs[k]
        estimate = self.map_route_start(kfs[j], visible_k)
        return verify((feats, color, depth), (self.features(k, old_kf), None, old_kf.depth), invert_pose(old_kf.w2c),
                      old_map, view.intrinsics, self.config, rng, verification_align(view), estimate)

    def map_route_start(self, current, visible_k: float) -> np.ndarray | None:
        """Where verification starts when RANSAC finds too little: the tracked pose, if the map route
        is on and the old keyframe's Gaussians cover enough of the view; else None (no loop). The map
        route measures from the tracked pose against part of the map that tracking used, so it is
        off by default."""
        c = self.config
        return invert_pose(current.w2c) if c.map_route and visible_k >= c.min_visible else None

    def _close(self, view: SlamView, kfs, j, k, verdict, visible, orb) -> LoopFound:
        """The loop edge joins the graph; if the loop disagrees with the poses, the graph's new poses
        are the correction (applied by SplaTAM)."""
        c = self.config
        c2w_old, c2w_cur = invert_pose(kfs[k].w2c), invert_pose(kfs[j].w2c)
        measured = invert_pose(c2w_old) @ verdict.c2w_current
        sigma_m = float(np.clip(verdict.evidence["rmse_m"], 0.003, 0.02))
        self.edges.append(pose_graph.Edge(k, j, measured, sigma_m, 0.3, robust=True))
        dt, dr = pose_difference(c2w_cur, verdict.c2w_current)
        applied = dt > c.min_correction or dr > c.min_correction_deg
        moved_m = moved_deg = 0.0
        inconsistent: list = []
        correction = None
        if applied:
            old_c2ws = [invert_pose(kf.w2c) for kf in kfs]
            new_c2ws, robust = pose_graph.optimise(old_c2ws, self.edges)
            inconsistent = [self.edges[n].a for n in robust]
            moved_m, moved_deg = pose_difference(old_c2ws[j], new_c2ws[j])
            correction = Correction(np.array([kf.frame_index for kf in kfs], np.int64), old_c2ws, new_c2ws,
                                    self.remap_keyframes(j, k, len(kfs), view.config.mapping.window_size),
                                    c.remap_iterations)
        record = LoopRecord(keyframes=(int(k), int(j)), frames=(kfs[k].frame_index, kfs[j].frame_index),
                            inliers=verdict.evidence["inliers"], evidence=verdict.evidence,
                            visible=float(visible), orb_matches=int(orb),
                            disagreement_cm=100 * dt, disagreement_deg=dr, applied=bool(applied),
                            correction_cm=100 * moved_m, correction_deg=moved_deg,
                            inconsistent_loops=tuple(inconsistent))
        return LoopFound(record, correction)

    def remap_keyframes(self, j: int, k: int, count: int, window_size: int) -> tuple:
        """The loop's two keyframes and their neighbours (positions), at most a mapping window's worth;
        none when re-mapping is off."""
        if self.config.remap_iterations == 0:
            return ()
        near = [p for p in (j, j - 1, k, k + 1, k - 1, j - 2) if 0 <= p < count]
        return tuple(list(dict.fromkeys(near))[:window_size])

    # -------------------------------------------------------------- checkpoints
    def state(self) -> str:
        return json.dumps(dict(edges=[e.to_dict() for e in self.edges], rejected=self.rejected,
                               rejected_by=self.rejected_by, quiet_until=self.quiet_until))

    def load_state(self, state: str) -> None:
        s = json.loads(state)
        self.edges = [pose_graph.Edge.from_dict(e) for e in s["edges"]]
        self.rejected, self.quiet_until = int(s["rejected"]), int(s["quiet_until"])
        self.rejected_by = dict(s.get("rejected_by", {}))
        self._features.clear()

