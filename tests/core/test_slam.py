"""SplaTAM end to end (slam.py through the Pipeline) on the synthetic sequence, CPU and CUDA."""

from __future__ import annotations

import pytest

from splat_core.config import load_config
from splat_core.synthetic import SyntheticSource


@pytest.mark.slow
def test_slam_on_a_synthetic_sequence_tracks_to_under_a_centimetre():
    # The cpu preset as shipped (320x240) on the benchmark's scene (seed 0). Lower resolutions bias
    # the rendered depth of a map of one-pixel Gaussians and give 1-2 cm; so does the harder camera
    # path of seed 3 (1.8 cm, see docs/history/2026-11-23-cpu-preset-tracking.md) - a known limit,
    # not hidden by this test.
    from splat_core.run import Pipeline
    pipe = Pipeline(SyntheticSource(n_frames=8, width=320, height=240, seed=0), load_config("cpu"))
    while pipe.step() is not None:
        pass
    assert pipe.ate_cm() < 1.0
    assert len(pipe.engine.slam.keyframes) == 3          # frames 0, 4, 6 (second to last)
    assert len(pipe.engine.slam.map) > 70000


@pytest.mark.cuda
@pytest.mark.slow
def test_slam_on_cuda_tracks_like_the_cpu():
    # The whole engine on the GPU (gsplat renderer, tensors on the device, keyframes on the host).
    from splat_core.run import Pipeline
    from splat_core.render import cuda
    reason = cuda.unavailable_reason()
    if reason is not None:
        pytest.skip(f"CUDA backend unavailable: {reason}")
    pipe = Pipeline(SyntheticSource(n_frames=8, width=320, height=240, seed=0), load_config("splatam_s"),
                    device="cuda")
    while pipe.step() is not None:
        pass
    assert pipe.engine.slam.map.device.type == "cuda"
    assert pipe.ate_cm() < 1.0
