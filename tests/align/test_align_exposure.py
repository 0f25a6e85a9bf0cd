"""tracking.align.exposure (issue 44's candidate): one brightness gain per frame between the live
image and the rendered map before the photometric term."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splat_core.camera import invert_pose
from splat_core.config import MappingConfig, load_config
from splat_core.mapping import View, optimise_map
from splat_core.synthetic import SyntheticSource
from splat_core.tracking import align_options

from helpers.engine import map_from_frame, rel_w2c


def test_exposure_gain_is_the_brightness_ratio_on_the_mask_clipped():
    from splat_core.align.numba_backend import exposure_gain
    live = np.full((20, 20), 0.3)
    model = np.full((20, 20), 0.5)
    mask = np.zeros((20, 20), bool)
    mask[:10] = True
    model[10:] = 5.0                                  # outside the mask: ignored
    assert exposure_gain(live, model, mask) == pytest.approx(0.6)
    assert exposure_gain(torch.as_tensor(live), torch.as_tensor(model), torch.as_tensor(mask)) == pytest.approx(0.6)
    assert exposure_gain(live, 0.01 * model, mask) == 2.0        # clipped
    assert exposure_gain(live, model, np.zeros_like(mask)) == 1.0  # too few pixels
    assert exposure_gain(0 * live, model, mask) == 1.0            # no brightness


def test_the_setting_reaches_the_alignment_off_by_default():
    config = load_config("cpu")
    assert config.tracking.align.exposure is False
    assert align_options(config.tracking, SyntheticSource(n_frames=1, width=32, height=24)[0].intrinsics,
                         0.01)["exposure"] is False
    on = load_config("cpu", {"tracking": {"align": {"exposure": True}}})
    assert align_options(on.tracking, SyntheticSource(n_frames=1, width=32, height=24)[0].intrinsics,
                         0.01)["exposure"] is True


@pytest.fixture(scope="module")
def scene():
    src = SyntheticSource(n_frames=4, width=160, height=120, seed=0)
    f0 = src[0]
    m = map_from_frame(f0)
    view = View(torch.as_tensor(f0.color), torch.as_tensor(f0.depth), np.eye(4))
    optimise_map(m, [view], f0.intrinsics, MappingConfig(), 60, 2.0, np.random.default_rng(0))
    return src, m.tensors(detach=True)


def _error(scene, gain: float, exposure: bool, backend: str = "numba") -> float:
    from splat_core.align import align_to_map
    src, g = scene
    f = src[3]
    out = align_to_map(g, np.clip(gain * f.color, 0, 1), f.depth, f.intrinsics, np.eye(4), backend=backend,
                       iterations=10, passes=2, color_weight=1.0, exposure=exposure)
    centre = lambda w2c: invert_pose(w2c)[:3, 3]  # noqa: E731
    return float(np.linalg.norm(centre(out.w2c) - centre(rel_w2c(src, 3))))


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_a_darker_frame_aligns_as_well_as_the_same_frame_at_the_map_exposure(scene, backend):
    same = _error(scene, 1.0, True, backend)
    darker = _error(scene, 0.6, True, backend)
    assert same < 0.005 and darker < 0.005, (same, darker)
    assert abs(darker - same) < 0.002
    # With the gain the darker frame does at least as well as without it.
    assert darker <= _error(scene, 0.6, False, backend) + 1e-4
