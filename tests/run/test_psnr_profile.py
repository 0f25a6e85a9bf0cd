"""benchmarks/psnr_profile.py: the figure of record and the original code's depth-masked PSNR."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import psnr_profile  # noqa: E402

from splat_core import metrics as M  # noqa: E402


def _frame(seed=0, h=12, w=16):
    rng = np.random.default_rng(seed)
    color = rng.uniform(0, 1, (h, w, 3))
    render = np.clip(color + rng.normal(0, 0.05, (h, w, 3)), 0, 1)
    depth = rng.uniform(0.5, 3.0, (h, w))
    return render, color, depth


def test_masked_equals_record_when_every_pixel_has_depth():
    render, color, depth = _frame()
    row = psnr_profile.profile_frame(render, np.ones(depth.shape), color, depth)
    assert np.isclose(row["psnr"], M.psnr(render, color))
    assert np.isclose(row["masked"], row["psnr"])


def test_masked_counts_pixels_without_depth_as_exact_but_keeps_them_in_the_mean():
    render, color, depth = _frame(1)
    depth[:, :4] = 0.0                      # a quarter of the pixels without depth
    render[:, :4] = 1.0 - color[:, :4]      # and badly rendered there
    row = psnr_profile.profile_frame(render, np.ones(depth.shape), color, depth)
    sq = ((render - color) ** 2).mean(axis=2)
    expected = -10 * np.log10(sq[:, 4:].sum() / sq.size)
    assert np.isclose(row["masked"], expected)
    assert np.isclose(row["psnr"], M.psnr(render, color))
    assert row["masked"] > row["psnr"] + 3.0     # the holes' error is what the masked figure leaves out
