"""Closed loops in the viewer, without a browser: the edges join the loop keyframes' frustums,
the frustums and the edges follow corrected poses, the status panel and browse mode say what
happened (app/viewer/loops.py). Loop records are fabricated (closer.py's fields), no loop closure runs."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from app.snapshot import KeyframeView, MapSnapshot
from app.viewer.loops import loop_line
from app.worker import SlamWorker
from splat_core.camera import invert_pose
from splat_core.loop.records import LoopRecord

from helpers.runs import make_run
from helpers.viewer import FakePipeline, apply_snapshot, blob_map, wait_until

THUMB = np.zeros((4, 4, 3), np.uint8)


def record(k=(0, 2), frames=(0, 4), applied=True, cm=5.0, deg=0.25, disagreement=5.2):
    return LoopRecord(keyframes=tuple(k), frames=tuple(frames), inliers=40, applied=applied,
                      correction_cm=cm if applied else 0.0, correction_deg=deg if applied else 0.0,
                      disagreement_cm=disagreement, disagreement_deg=0.3, seconds=0.4)


def c2w_at(x, y=0.0):
    c2w = np.eye(4)
    c2w[0, 3], c2w[1, 3] = x, y
    return c2w


def test_loop_line_says_what_the_record_says():
    from app.viewer.loops import loop_count_text, loop_status_lines

    assert loop_line(record()) == "loop closed: keyframe 0 <-> 2 (frames #0 <-> #4), correction 5.0 cm, 0.25°"
    kept = loop_line(record(k=(3, 17), frames=(60, 340), applied=False, disagreement=0.4))
    assert kept == ("loop closed: keyframe 3 <-> 17 (frames #60 <-> #340), no correction applied "
                    "(the poses already agreed within 0.4 cm)")
    assert "correction 0.0" not in kept
    assert loop_count_text(None) == "" and loop_count_text(()) == " · loops: 0"
    assert loop_status_lines((record(), record(k=(1, 2)))) == [f"🔁 {loop_line(record(k=(1, 2)))}"]


def test_loop_segments_join_the_keyframe_centres():
    from app.viewer.loops import loop_segments

    kfs = tuple(KeyframeView(f, c2w_at(0.1 * f, 0.01 * f), THUMB) for f in (0, 2, 4, 6))
    loops = (record(frames=(0, 4)), record(k=(1, 3), frames=(2, 6)), record(frames=(0, 99)))   # 99: no keyframe
    seg = loop_segments(loops, kfs)
    assert seg.shape == (2, 2, 3)
    assert np.allclose(seg[0], [[0, 0, 0], [0.4, 0.04, 0]]) and np.allclose(seg[1], [[0.2, 0.02, 0], [0.6, 0.06, 0]])
    assert loop_segments(loops, kfs, upto_frame=4).shape == (1, 2, 3)       # a page scrubbed to frame 4
    assert loop_segments(None, kfs).shape == (0, 2, 3)


def test_frustums_and_edges_follow_a_loop_correction_at_once(server):
    """Policy "off" holds the scene back while SLAM runs, but a closed loop redraws it: the keyframe
    frustums move to their corrected poses, the edge joins their centres, the map is re-sent."""
    from app.viewer import build_viewer

    class Source:
        snap = None

        def latest(self):
            return self.snap

    m = blob_map(300, 0).to_numpy()
    m["birth_frame"] = np.repeat([0, 2, 4], 100)

    def snap(version, poses, loops, state="running", shift=0.0):
        kfs = tuple(KeyframeView(f, c2w, THUMB) for f, c2w in poses.items())
        g = {k: np.array(v) for k, v in m.items()}
        g["means"][100:] += shift                             # the map moved with the correction
        return MapSnapshot(version, state, version, 20, version, g, kfs, estimated_c2w=np.stack(list(poses.values())),
                           loops=loops)

    source = Source()
    app = build_viewer(server, source, map_updates="off")
    try:
        def apply(s):
            apply_snapshot(app, source, s)

        drifted = {0: c2w_at(0.0), 2: c2w_at(0.2), 4: c2w_at(0.4)}
        apply(snap(1, drifted, (), "paused"))                 # paused: drawn
        assert np.allclose(app.camera_layer._frustums[4].position, [0.4, 0, 0])
        assert len(app.loop_layer.segments) == 0
        apply(snap(2, drifted, ()))                           # running: held back ("off")
        sent, consolidations = app.map_layer.chunks_sent, app.map_layer.consolidations
        corrected = {0: c2w_at(0.0), 2: c2w_at(0.2, 0.03), 4: c2w_at(0.4, 0.06)}
        apply(snap(3, corrected, (record(frames=(0, 4)),), shift=0.03))
        for f, c2w in corrected.items():
            assert np.allclose(app.camera_layer._frustums[f].position, c2w[:3, 3])
        seg = app.loop_layer.segments
        assert seg.shape == (1, 2, 3)
        assert np.allclose(seg[0, 0], app.camera_layer._frustums[0].position)
        assert np.allclose(seg[0, 1], app.camera_layer._frustums[4].position)
        assert app.map_layer.consolidations == consolidations + 1 and app.map_layer.chunks_sent == sent + 2
        assert "loops: 1" in app.panels.status.content
        assert loop_line(record(frames=(0, 4))) in app.panels.status.content
    finally:
        app.close()


class LoopingPipeline(FakePipeline):
    """A FakePipeline with loop closure on that closes a loop at frame 4 (keyframe 0 <-> keyframe 2):
    keyframes 1 and 2 and their frames move 5 cm down, and the map version carries the record."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.config = dataclasses.replace(self.config, loop_closure=dataclasses.replace(
            self.config.loop_closure, enabled=True))
        self.loops: list[dict] = []

    def step(self):
        r = super().step()
        if r is not None and r.index == 4:
            for kf in self.kf[1:]:
                kf.w2c = _moved_down(kf.w2c, 0.05)
            self.w2cs[2:] = [_moved_down(w, 0.05) for w in self.w2cs[2:]]
            self.loops.append(record(frames=(0, 4)))
            r.loops = [self.loops[-1]]
        return r

    def map_version(self):
        return dataclasses.replace(super().map_version(), loops=tuple(self.loops))


def _moved_down(w2c, dy):
    c2w = invert_pose(w2c)
    c2w[1, 3] += dy
    return invert_pose(c2w)


def test_worker_snapshots_carry_loops_and_corrected_keyframes(server):
    from app.viewer import build_viewer

    pipe = LoopingPipeline(total=6, per_frame=50, keyframe_every=2)
    worker = SlamWorker(pipe, live_render=False)
    app = build_viewer(server, worker)
    try:
        worker.start()     # the keyframe at frame 2 is published at frame 2, moved by the loop at frame 4
        snap = worker.wait_for(lambda s: s is not None and s.state == "finished", 60)
        assert len(snap.loops) == 1 and snap.loops[0].frames == (0, 4)
        assert np.isclose(snap.keyframes[1].c2w[1, 3], 0.05) and np.isclose(snap.keyframes[2].c2w[1, 3], 0.05)
        assert np.array_equal(snap.keyframes[1].thumbnail, worker._keyframe_views[2][1].thumbnail)
        wait_until(lambda: app.applied is not None and app.applied.state == "finished", 60, what="run end")
        assert np.allclose(app.camera_layer._frustums[2].position, [0.2, 0.05, 0])
        assert np.allclose(app.loop_layer.segments, [[[0, 0, 0], [0.4, 0.05, 0]]])
        assert "loop closed: keyframe 0 <-> 2" in app.panels.status.content
    finally:
        worker.stop(join_timeout=10)
        app.close()
    off = SlamWorker(FakePipeline(total=2), live_render=False)
    assert off.latest().loops is None                         # loop closure off: no count shown


def test_browse_mode_reads_the_loops_of_metrics_json(tmp_path):
    from app.browse import load_run
    from app.viewer.panels import status_markdown

    run = make_run(tmp_path)
    assert load_run(run).loops is None                        # no metrics.json: nothing said
    (run / "metrics.json").write_text(json.dumps({"ate_rmse_cm": 1.5, "loops_closed": 2,
                                                  "loops": [record().to_dict(), record(
                                                      k=(3, 17), frames=(60, 340), applied=False,
                                                      disagreement=0.4).to_dict()]}))
    snap = load_run(run)
    assert snap.loops == (record(), record(k=(3, 17), frames=(60, 340), applied=False, disagreement=0.4))
    text = status_markdown(snap)
    assert "keyframes: 0 · loops: 2" in text
    assert "loop closed: keyframe 3 <-> 17 (frames #60 <-> #340), no correction applied" in text
