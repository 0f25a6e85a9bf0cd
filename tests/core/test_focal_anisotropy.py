"""benchmarks/focal_anisotropy.py (the colour/depth focal ratio per axis, from a capture's edges) and
benchmarks/capture_with_focal.py (a capture with other depth focal lengths)."""

from __future__ import annotations

import pytest

from benchmarks.focal_anisotropy import measure
from helpers.two_cameras import DEPTH_TO_COLOR, write_two_camera_tum
from splat_core.io import open_capture


@pytest.mark.parametrize("ratio", [(0.9, 0.9), (0.9, 0.94)])
def test_recovers_the_focal_ratio_of_each_axis(tmp_path, ratio):
    cap = write_two_camera_tum(tmp_path / "cap", n=5, ratio=ratio, describe=False)
    src = open_capture(cap.path)
    out = measure(src, list(range(len(src))), quotient=1.045 * ratio[0] / ratio[1], radial=True)   # 4.5 % off the truth
    assert out["rx"] == pytest.approx(ratio[0], rel=0.006)
    assert out["ry"] == pytest.approx(ratio[1], rel=0.006)
    assert out["rx_over_ry"] == pytest.approx(ratio[0] / ratio[1], rel=0.008)
    assert abs(out["tx_cm"] / 100 - DEPTH_TO_COLOR[0]) < 0.003
    # a wrong hypothesis about the quotient scores below the free best
    assert out["hypothesis"]["score"] < out["free_score"]
    # pinhole cameras: no distortion of one relative to the other (searched with one focal ratio,
    # so with the anisotropic colour camera k stands in for part of the anisotropy)
    if ratio[0] == ratio[1]:
        assert abs(out["radial"]["k"]) <= 0.01 and out["radial"]["profile"]["+0.0"] > out["radial"]["profile"]["+0.2"]


def test_a_capture_copy_with_other_focal_lengths(tmp_path):
    from benchmarks.capture_with_focal import copy_with_focal

    cap = write_two_camera_tum(tmp_path / "cap", n=2, describe=False)
    a = open_capture(cap.path)
    b = open_capture(copy_with_focal(cap.path, tmp_path / "copy", 0.95 * a.intrinsics.fx, a.intrinsics.fy))
    assert b.intrinsics.fx == pytest.approx(0.95 * a.intrinsics.fx) and b.intrinsics.fy == a.intrinsics.fy
    assert b.intrinsics.cx == a.intrinsics.cx and len(b) == len(a)
    assert (b[1].depth == a[1].depth).all() and (b[1].color == a[1].color).all()
