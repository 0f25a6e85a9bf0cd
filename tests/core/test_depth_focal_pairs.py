"""benchmarks/depth_focal_pairs.py on exact synthetic depth: at the focal length the depth was rendered
with, ICP of depth pairs reproduces the exact motion; told a focal length 6 % too long in x, the
motion it finds along the camera's x is off by several per cent (issue 44: a depth focal length
error changes the motion that depth alone measures; its direction depends on the path)."""

from __future__ import annotations

import numpy as np
import pytest


def test_depth_pairs_measure_the_motion_at_the_true_focal_length_and_not_at_a_wrong_one():
    pytest.importorskip("open3d")
    from depth_focal_pairs import pair_motions

    from splat_core.camera import Intrinsics
    from splat_core.synthetic import SyntheticSource

    source = SyntheticSource(n_frames=41)
    pairs = [(0, 10), (10, 20), (20, 30), (30, 40)]
    depths = {k: np.asarray(source[k].depth, dtype=np.float64) for pair in pairs for k in pair}
    exact = {"exact": source.reference_c2w()}
    i = source.intrinsics
    true = pair_motions(depths, exact, pairs, i)["exact"]
    wrong = pair_motions(depths, exact, pairs, Intrinsics(i.fx * 1.06, i.fy, i.cx, i.cy, i.width, i.height))["exact"]
    assert true["rms_cm"] < 0.5 and abs(true["slope_x"] - 1) < 0.02
    assert abs(wrong["slope_x"] - 1) > 0.03
    assert wrong["rms_cm"] > 2 * true["rms_cm"]
