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
        move keyframes, frame poses and Gaussians   by their keyframe's correction (anchors.py)
        re-map the loop's keyframes briefly         the seams

State (odometry and loop edges, accepted loops, the cool-down) goes into the checkpoint as JSON;
the anchors are the Gaussians' birth frames, already in the map. Randomness comes from a
generator seeded by (seed, frame number), and ORB features are recomputed from the keyframes' stored
images, so a resumed sequential run closes the same loops bit for bit.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections import OrderedDict

import numpy as np
import torch

from ..camera import invert_pose
from ..config import LoopClosureConfig
from ..gaussians import Gaussians
from ..tracking import align_options
from . import anchors, detect, pose_graph
from .verify import pose_difference, verify


def verification_align(slam) -> dict:
    """The tracker's alignment settings with a longer reach (at least 10 iterations per level, two
    renders): verification aligns from RANSAC's pose, farther off than a tracking prediction.
    It aligns on the host (the Numba backend) whatever tracking.align.backend says."""
    tc = slam.config.tracking
    return align_options(tc, slam.intrinsics, slam.renderer.near, iterations=max(10, tc.align.iterations), passes=2,
                         backend="numba")


class LoopClosure:
    def __init__(self, config: LoopClosureConfig, seed: int = 0):
        self.config, self.seed = config, seed
        self.edges: list[pose_graph.Edge] = []      # odometry and loop edges between keyframe positions
        self.loops: list[dict] = []                 # accepted loops with their evidence
        self.rejected = 0                           # candidates verification turned down
        self.rejected_by: dict[str, int] = {}       # ... per failed test (verify.Verdict.reason)
        self.quiet_until = -1                       # keyframe position before which nothing is detected
        self._features: OrderedDict[int, detect.Features] = OrderedDict()   # LRU, config.feature_cache
        self.apply_lock = contextlib.nullcontext    # a context per correction; the live engine's holds its pose lock

    # -------------------------------------------------------------- one keyframe
    def after_keyframe(self, slam, frame_index: int) -> list[dict]:
        """Called once keyframe `frame_index` was mapped (the sequential engine at once, the live
        engine's mapper for each keyframe of its batch, in order, possibly after newer ones were
        mapped); returns the loops accepted now (at most one)."""
        kfs = list(slam.keyframes)
        j = next((p for p in range(len(kfs) - 1, -1, -1) if kfs[p].frame_index == frame_index), None)
        if j is None:
            return []
        c = self.config
        self.link(kfs, j)
        if j < self.quiet_until or c.max_candidates == 0:
            return []
        frames = np.array([kf.frame_index for kf in kfs], np.int64)
        old = np.flatnonzero(frames <= frame_index - c.min_gap_frames)
        if old.size == 0:
            return []
        start = time.perf_counter()
        current = kfs[j]
        depth = current.depth
        means = slam.map.means.detach().cpu().numpy()
        owner = detect.birth_keyframe(slam.map.birth_frame.cpu().numpy(), frames)
        visible = detect.visible_by_keyframe(means, owner, len(kfs), depth, current.w2c, slam.intrinsics)
        feats = self.features(j, current)
        orb = np.zeros(len(kfs))
        sample = np.random.default_rng([self.seed, frame_index, 11])
        for k in detect.orb_partners(old, visible, c.orb_by_map, c.orb_sample, sample):
            orb[k] = len(detect.match(feats, self.features(int(k), kfs[k])))
        picks = detect.candidates(j, frames, visible, orb, c.min_gap_frames, c.min_visible, c.min_orb_matches,
                                  c.max_candidates)
        if not picks:
            return []
        rng = np.random.default_rng([self.seed, frame_index, 7])
        color = current.color
        old_map = self.old_part(slam, frame_index)          # the same for every candidate
        for k in picks:
            verdict = self._verify(slam, kfs, j, k, feats, color, depth, old_map, rng, visible[k])
            if verdict.accepted:
                record = self._close(slam, kfs, j, k, verdict, visible[k], orb[k], start)
                self.quiet_until = j + 1 + c.cooldown_keyframes
                return [record]
            self.rejected += 1
            self.rejected_by[verdict.reason] = self.rejected_by.get(verdict.reason, 0) + 1
        return []

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

    def old_part(self, slam, frame_index: int) -> Gaussians:
        """The Gaussians born at least min_gap_frames before frame_index (what verification aligns to)."""
        keep = slam.map.birth_frame <= frame_index - self.config.min_gap_frames
        g = slam.map.tensors(detach=True)
        idx = torch.nonzero(keep.to(g.means.device)).flatten()
        return Gaussians(*(x[idx] for x in (g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales)))

    def _verify(self, slam, kfs, j, k, feats, color, depth, old_map, rng, visible_k):
        old_kf = kfs[k]
        estimate = self.map_route_start(kfs[j], visible_k)
        return verify((feats, color, depth), (self.features(k, old_kf), None, old_kf.depth), invert_pose(old_kf.w2c),
                      old_map, slam.intrinsics, self.config, rng, verification_align(slam), estimate)

    def map_route_start(self, current, visible_k: float) -> np.ndarray | None:
        """Where verification starts when RANSAC finds too little: the tracked pose, if the map route
        is on and the old keyframe's Gaussians cover enough of the view; else None (no loop). The map
        route measures from the tracked pose against part of the map that tracking used, so it is
        off by default."""
        c = self.config
        return invert_pose(current.w2c) if c.map_route and visible_k >= c.min_visible else None

    def _close(self, slam, kfs, j, k, verdict, visible, orb, start) -> dict:
        c = self.config
        c2w_old, c2w_cur = invert_pose(kfs[k].w2c), invert_pose(kfs[j].w2c)
        measured = invert_pose(c2w_old) @ verdict.c2w_current
        sigma_m = float(np.clip(verdict.evidence["rmse_m"], 0.003, 0.02))
        self.edges.append(pose_graph.Edge(k, j, measured, sigma_m, 0.3, robust=True))
        dt, dr = pose_difference(c2w_cur, verdict.c2w_current)
        applied = dt > c.min_correction or dr > c.min_correction_deg
        moved_m = moved_deg = locked = 0.0
        inconsistent: list = []
        if applied:
            old_c2ws = [invert_pose(kf.w2c) for kf in kfs]
            new_c2ws, robust = pose_graph.optimise(old_c2ws, self.edges)
            inconsistent = [self.edges[n].a for n in robust]
            moved_m, moved_deg = pose_difference(old_c2ws[j], new_c2ws[j])
            with self.apply_lock():                 # the live engine's also publishes the moved map
                held = time.perf_counter()
                self.apply(slam, kfs, old_c2ws, new_c2ws)
            locked = time.perf_counter() - held     # what the live tracker may wait
            self.remap(slam, kfs, j, k)
        record = dict(keyframes=[int(k), int(j)], frames=[kfs[k].frame_index, kfs[j].frame_index],
                      inliers=verdict.evidence["inliers"], evidence=verdict.evidence,
                      visible=float(visible), orb_matches=int(orb),
                      disagreement_cm=100 * dt, disagreement_deg=dr, applied=bool(applied),
                      correction_cm=100 * moved_m, correction_deg=moved_deg, inconsistent_loops=inconsistent,
                      seconds=time.perf_counter() - start, apply_seconds=locked)
        self.loops.append(record)
        return record

    @staticmethod
    def apply(slam, kfs, old_c2ws, new_c2ws) -> None:
        """Move keyframes, frame poses and Gaussians by the keyframes' corrections."""
        frames = np.array([kf.frame_index for kf in kfs], np.int64)
        C = anchors.corrections(old_c2ws, new_c2ws)
        for kf, c2w in zip(kfs, new_c2ws):
            kf.w2c = invert_pose(c2w)
        anchors.move_poses(slam.w2cs, frames, C)
        anchors.move_gaussians(slam.map, frames, C)

    def remap(self, slam, kfs, j, k) -> None:
        """A short mapping run over the loop's two keyframes and their neighbours."""
        if self.config.remap_iterations == 0:
            return
        near = [p for p in (j, j - 1, k, k + 1, k - 1, j - 2) if 0 <= p < len(kfs)]
        chosen = list(dict.fromkeys(near))[: slam.config.mapping.window_size]
        slam.optimise([slam.keyframe_view(kfs[p]) for p in chosen], iterations=self.config.remap_iterations)

    # -------------------------------------------------------------- checkpoints
    def state(self) -> str:
        return json.dumps(dict(edges=[e.to_dict() for e in self.edges], loops=self.loops, rejected=self.rejected,
                               rejected_by=self.rejected_by, quiet_until=self.quiet_until))

    def load_state(self, state: str) -> None:
        s = json.loads(state)
        self.edges = [pose_graph.Edge.from_dict(e) for e in s["edges"]]
        self.loops, self.rejected, self.quiet_until = list(s["loops"]), int(s["rejected"]), int(s["quiet_until"])
        self.rejected_by = dict(s.get("rejected_by", {}))
        self._features.clear()

