"""The live engine (live.py): tracking against published map versions while a mapper thread maps,
with other threads rendering those versions at the same time; and sparse-pixel tracking."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from splat_core.config import load_config
from splat_core.run import Pipeline
from splat_core.pixel_selection import choose_pixels
from splat_core.render import render
from splat_core.synthetic import CorridorSource, SyntheticSource


def _source(n=10):
    return SyntheticSource(n_frames=n, width=160, height=120, seed=0)


def _config(**tracking):
    return load_config("cpu", overrides={"resolution": [160, 120], "checkpoint_every": 0,
                                         "mapping": {"first_frame_iterations": 40},
                                         "tracking": tracking})


def _run(pipe: Pipeline) -> Pipeline:
    while pipe.step() is not None:
        pass
    return pipe


# ----------------------------------------------------------------------------- pixel rules

@pytest.mark.parametrize("rule", ["random", "gradient", "depth_edges"])
def test_pixel_rules_pick_valid_pixels_in_every_block(rule):
    frame = _source(1)[0]
    depth = frame.depth.copy()
    depth[:20, :40] = 0                                   # blocks without depth get no pixel
    pixels = choose_pixels(rule, frame.color, depth, 8, 2, np.random.default_rng(0))
    x, y = pixels[:, 0], pixels[:, 1]
    assert (depth[y, x] > 0).all()
    blocks = (y // 8) * 20 + x // 8
    counts = np.bincount(blocks, minlength=15 * 20)
    has_depth = np.add.reduceat(np.add.reduceat((depth > 0).astype(int), np.arange(0, 120, 8), 0),
                                np.arange(0, 160, 8), 1).ravel() > 0
    assert (counts[has_depth] == np.minimum(2, 64)).all() and (counts[~has_depth] == 0).all()
    assert len(np.unique(y * 160 + x)) == len(x)


@pytest.mark.parametrize("rule", ["random", "depth_edges"])
def test_one_pixel_per_block_is_the_best_scored_valid_pixel_of_the_block(rule):
    from splat_core.pixel_selection import _score
    frame = _source(1)[0]
    depth = frame.depth.copy()
    depth[:20, :40] = 0
    depth[60:, 100:] = np.where(np.arange(60)[:, None] % 3 == 0, depth[60:, 100:], 0)   # sparse rows
    pixels = choose_pixels(rule, frame.color, depth, 8, 1, np.random.default_rng(3))
    score = np.where(depth > 0, _score(rule, frame.color, depth, np.random.default_rng(3)), -np.inf)
    H, W = depth.shape
    expected = []
    for by in range(0, H, 8):
        for bx in range(0, W, 8):
            block = score[by:by + 8, bx:bx + 8]
            if np.isfinite(block).any():
                k = int(np.flatnonzero(block == block.max())[0])
                expected.append((by + k // block.shape[1]) * W + bx + k % block.shape[1])
    assert np.array_equal(pixels[:, 1] * W + pixels[:, 0], np.sort(expected))


def test_gradient_rule_takes_the_strongest_edge_of_a_block():
    color = np.zeros((16, 16, 3), np.float32)
    color[:, 5:] = 1.0                                     # one vertical edge between x = 4 and 5
    pixels = choose_pixels("gradient", color, np.ones((16, 16), np.float32), 16, 1, np.random.default_rng(0))
    assert pixels.shape == (1, 2) and pixels[0, 0] in (4, 5) and 1 <= pixels[0, 1] <= 14


# ----------------------------------------------------------------------------- live engine

@pytest.mark.slow
def test_live_engine_tracks_while_other_threads_render_its_map():
    sequential = _run(Pipeline(_source(), _config(pixels="random", align={"stride": 2})))
    live = Pipeline(_source(), _config(pixels="random", align={"stride": 2}), engine="live")
    seen, errors, stop = {}, [], threading.Event()
    intr = live.intrinsics.scaled(80, 60)

    def viewer():          # novel views of whatever version is newest, as the viewer thread does
        try:
            while not stop.is_set():
                if live.engine.slam.latest_version() is None:
                    stop.wait(0.001)        # no map yet: do not spin, the engine needs the cores
                    continue
                version = live.map_version()
                seen.setdefault(version.number, (version, version.gaussians.means.clone()))
                with torch.no_grad():
                    out = render(version.gaussians, intr, np.eye(4), near=live.config.near_plane)
                assert torch.isfinite(out.color).all()
        except BaseException as e:   # noqa: BLE001 - reported below
            errors.append(e)

    thread = threading.Thread(target=viewer)
    thread.start()
    try:
        _run(live)
        metrics = live.finish()
    finally:
        stop.set()
        thread.join()
    assert not errors, errors
    assert len(seen) >= 3, "the viewer saw the map grow version by version"
    for number, (version, first_seen) in seen.items():   # nothing changed a published version
        assert torch.equal(version.gaussians.means, first_seen), number   # exact: a float sum's order varies
    assert metrics["engine"] == "live" and metrics["live"]["mapper_steps"] >= 2
    assert live.ate_cm() <= 1.5 * sequential.ate_cm() + 0.05, (live.ate_cm(), sequential.ate_cm())
    assert len(live.engine.slam.keyframes) == len(sequential.engine.slam.keyframes)


@pytest.mark.slow
def test_live_run_resumes_from_its_checkpoint(tmp_path):
    config = load_config("cpu", overrides={"resolution": [160, 120], "checkpoint_every": 4,
                                           "mapping": {"first_frame_iterations": 40},
                                           "tracking": {"pixels": "random"}})
    first = Pipeline(_source(8), config, tmp_path, engine="live")
    for _ in range(6):           # killed after frame 5: the checkpoint holds frames 0-3
        first.step()
    first.engine.close()
    resumed = _run(Pipeline(_source(8), config, tmp_path, engine="live", resume=True))
    resumed.finish()
    assert len(resumed.engine.slam.w2cs) == 8 and resumed.ate_cm() < 1.0
    assert (tmp_path / "map.ply").is_file()
    from splat_core.errors import InputError
    with pytest.raises(InputError, match="engine"):
        Pipeline(_source(8), config, tmp_path, engine="sequential", resume=True)


def test_live_preset_tracks_on_while_the_mapper_is_blocked():
    """`live.wait: false` (the `live` preset): after frame 0 is in the map, the tracker goes on while
    a mapper step is held (a mapper slowed without limit), tracking against frame 0's map; the
    mapper's lag is reported; once released, one step maps what was handed over."""
    config = load_config("live", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100,
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                            "loop_closure": {"enabled": False}})
    assert config.live.wait is False and load_config("cpu").live.wait is True
    pipe = Pipeline(SyntheticSource(n_frames=6, width=80, height=60, seed=0), config, engine="live")
    engine, gate = pipe.engine, threading.Event()
    mapped = engine._map

    def held(batch):                     # every step after frame 0's waits for the test
        if batch[0][0] > 0:
            gate.wait(120)
        mapped(batch)
    engine._map = held
    try:
        results = [pipe.step() for _ in range(6)]
        assert not gate.is_set() and engine._mapped == 0        # all six tracked, only frame 0 mapped
        assert [r.index for r in results] == list(range(6))
        assert engine.lags == [1, 2, 3, 4, 5] and engine.lag_keyframes == [0, 0, 0, 0, 1]
        assert len({r.map_version for r in results[1:]}) == 1
    finally:
        gate.set()
    metrics = pipe.finish()
    assert engine._mapped == 5 and metrics["num_gaussians"] > results[1].num_gaussians   # frame 0's map grew
    assert (metrics["live"]["lag_frames_median"], metrics["live"]["lag_frames_max"]) == (3.0, 5)
    assert metrics["live"]["lag_keyframes_max"] == 1 and metrics["live"]["wait"] is False


def test_live_checkpoint_saves_what_the_mapper_published_without_stalling_the_tracker(tmp_path):
    """`live.checkpoint: published` (the `live` preset): a checkpoint falls due while the mapper is
    held; the tracker goes on through it (no drain), the mapper saves it after its next step, with
    the frames up to the newest it settled, and a run resumes from it."""
    import shutil
    config = load_config("live", overrides={"resolution": [80, 60], "checkpoint_every": 2, "eval_every": 100,
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                            "loop_closure": {"enabled": False}})
    assert config.live.checkpoint == "published" and load_config("cpu").live.checkpoint == "drain"
    run = tmp_path / "run"
    pipe = Pipeline(SyntheticSource(n_frames=8, width=80, height=60, seed=0), config, run, engine="live")
    engine, gate, saved = pipe.engine, threading.Event(), threading.Event()
    mapped, save = engine._map, pipe._save_published

    def held(batch):                     # every step after frame 0's waits for the test
        if batch[0][0] > 0:
            gate.wait(120)
        mapped(batch)

    def save_and_tell(arrays, m):
        save(arrays, m)
        saved.set()
    engine._map, pipe._save_published = held, save_and_tell
    try:
        results = [pipe.step() for _ in range(6)]      # checkpoints fall due after frames 1, 3 and 5
        assert not gate.is_set() and not saved.is_set() and engine._settled == 0
        assert [r.index for r in results] == list(range(6))
    finally:
        gate.set()
    assert saved.wait(120)
    meta = pipe.folder.checkpoint_meta()
    done = meta["frames_done"]
    assert 1 <= done <= 6 and len(meta["records"]) == done and len(pipe.folder.load_checkpoint().arrays["w2cs"]) == done
    shutil.copytree(run, tmp_path / "copy")            # the mid-run checkpoint (finish() writes its own)
    pipe.finish()
    resumed = _run(Pipeline(SyntheticSource(n_frames=8, width=80, height=60, seed=0), config, tmp_path / "copy",
                            engine="live", resume=True))
    assert len(resumed.records) == 8
    metrics = resumed.finish()
    assert len(resumed.engine.slam.w2cs) == 8 and metrics["ate_rmse_cm"] < 2.0


def test_live_preset_optimises_every_keyframe_a_held_mapper_finds():
    """`live.map: keyframes`: a mapper that finds several keyframes handed over at once (it was held,
    as a starved one is) optimises each over its own window, oldest first, not only the newest (the
    others would enter the map densified but never optimised)."""
    config = load_config("live", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100,
                                            "keyframes": {"every": 2},
                                            "live": {"max_keyframe_lag": None, "pace_keyframes": None},
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                            "loop_closure": {"enabled": False}})
    assert config.live.map == "keyframes" and load_config("live").live.densify_between
    pipe = Pipeline(SyntheticSource(n_frames=8, width=80, height=60, seed=0), config, engine="live")
    engine, gate = pipe.engine, threading.Event()
    mapped, map_frame, calls = engine._map, engine.slam.map_frame, []

    def held(batch):
        if batch[0][0] > 0:
            gate.wait(120)
        mapped(batch)

    def recorded(frame, w2c, t, optimise=True, **kwargs):
        calls.append((t, optimise))
        return map_frame(frame, w2c, t, optimise=optimise, **kwargs)
    engine._map, engine.slam.map_frame = held, recorded
    try:
        for _ in range(7):
            pipe.step()
        assert calls == [(0, True)]                            # only frame 0 mapped while held
    finally:
        gate.set()
    pipe.finish()
    keyframes = [t for t in range(1, 7) if engine.slam.is_keyframe(t)]   # frames 1-6 were handed over
    assert len(keyframes) >= 3
    assert [c for c in calls[1:] if engine.slam.is_keyframe(c[0])] == [(t, True) for t in keyframes]
    # the other calls densify the newest frame of a batch between keyframes, never optimised
    # (live.densify_between; frame 7, handed over after the mapper was let go)
    assert all(not optimise for t, optimise in calls[1:] if not engine.slam.is_keyframe(t))


def test_live_tracker_waits_once_the_mapper_is_more_than_max_keyframe_lag_keyframes_behind():
    """`live.max_keyframe_lag` (1 in the `live` preset): the tracker runs ahead of a held mapper until
    more than that many keyframes it handed over are unmapped, then waits for the map (a tracker
    that outran its map drifted: 7-Scenes ATE 1.33 against 0.71 cm with the bound)."""
    config = load_config("live", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100,
                                            "keyframes": {"every": 2},
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                            "loop_closure": {"enabled": False}})
    lag = config.live.max_keyframe_lag
    assert lag == 1 and config.live.pace_sources == "live"   # a capture: not paced
    pipe = Pipeline(SyntheticSource(n_frames=12, width=80, height=60, seed=0), config, engine="live")
    engine, gate, blocked = pipe.engine, threading.Event(), threading.Event()
    mapped, wait = engine._map, engine._cond.wait
    stepped = []

    def held(batch):
        if batch[0][0] > 0:
            gate.wait(120)
        mapped(batch)

    def watched_wait(timeout=None):      # the tracker's thread waiting for the map
        if threading.current_thread() is tracker and engine._mapped >= 0:   # not frame 1 waiting for frame 0
            blocked.set()
        return wait(timeout)
    engine._map, engine._cond.wait = held, watched_wait

    def track_all():
        for _ in range(12):
            stepped.append(pipe.step().index)
    tracker = threading.Thread(target=track_all)
    tracker.start()
    try:
        assert blocked.wait(120)
        unmapped = [k for k in range(1, len(stepped)) if engine.slam.is_keyframe(k)]   # handed over, held
        assert len(unmapped) == lag + 1 and tracker.is_alive()  # one unmapped keyframe more stops it
    finally:
        gate.set()
        tracker.join(300)
    assert stepped == list(range(12))
    pipe.finish()
    assert max(engine.lag_keyframes) <= lag


# ----------------------------------------------------------------------------- keyframes paced by the mapper

def _paced_config(**overrides):
    base = {"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100, "keyframes": {"every": 2},
            "mapping": {"first_frame_iterations": 5, "iterations": 2}, "loop_closure": {"enabled": False}}
    base.update(overrides)
    return load_config("live", overrides=base)


class _StepClock:
    """A playback clock that only its `sleep` moves: every frame arrives just as it is asked for,
    none is dropped, and nothing waits on wall time."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def _played(n: int):
    """The synthetic scene as a real-time playback (a live source), every frame handed over."""
    from splat_core.io.playback import RealtimePlayback
    clock = _StepClock()
    return RealtimePlayback(SyntheticSource(n_frames=n, width=80, height=60, seed=0), 30.0, clock=clock,
                            sleep=clock.sleep)


def _held(engine, gate):
    """The engine's mapper holds every step after frame 0's until `gate` is set."""
    mapped = engine._map

    def held(batch):
        if batch[0][0] > 0:
            gate.wait(120)
        mapped(batch)
    engine._map = held


def test_live_preset_tracker_never_waits_for_a_held_mapper_and_defers_the_keyframes_it_falls_behind_on():
    """`live.pace_keyframes` (the `live` preset): with the mapper held (slowed without limit) the
    tracker tracks every frame without waiting after frame 0: a keyframe that falls due while a
    keyframe handed over is unmapped is deferred (owed by the frames after it), so the keyframes
    the tracker waited for without pacing (max_keyframe_lag) are never made."""
    from splat_core.slam import DEFERRED, KEYFRAME, NOT_KEYFRAME
    config = _paced_config()
    assert config.live.wait is False and config.live.pace_keyframes is not None
    assert config.live.pace_keyframes <= config.live.max_keyframe_lag
    pipe = Pipeline(_played(14), config, engine="live")
    engine, gate, ended = pipe.engine, threading.Event(), threading.Event()
    assert pipe.streaming and engine.paced
    _held(engine, gate)
    wait, waits, stepped = engine._cond.wait, [], []

    def watched_wait(timeout=None):      # the tracker's thread waiting for the map after frame 0's
        if threading.current_thread() is tracker and engine._mapped >= 0:
            waits.append(engine.slam.frames_tracked)
            ended.set()
        return wait(timeout)
    engine._cond.wait = watched_wait

    def track_all():
        for _ in range(12):
            stepped.append(pipe.step().index)
        ended.set()
    tracker = threading.Thread(target=track_all)
    tracker.start()
    try:
        assert ended.wait(300)
        assert waits == [] and stepped == list(range(12))      # all twelve tracked while the mapper was held
        assert [r["source_index"] for r in pipe.records] == list(range(12))   # none dropped
        assert engine._mapped == 0
        marks = engine.slam.keyframe_marks
        # frame 1 (due) is the only keyframe handed over; every later frame owes the one due at frame 3
        assert marks == [KEYFRAME, KEYFRAME, NOT_KEYFRAME] + [DEFERRED] * 9
        assert max(engine.lag_keyframes) == 1
    finally:
        gate.set()
        tracker.join(300)
    metrics = pipe.finish()
    assert metrics["live"]["keyframes_deferred"] >= 1 and metrics["live"]["pace_keyframes"] == 1


def test_a_deferred_keyframe_is_taken_once_the_mapper_has_caught_up_and_survives_a_resume(tmp_path):
    """The keyframe owed when a checkpoint is saved is owed after the resume: the first frame tracked
    after it becomes the keyframe, as the first frame after the mapper caught up does in a run."""
    from splat_core.slam import DEFERRED, KEYFRAME, NOT_KEYFRAME
    config = _paced_config(live={"checkpoint": "drain", "pace_sources": "all"})   # a capture, resumable
    source = lambda: SyntheticSource(n_frames=12, width=80, height=60, seed=0)   # noqa: E731
    pipe = Pipeline(source(), config, tmp_path, engine="live")
    engine, gate = pipe.engine, threading.Event()
    assert engine.paced and not pipe.streaming
    _held(engine, gate)
    try:
        for _ in range(6):               # frames 0-5: frame 3's keyframe deferred (frame 1 held)
            pipe.step()
        assert engine.slam.keyframe_marks == [KEYFRAME, KEYFRAME, NOT_KEYFRAME, DEFERRED, DEFERRED, DEFERRED]
    finally:
        gate.set()
    pipe.save_checkpoint()               # drains: frame 1 mapped, frames 2-5 settled (no keyframe among them)
    assert engine._mapped == 5
    pipe.engine.close()
    resumed = Pipeline(source(), config, tmp_path, engine="live", resume=True)
    slam = resumed.engine.slam
    assert slam.keyframe_marks == [KEYFRAME, KEYFRAME, NOT_KEYFRAME, DEFERRED, DEFERRED, DEFERRED]
    assert [kf.frame_index for kf in slam.keyframes] == [0, 1]
    result = resumed.step()
    assert result.index == 6 and result.is_keyframe          # the owed keyframe, taken at once
    _run(resumed)
    resumed.finish()
    assert slam.keyframe_marks[6] == KEYFRAME and 6 in [kf.frame_index for kf in slam.keyframes]


def test_keyframe_decisions_survive_a_state_round_trip_and_an_old_checkpoint_gets_the_rule(tmp_path):
    """SplaTAM keeps each frame's keyframe decision (deferred included) in its state; a checkpoint
    without them (made before they were kept) gets the keyframe rule, nothing deferred."""
    from splat_core.slam import DEFERRED, KEYFRAME, NOT_KEYFRAME, SplaTAM
    config = _paced_config()
    src = SyntheticSource(n_frames=8, width=80, height=60, seed=0)
    intr = src.intrinsics.scaled(80, 60)
    slam = SplaTAM(config, intr, total_frames=8)
    slam.keyframes.attach(tmp_path / "kf.bin")
    for k in range(5):
        frame = src.frame_at_size(k, 80, 60)
        t, w2c, _ = slam.track(frame, slam.map.tensors(detach=True), defer_keyframe=k == 3)
        slam.map_frame(frame, w2c, t)
    assert slam.keyframe_marks == [KEYFRAME, KEYFRAME, NOT_KEYFRAME, DEFERRED, KEYFRAME]
    assert [kf.frame_index for kf in slam.keyframes] == [0, 1, 4]
    arrays = slam.state_arrays()
    again = SplaTAM(config, intr, total_frames=8)
    again.load_state_arrays(arrays, tmp_path / "kf.bin")
    assert again.keyframe_marks == slam.keyframe_marks
    del arrays["keyframe_marks"]
    old = SplaTAM(config, intr, total_frames=8)
    old.load_state_arrays(arrays, tmp_path / "kf.bin")
    assert old.keyframe_marks == [KEYFRAME, KEYFRAME, NOT_KEYFRAME, KEYFRAME, NOT_KEYFRAME]


def test_live_publish_densified_hands_the_tracker_a_keyframes_new_gaussians_before_its_optimisation():
    """`live.publish_densified`: while a keyframe's optimisation is still running (held here), the
    newest map version already holds the Gaussians densified from it; the keyframe still counts as
    unmapped (the next due keyframe is deferred) until the step ends."""
    from splat_core.slam import DEFERRED
    config = _paced_config(live={"publish_densified": True})
    pipe = Pipeline(_played(10), config, engine="live")
    engine, slam = pipe.engine, pipe.engine.slam
    entered, gate = threading.Event(), threading.Event()
    optimise, densify, densified = slam.optimise, slam.densify, []

    def counted(color, depth, w2c, t):
        added = densify(color, depth, w2c, t)
        densified.append((t, len(slam.map)))       # the map's size once frame t is densified
        return added

    def held(window, first=False, **kwargs):
        if not first:                    # a keyframe after frame 0: hold its optimisation
            entered.set()
            gate.wait(120)
        return optimise(window, first=first, **kwargs)
    slam.optimise, slam.densify = held, counted
    try:
        for _ in range(2):               # frame 1: a keyframe (keyframes.every 2)
            pipe.step()
        assert entered.wait(120)         # frame 1's optimisation has begun, its densification is done
        version = pipe.map_version()
        assert version.frame_index == 1 and engine._mapped == 0
        assert densified[-1] == (1, len(version))       # frame 1's densified map, before pruning and optimising
        for _ in range(2):               # frame 3 falls due while frame 1 is unmapped: deferred
            pipe.step()
        assert slam.keyframe_marks[3] == DEFERRED
    finally:
        gate.set()
    pipe.finish()
    assert engine._mapped == 3 and slam.is_keyframe(1)


@pytest.mark.parametrize("between", [True, False])
def test_live_keyframe_mapper_densifies_from_frames_between_keyframes(between):
    """`live.map: keyframes` with `live.densify_between` (the `live` preset): a mapper step whose
    newest frame is not a keyframe adds Gaussians where that frame sees what the map lacks and
    publishes them, so the tracker's next frames find what came into view since the last keyframe.
    Without them the corridor's tracking failed where the camera looks down it (frames 240-280:
    each frame 0.3-2 cm off from a perfect prediction against 0.1 cm; docs/benchmarks.md, Long runs).
    Off, only keyframes add Gaussians."""
    config = load_config("live", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100,
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                            "loop_closure": {"enabled": False}, "live": {"densify_between": between}})
    assert config.live.map == "keyframes" and load_config("live").live.densify_between
    # 6 cm a frame down the corridor, panning: walls and objects come into view every frame
    pipe = Pipeline(CorridorSource(n_frames=8, width=80, height=60, speed=4.0), config, engine="live")
    engine, versions = pipe.engine, []
    for _ in range(6):
        t = pipe.step().index
        engine.drain()                   # each frame its own mapper step
        versions.append((t, engine.map_version()))
    slam = engine.slam
    between_frames = [t for t, _ in versions if not slam.is_keyframe(t)]
    assert len(between_frames) >= 3 and slam.lost_tracking.lost == {}
    births = set(np.unique(engine.map_version().birth_frame.cpu().numpy()).tolist())
    if between:
        assert all(version.frame_index == t for t, version in versions)       # published at each frame
        assert births & set(between_frames)                                  # and densified from them
        assert engine.stats()["live"]["densified_between"] == len(between_frames)
    else:
        keyframes = [t for t, _ in versions if slam.is_keyframe(t)]
        assert births <= set(keyframes)
        assert all(version.frame_index == max(k for k in keyframes if k <= t) for t, version in versions)
    pipe.finish()


@pytest.mark.parametrize("live_source", [True, False])
def test_live_hurry_ends_a_keyframe_step_once_a_later_frame_left_the_map(monkeypatch, live_source):
    """`live.hurry_coverage`: on a live source, a keyframe's mapper step ends after
    `hurry_iterations` once a frame tracked after that keyframe was covered less than that share by
    its map (the camera pans past a map that lags it): the keyframe owed meanwhile is mapped sooner.
    Frame 0's step and every step of a capture read frame by frame run all their iterations."""
    import dataclasses

    import splat_core.slam as slam_module
    runs, real = [], slam_module.optimise_map

    def counted(*args, stop=None, **kwargs):         # iterations each mapper step ran
        done = []
        out = real(*args, stop=lambda i: done.append(i) or (stop is not None and stop(i)), **kwargs)
        runs.append(len(done))
        return out
    monkeypatch.setattr(slam_module, "optimise_map", counted)
    config = _paced_config(live={"hurry_coverage": 0.5, "hurry_iterations": 2},
                           mapping={"first_frame_iterations": 5, "iterations": 6})
    source = _played(12) if live_source else SyntheticSource(n_frames=12, width=80, height=60, seed=0)
    pipe = Pipeline(source, config, engine="live")
    engine, gate = pipe.engine, threading.Event()
    assert engine.paced == live_source
    _held(engine, gate)
    result = engine.slam.result

    def leaving(*args, **kwargs):                     # frames 2 on: the map covers a tenth of them
        r = result(*args, **kwargs)
        return dataclasses.replace(r, tracking_coverage=0.1) if r.index >= 2 else r
    engine.slam.result = leaving
    try:
        steps = 8 if live_source else 3      # a capture: the tracker waits beyond max_keyframe_lag
        for _ in range(steps):
            pipe.step()
    finally:
        gate.set()
    # The held steps finish before the rest is tracked: otherwise, on a busy machine, the tracker
    # could track every remaining frame while they run, defer every keyframe due meanwhile and
    # leave no later step (a clean-clone run beside a busy core failed that way: runs [5, 2]).
    engine.drain()
    while pipe.step() is not None:
        pass
    metrics = pipe.finish()
    assert runs[0] == 5 and len(runs) >= 3                    # frame 0's step is whole
    hurried = metrics["live"]["hurried_steps"]
    if live_source:
        assert runs[1] == 2                                   # keyframe 1, frames 2-7 tracked meanwhile
        # later steps run while frames are tracked: cut at the first check after a frame left the map
        assert all(2 <= r <= 6 for r in runs[1:]) and hurried >= sum(r < 6 for r in runs[1:]) >= 1
    else:
        assert set(runs[1:]) == {6} and hurried == 0
