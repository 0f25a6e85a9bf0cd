"""Run SplaTAM on a synthetic loop with drifting odometry, with or without loop closure, and measure
ATE and the map's depth error against the noise-free depth at every 10th frame's estimated pose
(its mean over pixels, which the tails of doubled surfaces and depth edges dominate, and its
median). Used by benchmarks/loops.py and tests/loop/test_loop_closure.py (benchmarks/ is on their
sys.path); a harness around the engine, so it lives here rather than in splat_core."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from splat_core import metrics as M
from splat_core.camera import invert_pose
from splat_core.config import Config
from splat_core.slam import SplaTAM
from splat_core.synthetic.loop import DriftingOdometry


def run_drifting(source, config: Config, loop_closure: bool, bias_m: float, bias_deg: float,
                 eval_every: int = 10) -> dict:
    config = dataclasses.replace(config, loop_closure=dataclasses.replace(config.loop_closure, enabled=loop_closure))
    slam = SplaTAM(config, source.intrinsics)
    slam.total_frames = len(source)
    odo = DriftingOdometry(source, bias_m, bias_deg)
    start = time.perf_counter()
    for t in range(len(source)):
        slam.process(source[t], w2c_given=odo.w2c(t, slam.w2cs))
    seconds = time.perf_counter() - start
    est = np.array([invert_pose(w) for w in slam.w2cs])
    ref = np.array(odo.ref)
    depth_err, depth_median = [], []
    g = slam.map.tensors(detach=True)
    for t in range(0, len(source), eval_every):
        _, exact = source.render_view(source.reference_c2w()[t])
        with torch.no_grad():      # at the estimated pose: a doubled surface shows as a depth error
            out = slam.renderer.render_visible(g, source.intrinsics, slam.w2cs[t])
        d, alpha = out.depth.cpu().numpy(), out.alpha.cpu().numpy()
        ok = (exact > 0) & (alpha > 0.5)
        err = np.abs(d[ok] / np.maximum(alpha[ok], 1e-6) - exact[ok])
        depth_err.append(float(np.mean(err)))
        depth_median.append(float(np.median(err)))
    return dict(loop_closure=loop_closure, frames=len(source), ate_rmse_cm=100 * M.ate_rmse(est, ref),
                ate_max_cm=100 * float(M.ate_errors(est, ref).max()),
                map_depth_error_cm=100 * float(np.mean(depth_err)),
                map_depth_error_median_cm=100 * float(np.mean(depth_median)), loops=[r.to_dict() for r in slam.loops],
                seconds=seconds, slam=slam)
