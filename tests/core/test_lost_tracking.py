"""Lost tracking (issue 13 item 4): the detector on crafted numbers, what a lost frame does to the
map, and the synthetic hard captures (a 30-frame jump, a covered lens, a fast 90-degree turn)."""

from __future__ import annotations

import collections
import contextlib
import functools
import json
import threading

import numpy as np
import pytest

from splat_core.config import LostTrackingConfig, load_config
from splat_core.io.trajectory import read_tum_trajectory, write_tum_trajectory
from splat_core.keyframes import is_keyframe_time
from splat_core.metrics import ate_rmse
from splat_core.run import Pipeline
from splat_core.run.live import LiveEngine
from splat_core.relocalise import Evidence, lost_reason, relative_motion
from splat_core.slam import SplaTAM
from splat_core.synthetic import HardCapture, turn_away

CFG = LostTrackingConfig()
RECENT = [0.020, 0.022, 0.018, 0.021, 0.019]


def normal(**kw) -> Evidence:
    """A hand-held frame at 30 fps: 1.5 cm, 0.8 degrees, 75 % covered, an ordinary loss."""
    values = dict(loss_per_pixel=0.025, coverage=0.75, translation=0.015, rotation_deg=0.8, seconds=1 / 30)
    return Evidence(**{**values, **kw})


def test_the_detector_on_crafted_numbers():
    assert lost_reason(normal(), RECENT, CFG) is None
    assert "covers 10%" in lost_reason(normal(coverage=0.10), RECENT, CFG)
    assert "loss per pixel" in lost_reason(normal(loss_per_pixel=0.5), RECENT, CFG)
    assert "loss per pixel" in lost_reason(normal(loss_per_pixel=np.inf), RECENT, CFG)   # no pixel at all
    assert "moved 30 cm" in lost_reason(normal(translation=0.30), RECENT, CFG)
    assert "turned 45 degrees" in lost_reason(normal(rotation_deg=45.0), RECENT, CFG)
    # A short history does not judge the loss yet; coverage and motion still count.
    assert lost_reason(normal(loss_per_pixel=0.5), RECENT[:2], CFG) is None
    assert lost_reason(normal(coverage=0.1), [], CFG) is not None
    # The same motion over --stride 10 (a third of a second) is hand-held again.
    assert lost_reason(normal(translation=0.30, rotation_deg=45.0, seconds=10 / 30), RECENT, CFG) is None
    # Unknown coverage (no polish stage) is not a reason.
    assert lost_reason(normal(coverage=None), RECENT, CFG) is None


def test_relative_motion_and_the_turn_helper():
    c2w = np.eye(4)
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    turned = turn_away(c2w, 90.0)
    turned[:3, 3] += [0.0, 0.0, 0.05]
    metres, degrees = relative_motion(np.linalg.inv(c2w), np.linalg.inv(turned))
    assert metres == pytest.approx(0.05) and degrees == pytest.approx(90.0)


def light_config(**lost):
    overrides = {"resolution": [80, 60], "mapping": {"first_frame_iterations": 30}, "keyframes": {"every": 2}}
    if lost:
        overrides["lost_tracking"] = lost
    return load_config("cpu", overrides)


def test_a_lost_frame_adds_nothing_and_the_pose_is_held_not_extrapolated():
    src = HardCapture("turn", n_frames=14, at=3, width=80, height=60)   # frames 4-11 pan 30, 60, 90 x 5, 60, 30 degrees
    slam = SplaTAM(light_config(), src.intrinsics)
    assert all(slam.process(src[i]).lost is None for i in range(4))
    for i in range(4, 9):
        size, keyframes = len(slam.map), len(slam.keyframes)
        r = slam.process(src[i])
        if r.lost is not None:
            assert r.num_added == 0 and len(slam.map) == size          # nothing densified, nothing pruned
            assert not r.is_keyframe and len(slam.keyframes) == keyframes
            assert np.allclose(r.w2c, slam.w2cs[slam.lost_tracking.good[0]])   # held, not extrapolated
    lost = sorted(slam.lost_tracking.lost)
    assert {6, 7, 8} <= set(lost) and is_keyframe_time(7, None, 2)     # 7: a keyframe that was not kept
    assert slam.lost_tracking.active


@contextlib.contextmanager
def mapper_one_frame_behind():
    """The live engine with its timing fixed: frame t (t >= 2) is tracked against the map of frame
    t-2, the furthest behind that `live.max_lag` 1 (the cpu preset's) lets tracking run, and the
    tracker and the mapper take turns.

    Left to the machine, which frames the map holds when a frame is tracked depends on thread
    timing (and the two threads sharing the cores changes the floating-point sums), so the live
    engine's ATE varies from run to run: jump-live once gave 12.7 cm against a bound of 2.3 cm on a
    loaded machine. Here the mapper starts mapping frame m only once the tracker waits for the map
    of m (the policy's wait before tracking m+2, a lost frame's retrack, or `drain`): a condition,
    no sleep; and the tracker does not run on while the mapper looks for loops after a keyframe
    (the engine lets it). Every run takes the same path, the one where the map lags most, so the ATE bound
    below is a fixed number, not a draw. The live engine's timing itself is tested in test_live.py."""
    cond = threading.Condition()
    awaited = [-1]                       # the newest frame whose map the tracker has waited for
    wait_for_map, map_, drain = LiveEngine._wait_for_map, LiveEngine._map, LiveEngine.drain

    def await_map(frame):
        with cond:
            awaited[0] = max(awaited[0], frame)
            cond.notify_all()

    def _wait_for_map(self, t, max_lag=None):
        if t == 0:
            return wait_for_map(self, t, max_lag)
        need = max(0, t - 1 - (self.config.max_lag if max_lag is None else max_lag))   # as LiveEngine's
        await_map(need)
        waited = wait_for_map(self, t, max_lag)
        with self._cond:                 # the engine lets the tracker on while loop detection runs: not here
            while self._mapped < need and self.error is None:
                self._cond.wait(0.5)
        return waited

    def _map(self, batch):
        newest = batch[-1][0]
        with cond:
            assert cond.wait_for(lambda: awaited[0] >= newest, 600), "the tracker never waited for the map"
        return map_(self, batch)

    def _drain(self):
        await_map(self._handed)
        return drain(self)

    LiveEngine._wait_for_map, LiveEngine._map, LiveEngine.drain = _wait_for_map, _map, _drain
    try:
        yield
    finally:
        LiveEngine._wait_for_map, LiveEngine._map, LiveEngine.drain = wait_for_map, map_, drain


def hard_run(kind, tmp_path=None, n=24, at=8, engine="sequential", **kw):
    src = HardCapture(kind, n_frames=n, at=at, width=80, height=60)
    pipe = Pipeline(src, light_config(), tmp_path, device="cpu", engine=engine, **kw)
    pipe.warn = lambda message: None
    with mapper_one_frame_behind() if engine == "live" else contextlib.nullcontext():
        while pipe.step() is not None:
            pass
        metrics = pipe.finish()
    est, ref = np.array(pipe.estimated_c2w()), np.array(pipe.reference_c2w())
    errors = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    return pipe, metrics, errors


def after_recovery(pipe, errors):
    lost = [x["index"] for x in pipe.lost]
    return errors[(max(lost) + 1 if lost else 0):]


def test_covered_lens_is_skipped_and_tracking_goes_on(tmp_path):
    pipe, metrics, errors = hard_run("covered", tmp_path / "run", n=20, at=8)
    assert metrics["frames_skipped"] == 5 and metrics["frames"] == 20 - 5
    assert errors.max() < 0.10
    stamps, c2w = read_tum_trajectory(tmp_path / "run" / "trajectory.txt")
    assert len(stamps) == metrics["frames"]


@functools.lru_cache(maxsize=None)
def undisturbed(n: int, at: int, engine: str):
    """(estimated, reference) c2w of the whole path with nothing missing, covered or turned."""
    pipe, _, _ = hard_run("none", n=n, at=at, engine=engine)
    return np.array(pipe.estimated_c2w()), np.array(pipe.reference_c2w())


@pytest.mark.slow
@pytest.mark.parametrize("kind, engine", [("jump", "sequential"), ("jump", "live"),
                                          ("turn", "sequential"), ("turn", "live")])
def test_hard_captures_recover(tmp_path, kind, engine):
    pipe, metrics, errors = hard_run(kind, tmp_path / "run", n=30, at=12, engine=engine)
    assert after_recovery(pipe, errors).max() < 0.10
    # ATE within 2x of the undisturbed run's on the same camera poses (the jump's lie 30 frames further on)
    est, ref = undisturbed(60, 12, engine)
    path = pipe.source.path_index[[r["source_index"] for r in pipe.records]]
    assert metrics["ate_rmse_cm"] <= 2 * 100 * ate_rmse(est[path], ref[path])
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["frames_lost"] == len(saved["lost"]) == len(pipe.lost)
    if kind == "turn":
        assert pipe.lost                 # looking away from the map is detected, not tracked through


def test_lost_frames_are_marked_in_the_trajectory_metrics_and_checkpoint(tmp_path):
    out = tmp_path / "run"
    pipe, metrics, errors = hard_run("turn", out, n=16, at=4)
    assert metrics["frames_lost"] >= 1 and metrics["frames_lost"] == len(metrics["lost"])
    lost = [x["index"] for x in metrics["lost"]]
    text = (out / "trajectory.txt").read_text().splitlines()
    marks = [line for line in text if line.startswith("# tracking lost at frame")]
    assert [int(line.split()[5]) for line in marks] == lost
    stamps, c2w = read_tum_trajectory(out / "trajectory.txt")   # the reader skips the marks
    assert len(stamps) == metrics["frames"]
    a, b = lost[0] - 1, lost[-1] + 1                             # once back: interpolated between a and b
    for k in lost:
        s = (k - a) / (b - a)
        assert np.allclose(c2w[k][:3, 3], (1 - s) * c2w[a][:3, 3] + s * c2w[b][:3, 3], atol=1e-6)
    state = np.load(out / "checkpoint" / "state.npz")
    assert sorted(int(k) for k in json.loads(str(state["lost_state"]))["lost"]) == lost
    assert after_recovery(pipe, errors).max() < 0.10


@pytest.mark.slow
def test_resume_keeps_the_lost_frames(tmp_path):
    src = HardCapture("turn", n_frames=16, at=4, width=80, height=60)
    config = light_config()
    config.checkpoint_every = 9          # after the lost frames (5..)
    out = tmp_path / "run"
    whole = Pipeline(src, config, tmp_path / "whole", device="cpu")
    whole.warn = lambda message: None
    while whole.step() is not None:
        pass
    first = Pipeline(src, config, out, device="cpu", max_frames=None)
    first.warn = lambda message: None
    for _ in range(9):
        first.step()
    assert first.lost
    resumed = Pipeline(src, config, out, device="cpu", resume=True)
    resumed.warn = lambda message: None
    assert resumed.lost == first.lost
    assert resumed.engine.slam.lost_tracking.state() == first.engine.slam.lost_tracking.state()
    while resumed.step() is not None:
        pass
    assert resumed.lost == whole.lost
    assert np.allclose(np.array(resumed.estimated_c2w()), np.array(whole.estimated_c2w()))


def test_trajectory_comments_precede_their_pose(tmp_path):
    c2w = np.stack([np.eye(4)] * 3)
    c2w[:, 0, 3] = [0.0, 0.1, 0.2]
    write_tum_trajectory(tmp_path / "t.txt", [0.0, 0.1, 0.2], c2w, comments={1: "tracking lost at frame 1"})
    lines = (tmp_path / "t.txt").read_text().splitlines()
    k = lines.index("# tracking lost at frame 1")
    assert lines[k + 1].startswith("0.100000 0.1")
    assert len(read_tum_trajectory(tmp_path / "t.txt")[0]) == 3


def test_the_viewer_shows_a_lost_track():
    import viser

    from app.viewer.assets import DEFAULT_COLORS
    from app.snapshot import MapSnapshot, freeze_gaussians
    from helpers.viewer import blob_map
    from app.viewer.panels import status_markdown
    from app.viewer.cameras import CameraLayer

    c2w = np.stack([np.eye(4)] * 6)
    snap = lambda frame, lost: MapSnapshot(version=1, state="running", frame_index=frame, total_frames=10,  # noqa: E731
                                           map_version=1, gaussians=freeze_gaussians(blob_map(10).to_numpy()),
                                           estimated_c2w=c2w[: frame + 1], lost_frames=lost)
    assert "tracking lost at frame 3, relocalising" in status_markdown(snap(5, (1, 3, 4, 5)))
    assert "recovered" in status_markdown(snap(5, (3, 4)))
    assert "lost" not in status_markdown(snap(5, ()))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        layer = CameraLayer(server, dict(DEFAULT_COLORS))
        layer.update(snap(5, (4, 5)))
        assert tuple(layer._current.color) == DEFAULT_COLORS["lost"]
        layer.update(snap(5, (3, 4)))
        assert tuple(layer._current.color) == DEFAULT_COLORS["current"]
    finally:
        server.stop()
