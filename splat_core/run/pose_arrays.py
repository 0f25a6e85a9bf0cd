"""Per-frame pose arrays that grow with a run, each pose converted once.

    inverses = InverseTrajectory()
    c2w = inverses(engine.trajectory())          # (n, 4, 4): only new or moved poses inverted
    refs = ReferenceWorld()
    refs.update(references, to_world)            # the frames added since the last call
    refs.poses, refs.rows.copy()                 # a list (None: no reference) / (n, 4, 4), NaN rows

Why: the viewer's worker asks for the whole trajectory and the reference poses after every frame
(app/worker.py). Converting every pose each time made its bookkeeping grow with the run: 30 ms a
frame by frame 1000 (docs/history/2026-12-07-viewer-rate-and-worker.md).
"""

from __future__ import annotations

import operator

import numpy as np

from ..camera import invert_poses


class GrowingArray:
    """An array of rows of one shape ((4, 4) poses by default, () for a series of numbers) whose
    length changes at its end; capacity doubles, so a row costs amortised O(1). `view()` is the
    filled part (rows settable), `copy()` a copy of it."""

    def __init__(self, row_shape: tuple = (4, 4)):
        self._buf = np.zeros((0, *row_shape))
        self.n = 0

    def resize(self, n: int) -> None:
        if n > len(self._buf):
            grown = np.zeros((max(n, 2 * len(self._buf), 16), *self._buf.shape[1:]))
            grown[:self.n] = self._buf[:self.n]
            self._buf = grown
        self.n = n

    def append(self, row) -> None:
        self.resize(self.n + 1)
        self._buf[self.n - 1] = row

    def view(self) -> np.ndarray:
        return self._buf[:self.n]

    def copy(self) -> np.ndarray:
        return self._buf[:self.n].copy()


class InverseTrajectory:
    """The inverses (camera.invert_poses: invert_pose's numbers) of a pose list that grows at its
    end and whose entries are replaced, never changed in place, when a pose moves: the engines'
    trajectories (slam.py assigns a new array to a frame that lost tracking, loop/anchors.py
    move_poses to every frame a loop correction moves; a resume makes a new list). Each call
    inverts only the entries it has not seen, found by identity."""

    def __init__(self):
        self._seen: list = []
        self._out = GrowingArray()

    def __call__(self, poses: list) -> np.ndarray:
        n, m = len(poses), min(len(poses), len(self._seen))
        moved = np.flatnonzero(np.fromiter(map(operator.is_not, poses[:m], self._seen[:m]), bool, m))
        todo = np.concatenate([moved, np.arange(m, n)])
        self._out.resize(n)
        if len(todo):
            self._out.view()[todo] = invert_poses([poses[i] for i in todo])
        self._seen = list(poses)       # holds the arrays: an id is never reused while we compare
        return self._out.copy()


class ReferenceWorld:
    """Reference poses converted into the SLAM world once each, as `poses` (a list, None where a
    frame has none) and `rows` ((n, 4, 4), NaN rows there). `update(references, convert)` takes
    the frames appended since the last call (`convert(reference, first_reference)`: a pose or
    None); a new list, another first frame or a shorter list starts again."""

    def __init__(self):
        self._refs = self._first = None
        self.poses: list = []
        self.rows = GrowingArray()

    def update(self, references: list, convert) -> None:
        if self._refs is not references or self._first is not references[0] or len(self.poses) > len(references):
            self._refs, self._first, self.poses = references, references[0], []
            self.rows.resize(0)
        start = len(self.poses)
        self.poses.extend(convert(r, references[0]) for r in references[start:])
        self.rows.resize(len(self.poses))
        for k, pose in enumerate(self.poses[start:], start):
            self.rows.view()[k] = np.nan if pose is None else pose
