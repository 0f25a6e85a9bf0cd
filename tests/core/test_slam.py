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


def test_lost_frames_follow_appended_records_and_a_resume():
    """Pipeline.lost reads each record once (the viewer asks after every frame): the same list as
    reading them all, after appends and after a resume's new list."""
    from splat_core.run import Pipeline
    pipe = Pipeline(SyntheticSource(n_frames=4, width=64, height=48, seed=0), load_config("cpu"))

    def record(k, lost=None):
        return dict(index=k, source_index=2 * k, lost=lost)

    def expected():
        return [dict(index=r["index"], source_index=r["source_index"], reason=r["lost"]) for r in pipe.records if r["lost"]]

    assert pipe.lost == []
    pipe.records.extend([record(0), record(1, "coverage"), record(2)])
    assert pipe.lost == expected() and len(expected()) == 1
    pipe.records.extend([record(3, "loss"), record(4)])
    assert pipe.lost == expected() and len(expected()) == 2
    lost = pipe.lost
    lost.clear()                                             # a caller's copy, not the pipeline's list
    assert pipe.lost == expected()
    pipe.records = [record(0, "coverage")]                   # a resume's records
    assert pipe.lost == expected() == [dict(index=0, source_index=0, reason="coverage")]


def test_reference_poses_in_the_slam_world_follow_appends_and_a_resume():
    """Pipeline.reference_c2w (and _array) converts only the frames added since it was last asked (a
    viewer asks after every frame): the same poses as converting them all, also after the list is
    replaced."""
    import numpy as np

    from splat_core.camera import pose_matrix, quat_to_rotmat_np
    from splat_core.run import Pipeline
    pipe = Pipeline(SyntheticSource(n_frames=4, width=64, height=48, seed=0), load_config("cpu"))
    rng = np.random.default_rng(3)

    def pose():
        q = rng.normal(size=4)
        return pose_matrix(quat_to_rotmat_np(q / np.linalg.norm(q)), rng.normal(size=3))

    def expected():
        return [pipe._reference_world(r, pipe.references[0]) for r in pipe.references]

    def same(got, want):
        rows = pipe.reference_c2w_array()                   # the same poses, NaN rows for none
        return len(got) == len(want) == len(rows) and all(
            (a is None and b is None and np.isnan(r).all()) or (np.array_equal(a, b) and np.array_equal(r, b))
            for a, b, r in zip(got, want, rows))

    assert pipe.reference_c2w() is None and pipe.reference_c2w_array() is None
    pipe.references.extend([pose(), None, pose()])
    assert same(pipe.reference_c2w(), expected())
    pipe.references.extend([pose(), pose()])                 # frames tracked since
    assert same(pipe.reference_c2w(), expected())
    assert np.allclose(pipe.reference_c2w()[0], np.eye(4))
    pipe.references = [pose(), pose()]                       # a resume's list
    assert same(pipe.reference_c2w(), expected())
    pipe.references[0] = pose()                              # another first frame
    assert same(pipe.reference_c2w(), expected())
