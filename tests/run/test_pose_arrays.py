"""splat_core/run/pose_arrays.py: a trajectory's inverses kept up to date as it grows and as poses
are replaced, the same bytes as inverting every pose each time."""

from __future__ import annotations

import numpy as np

from splat_core.camera import invert_pose, pose_matrix, quat_to_rotmat_np
from splat_core.run.pose_arrays import GrowingArray, InverseTrajectory


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
    g = GrowingArray()
    g.resize(3)
    g.view()[:] = np.arange(3)[:, None, None]
    g.resize(100)
    assert len(g.view()) == 100 and (g.view()[:3, 0, 0] == [0, 1, 2]).all()
    g.resize(2)
    assert g.copy().shape == (2, 4, 4)


def test_history_series_grow_and_publish_read_only_copies():
    """The viewer worker's history (app/worker.py): a series appended once a frame, an entry set
    later (a PSNR arriving after its frame), published as read-only copies (app.snapshot.frozen)."""
    from app.snapshot import frozen

    s = GrowingArray(())
    for k in range(40):                        # past its first capacity
        s.append(float(k))
    first = frozen(s.view())
    s.view()[len(s.view()) - 1] = -1.0         # a PSNR arriving after its frame
    s.append(np.nan)
    assert len(s.view()) == 41 and s.view()[39] == -1.0 and np.isnan(frozen(s.view())[-1])
    assert first[39] == 39.0 and not first.flags.writeable      # what was published stays as it was
    assert (frozen(s.view())[:39] == np.arange(39)).all()
