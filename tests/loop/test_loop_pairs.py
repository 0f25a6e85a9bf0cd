"""benchmarks/loop_pairs.py: depth-only registration of a revisit recovers the exact relative pose
from a start centimetres off, and the revisit pairs come from the reference's poses."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from splat_core.loop.verify import pose_difference  # noqa: E402
from splat_core.synthetic.loop import LoopSource  # noqa: E402


def test_revisits_are_reference_pairs_apart_and_close():
    import loop_pairs

    source = LoopSource(n_frames=60, width=128, height=96, overlap=0.4)
    ref = np.asarray(source.reference_c2w())
    pairs = loop_pairs.revisits(ref, gap=30, count=5)
    assert 0 < len(pairs) <= 5
    for a, b in pairs:
        cm, deg = pose_difference(ref[a], ref[b])
        assert b - a >= 30 and cm < 0.3 and deg < 20


def test_depth_icp_recovers_the_exact_relative_pose_from_a_wrong_start():
    pytest.importorskip("open3d", reason="open3d is in the bench extra")
    import loop_pairs

    source = LoopSource(n_frames=60, width=320, height=240, overlap=0.4)
    ref = np.asarray(source.reference_c2w())
    a, b = 10, 11
    exact = np.linalg.inv(ref[a]) @ ref[b]
    start = exact.copy()
    start[:3, 3] += [0.03, -0.02, 0.01]            # 3.7 cm off, as a drifted run would be
    intr = source.intrinsics
    clouds = [loop_pairs.cloud(source[k].depth, intr, 0.01) for k in (b, a)]
    T, fitness, _ = loop_pairs.icp(*clouds, start)
    cm, deg = pose_difference(T, exact)
    assert fitness > 0.3
    assert cm < 0.5 and deg < 0.5, (cm, deg)
