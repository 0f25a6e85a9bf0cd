"""splat_core/run/pose_arrays.py: a trajectory's inverses kept up to date as it grows and as poses
are replaced, the same bytes as inverting every pose each time."""

from __future__ import annotations

import numpy as np

from splat_core.camera import invert_pose, pose_matrix, quat_to_rotmat_np
from splat_core.run.pose_arrays import GrowingPoses, InverseTrajectory


def random_pose(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return pose_matrix(quat_to_rotmat_np(q / np.linalg.norm(q)), rng.normal(size=3))


def test_inverses_follow_appends_replacements_removals_and_a_new_list():
    rng = np.random.default_rng(5)
    inverses = InverseTrajectory()
    w2cs = [np.eye(4)]

    def check():
        want = np.stack([invert_pose(w) for w in w2cs]) if w2cs else np.zeros((0, 4, 4))
        got = inverses(w2cs)
        assert got.shape == (len(w2cs), 4, 4) and got.tobytes() == want.tobytes()
        return got

    first = check()
    for _ in range(40):                       # frames tracked (the buffer grows past its capacity)
        w2cs.append(random_pose(rng))
        check()
    w2cs[7] = random_pose(rng)                # a lost frame's pose filled in later
    for k in range(20, 41):                   # a loop correction moves every pose from frame 20 on
        w2cs[k] = w2cs[k] @ random_pose(rng)
    check()
    w2cs.pop()                                # a frame retracted
    check()
    w2cs = [random_pose(rng) for _ in range(5)]   # a resume: a new list
    check()
    w2cs = []
    check()
    assert first.tobytes() == np.eye(4)[None].tobytes() and first.flags.writeable   # a copy each call


def test_growing_poses_keep_their_rows_when_they_grow():
    g = GrowingPoses()
    g.resize(3)
    g.view()[:] = np.arange(3)[:, None, None]
    g.resize(100)
    assert len(g.view()) == 100 and (g.view()[:3, 0, 0] == [0, 1, 2]).all()
    g.resize(2)
    assert g.copy().shape == (2, 4, 4)
