"""Viewer without a browser: snapshots, the worker's controls, the scene layout, browse mode,
and the `export` / `render` / `splatam-viewer` commands."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from app.snapshot import LIVE_TILE_WIDTH, keyframe_buckets
from app.worker import SlamWorker
from splat_core.errors import InputError
from splat_core.io.ply import read_ply
from splat_core.io.trajectory import read_tum_trajectory

from helpers.viewer import FakePipeline, MessageLog, apply_snapshot, blob_map, wait_until
from helpers.runs import make_run, run_cli


def test_keyframe_buckets_show_the_map_as_it_was():
    kf = np.array([0, 3, 7])
    birth = np.array([0, 0, 1, 3, 4, 7, 8, 9])
    b = keyframe_buckets(birth, kf)
    assert b.tolist() == [0, 0, 1, 1, 2, 2, 3, 3]   # (kf_{k-1}, kf_k], tail = 3
    for k, f in enumerate(kf):                       # buckets 0..k == born up to keyframe k
        assert ((b <= k) == (birth <= f)).all()


def test_worker_publishes_immutable_snapshots(tmp_path):
    pipe = FakePipeline(total=5, per_frame=20, out_dir=tmp_path)
    w = SlamWorker(pipe, live_render=False)
    w.start()
    snap = w.wait_for(lambda s: s is not None and s.state == "finished", timeout=60)
    assert snap is not None, w.error
    assert snap.processed == 5 and snap.total_frames == 5
    assert snap.num_gaussians == 100
    assert snap.keyframe_frames.tolist() == [0, 2, 4]
    assert snap.estimated_c2w.shape == (5, 4, 4) and snap.reference_c2w.shape == (5, 4, 4)
    assert snap.history["tracking_loss"].shape == (5,)
    assert snap.gaussians["birth_frame"].tolist() == sorted(snap.gaussians["birth_frame"].tolist())
    assert snap.keyframes[1].thumbnail.dtype == np.uint8
    with pytest.raises(ValueError):
        snap.gaussians["means"][0, 0] = 1.0          # read-only copies
    pipe.map.params["means"].data[0, 0] = 123.0  # the worker's later edits never leak in
    assert snap.gaussians["means"][0, 0] != 123.0
    assert pipe.finished and (tmp_path / "map.ply").is_file()
    assert len(read_ply(tmp_path / "map.ply")["means"]) == 100


def test_worker_pause_step_resume_stop():
    pipe = FakePipeline(total=200, per_frame=5, frame_seconds=0.02)
    w = SlamWorker(pipe, live_render=False, start_paused=True)
    w.start()
    assert w.wait_for(lambda s: s.state == "paused", 60)
    time.sleep(0.2)
    assert w.latest().processed == 0
    w.step_once()
    assert w.wait_for(lambda s: s.processed == 1 and s.state == "paused", 60)
    w.step_once()
    assert w.wait_for(lambda s: s.processed == 2, 60)
    time.sleep(0.2)
    assert w.latest().processed == 2
    w.resume()
    assert w.wait_for(lambda s: s.processed >= 6, 60)
    w.pause()
    n = w.wait_for(lambda s: s.state == "paused", 60).processed
    time.sleep(0.2)
    assert w.latest().processed == n
    w.resume()
    assert w.wait_for(lambda s: s.processed > n, 60)
    w.stop(join_timeout=5)
    assert not w.is_alive() and w.latest().state == "stopped" and pipe.finished


def test_worker_survives_a_failing_pipeline():
    pipe = FakePipeline(total=5)

    def boom():
        raise RuntimeError("tracking diverged")
    pipe.step = boom
    w = SlamWorker(pipe, live_render=False)
    w.start()
    snap = w.wait_for(lambda s: s.state == "error", 60)
    assert "tracking diverged" in snap.message


def test_worker_live_render_with_the_real_renderer():
    pipe = FakePipeline(total=1, per_frame=200)
    w = SlamWorker(pipe, live_render=True, render_backend="reference", live_max_width=40)
    w.start()
    snap = w.wait_for(lambda s: s.state == "finished", 60)
    assert snap.live is not None and snap.live.render_color is not None, w.error
    assert snap.live.render_color.shape == (30, 40, 3)
    assert snap.live.render_alpha.max() > 0.5         # the patch covers the image centre
    assert np.isfinite(snap.live.psnr)


def test_worker_renders_the_live_panel_no_wider_than_its_tiles():
    """A 320 x 240 frame: the map is rendered at the panel's tile width, where it is shown as it
    came (no pixels drawn only to be scaled away)."""
    from app.viewer.panels import live_mosaic
    from splat_core.frame import Frame

    class Wide(FakePipeline):
        def frame(self, k):
            f = super().frame(k)
            up = np.ones((4, 4, 1), np.float32)
            return Frame(k, f.timestamp, np.kron(f.color, up), np.kron(f.depth, up[..., 0]),
                         f.intrinsics.scaled(320, 240), f.c2w_ref)
    w = SlamWorker(Wide(total=1, per_frame=200), live_render=True, render_backend="reference")
    w.start()
    snap = w.wait_for(lambda s: s.state == "finished", 60)
    assert snap.live is not None and snap.live.render_color is not None, w.error
    assert snap.live.color.shape == (240, 320, 3)                    # the captured frame as it is
    assert snap.live.render_color.shape == (150, LIVE_TILE_WIDTH, 3)
    assert live_mosaic(snap).shape == (2 * 150, 3 * LIVE_TILE_WIDTH, 3)


class FakeClient:
    """Enough of a viser ClientHandle for the scrubber: its own GUI and scene on the real server,
    recording which scene names it shadows with hidden nodes."""

    def __init__(self, server, client_id):
        import types

        from viser import ViserServer  # noqa: F401
        self.client_id = client_id
        self.hidden: set = set()
        self.camera = types.SimpleNamespace(position=np.zeros(3), look_at=np.array([0.0, 0.0, 1.0]),
                                            up_direction=np.array([0.0, -1.0, 0.0]))
        self._websock_connection = MessageLog()
        self.gui = server.gui
        outer = self

        class Scene:
            def add_frame(self, name, visible=True, **_):
                if not visible:
                    outer.hidden.add(name)
                return types.SimpleNamespace(remove=lambda: outer.hidden.discard(name))

            def add_camera_frustum(self, name, **_):
                return types.SimpleNamespace(remove=lambda: None, on_click=lambda cb: None)
        self.scene = Scene()

    def atomic(self):
        import contextlib
        return contextlib.nullcontext()


def test_viewer_builds_chunks_scrubs_and_exports(server, tmp_path):
    from app.viewer import build_viewer

    pipe = FakePipeline(total=6, per_frame=50)
    w = SlamWorker(pipe, live_render=False)
    app = build_viewer(server, w, export_dir=tmp_path, render_backend="reference", update_hz=20,
                       running_update_hz=20)
    try:
        w.start()
        w.wait_for(lambda s: s.state == "finished", 60)
        wait_until(lambda: app.applied is not None and app.applied.state == "finished", 60)
        names = sorted(app.map_layer.node_names)
        assert names == ["/map/kf_000000", "/map/kf_000002", "/map/kf_000004", "/map/tail"]
        assert app.map_layer.consolidations >= 1               # the end of the run consolidates
        assert sorted(app.camera_layer.keyframe_frames) == [0, 2, 4]
        assert "6 / 6" in app.panels.status.content
        # scrubbing is per page: a page scrubbed to the first keyframe hides later chunks for itself only
        page_a, page_b = FakeClient(server, 0), FakeClient(server, 1)
        for c in (page_a, page_b):
            app.scrubber.attach(c)
        scrub_a = app.scrubber.pages[0]
        assert scrub_a.slider.max == 3 and scrub_a.slider.value == 3 and scrub_a.follow.value
        app.scrubber.go_to(0, 0)
        assert scrub_a.slider.value == 1 and not scrub_a.follow.value
        first = app.scrubber.snapshot.keyframes[0].c2w                 # page a's camera flies there
        placed = page_a._websock_connection.placed()
        assert np.allclose(placed["position"], first[:3, 3]) and placed["look_at"] @ first[:3, 2] > 0
        assert page_b._websock_connection.placed()["position"] is None
        assert {"/map/kf_000002", "/map/kf_000004", "/map/tail", "/keyframes"} <= set(page_a.hidden)
        assert "/map/kf_000000" not in page_a.hidden and not page_b.hidden
        assert app.scrubber.birth_limit(0) == 0 and app.scrubber.birth_limit(1) is None
        wait_until(lambda: "Keyframe 1 / 3" in scrub_a.info.content and "PSNR" in scrub_a.info.content, 30,
                   what="keyframe render")
        assert app.scrubber.pages[1].follow.value and app.scrubber.pages[1].slider.value == 3
        scrub_a.follow.value = True                          # ticking "Follow latest" un-hides
        assert app.scrubber.position_of(0) is None and not page_a.hidden and scrub_a.slider.value == 3
        assert all(h.visible for h in app.map_layer._nodes.values())   # the shared scene was never touched
        assert app.map_layer.policy == "keyframes"          # the page's "Map updates" sets the policy
        app.panels.map_updates.value = "continuous"
        assert app.map_layer.policy == "continuous"
        assert app.map_layer.budget is None                 # "Splats while running" sets the budget
        app.panels.browser_splats.value = 5000
        assert app.map_layer.budget == 5000
        app.panels.browser_splats.value = 0
        assert app.map_layer.budget is None
        assert app.map_layer.running_style == "auto"        # and "Draw while running" the style
        app.panels.draw_while_running.value = "points"
        assert app.map_layer.running_style == "points"
        # one export path: map and trajectory land in the run folder's exports/
        path = app.export_panel.export("ply")
        assert path == tmp_path / "exports" / "map.ply"
        assert len(read_ply(path)["means"]) == 300
        path = app.export_panel.export("trajectory")
        assert path == tmp_path / "exports" / "trajectory.txt"
        stamps, c2w = read_tum_trajectory(path)
        assert len(stamps) == 6 and np.allclose(c2w[3][:3, 3], [0.3, 0, 0])
        assert app.export_panel.note.content == "Exports the finished run's map."
    finally:
        app.close()


def test_consolidation_resends_only_the_chunks_that_changed(server):
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import MapLayer

    m = blob_map(300, 0).to_numpy()
    m["birth_frame"] = np.repeat([0, 5, 10], 100)               # three keyframe chunks, no tail
    kfs = tuple(KeyframeView(f, np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in (0, 5, 10))
    snap = lambda version, g: MapSnapshot(version, "running", 10, 11, version, g, kfs)  # noqa: E731
    layer = MapLayer(server)
    assert layer.update(snap(1, m), force_consolidate=True) and layer.chunks_sent == 3
    moved = {k: np.array(v) for k, v in m.items()}
    moved["means"][250:] += 0.01                                # mapping moved Gaussians of the last chunk only
    assert layer.update(snap(2, moved), force_consolidate=True)
    assert layer.chunks_sent == 4 and layer.consolidations == 2


def test_map_update_policies_hold_back_changes_between_keyframes(server):
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import MapLayer

    m = blob_map(300, 0).to_numpy()
    m["birth_frame"] = np.repeat([0, 5, 7], 100)                # two keyframe chunks and a tail

    def snap(version, keyframes, state="running"):
        kfs = tuple(KeyframeView(f, np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in keyframes)
        g = {k: np.array(v) for k, v in m.items()}
        g["means"][200:] += 0.001 * version                     # the tail keeps changing
        return MapSnapshot(version, state, 7, 20, version, g, kfs)

    layer = MapLayer(server)                                    # default: "keyframes"
    assert layer.update(snap(1, (0, 5)))                        # first push
    sent = layer.chunks_sent
    assert not layer.update(snap(2, (0, 5)))                    # a new map, no new keyframe: held
    assert layer.chunks_sent == sent
    assert layer.update(snap(3, (0, 5), "paused"), force_consolidate=True)   # pausing sends it
    assert layer.chunks_sent == sent + 1                        # the changed tail only
    m["birth_frame"][200:] = 10
    assert layer.update(snap(4, (0, 5, 10)))                    # a keyframe arrives: pushed
    assert "/map/kf_000010" in layer.node_names
    layer.set_policy("continuous")
    assert layer.update(snap(5, (0, 5, 10)))                    # every new map goes out
    layer.set_policy("off")
    assert not layer.update(snap(6, (0, 5, 10, 15)))            # not even keyframes while running
    assert layer.update(snap(7, (0, 5, 10, 15), "finished"), force_consolidate=True)
    with pytest.raises(ValueError, match="map update policy"):
        layer.set_policy("sometimes")


def test_the_camera_layer_follows_the_map_update_policy(server):
    """The current camera and trajectory reach the browser when the splats do (any scene message
    makes viser's page redraw for a while: docs/viewer-notes.md §3), and at once when tracking is lost."""
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer import build_viewer

    class Source:
        snap = None

        def latest(self):
            return self.snap

    m = blob_map(200, 0).to_numpy()

    def snap(version, keyframes, x, state="running", lost=False):
        kfs = tuple(KeyframeView(f, np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in keyframes)
        c2w = np.repeat(np.eye(4)[None], version, axis=0)
        c2w[-1, 0, 3] = x
        return MapSnapshot(version, state, version - 1, 20, 1, m, kfs, estimated_c2w=c2w,
                           lost_frames=(version - 1,) if lost else ())

    source = Source()
    app = build_viewer(server, source)
    try:
        def apply(s):
            apply_snapshot(app, source, s)
            return np.asarray(app.camera_layer._current.position)

        assert np.allclose(apply(snap(2, (0,), 0.1)), [0.1, 0, 0])
        assert np.allclose(apply(snap(3, (0,), 0.2)), [0.1, 0, 0])       # no new keyframe: held
        assert np.allclose(apply(snap(4, (0, 3), 0.3)), [0.3, 0, 0])     # a keyframe: follows
        assert np.allclose(apply(snap(5, (0, 3), 0.35, lost=True)), [0.35, 0, 0])   # tracking lost:
        assert app.camera_layer.lost_shown                                          # shown at once
        assert np.allclose(apply(snap(6, (0, 3), 0.36, lost=True)), [0.35, 0, 0])
        assert np.allclose(apply(snap(7, (0, 3), 0.37)), [0.37, 0, 0])   # and found again
        app.panels.map_updates.value = "continuous"
        assert np.allclose(apply(snap(8, (0, 3), 0.4)), [0.4, 0, 0])     # every snapshot
        app.panels.map_updates.value = "off"
        assert np.allclose(apply(snap(9, (0, 3, 5), 0.5)), [0.4, 0, 0])  # not even keyframes
        assert np.allclose(apply(snap(10, (0, 3, 5), 0.6, "paused")), [0.6, 0, 0])
    finally:
        app.close()


def test_the_panels_follow_a_running_slam_once_a_second(server):
    """While SLAM runs the viewer applies snapshots at running_update_hz (each update is tens of
    messages to every page on SLAM's cores), at update_hz once it pauses or ends or while browsing."""
    from app.snapshot import MapSnapshot
    from app.viewer import build_viewer

    class Source:
        snap = None

        def latest(self):
            return self.snap

    m = blob_map(50, 0).to_numpy()
    source = Source()
    app = build_viewer(server, source)                          # update_hz 2, running_update_hz 1
    try:
        assert app.next_wait() == 0.5                           # nothing shown yet
        apply_snapshot(app, source, MapSnapshot(1, "running", 0, 20, 1, m, ()))
        assert app.next_wait() == 1.0
        apply_snapshot(app, source, MapSnapshot(2, "paused", 1, 20, 1, m, ()))
        assert app.next_wait() == 0.5
        apply_snapshot(app, source, MapSnapshot(3, "running", 2, 20, 1, m, ()))
        assert app.next_wait() == 1.0
        apply_snapshot(app, source, MapSnapshot(4, "finished", 3, 20, 1, m, ()))
        assert app.next_wait() == 0.5
    finally:
        app.close()
    fast = build_viewer(server, source, update_hz=20, running_update_hz=20)   # never slower than update_hz
    try:
        assert fast.next_wait() == 0.05
        apply_snapshot(fast, source, MapSnapshot(5, "running", 4, 20, 1, m, ()))
        assert fast.next_wait() == 0.05
    finally:
        fast.close()


def test_browser_budget_thins_the_map_while_slam_runs(server):
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import MapLayer, splat_payload

    m = blob_map(300, 0).to_numpy()
    m["birth_frame"] = np.repeat([0, 5, 10], 100)               # three keyframe chunks of 100

    def snap(version, state="running"):
        kfs = tuple(KeyframeView(f, np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in (0, 5, 10))
        return MapSnapshot(version, state, 10, 20, version, m, kfs)

    def sent():
        return sum(h.buffer.shape[0] for h in layer._nodes.values())

    layer = MapLayer(server, budget=100)
    assert layer.update(snap(1)) and layer.stride == 4 and sent() == 3 * 25   # 300 > 100: every 4th
    assert layer.update(snap(2, "paused"), force_consolidate=True)
    assert layer.stride == 1 and sent() == 300                   # pausing sends the whole map
    assert MapLayer(server, budget=300).stride_for(snap(3)) == 1
    assert MapLayer(server, budget=299).stride_for(snap(3)) == 2
    # a thinned splat covers the area of the ones it stands for: variances x stride
    _, cov, _, _ = splat_payload(m, np.arange(3))
    _, cov4, _, _ = splat_payload(m, np.arange(3), 4)
    np.testing.assert_allclose(cov4, 4 * cov, rtol=1e-6)


def test_points_while_running_then_splats(server):
    import viser

    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import WORLD_SCALE, MapLayer

    m = blob_map(200, 0).to_numpy()
    m["birth_frame"] = np.repeat([0, 5], 100)                      # two keyframe chunks of 100
    m["logit_opacities"][:10] = -5.0                               # ten nearly transparent Gaussians
    m["log_scales"][:] = np.log(0.01)

    def snap(version, state="running"):
        kfs = tuple(KeyframeView(f, np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in (0, 5))
        return MapSnapshot(version, state, 5, 20, version, m, kfs)

    layer = MapLayer(server, running_style="points")
    assert layer.update(snap(1)) and layer.style == "points"
    chunk = layer._nodes["/map/kf_000000"]
    assert isinstance(chunk, viser.PointCloudHandle)
    assert len(chunk.points) == 90                                 # the faint ten are left out
    np.testing.assert_allclose(chunk.points, m["means"][10:100] * WORLD_SCALE, rtol=1e-6)
    np.testing.assert_array_equal(chunk.colors, np.round(np.clip(m["colors"][10:100], 0, 1) * 255))
    assert chunk.point_size == pytest.approx(0.01 * WORLD_SCALE)   # the chunk's median radius
    assert not layer.update(snap(1))                               # nothing new, nothing sent
    assert layer.update(snap(2, "paused")) and layer.style == "splats"   # pausing: splats again
    assert all(isinstance(h, viser.GaussianSplatHandle) for h in layer._nodes.values())
    assert sum(h.buffer.shape[0] for h in layer._nodes.values()) == 200
    layer.budget = 50                                              # the budget thins points too
    assert layer.update(snap(3), force_consolidate=True) and layer.stride == 4 and layer.style == "points"
    assert len(layer._nodes["/map/kf_000005"].points) == 25
    assert layer._nodes["/map/kf_000005"].point_size == pytest.approx(0.01 * WORLD_SCALE * 2)
    with pytest.raises(ValueError, match="points"):
        MapLayer(server, running_style="dots")


def test_auto_draws_points_while_a_page_that_draws_in_software_is_connected(server):
    """`auto` (the default): points while a page that said it draws WebGL in software is connected
    (page_shim.SoftwarePages: its websocket open), splats otherwise and once SLAM pauses."""
    from websockets.protocol import State

    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer import page_shim
    from app.viewer.scene import MapLayer

    m = blob_map(100, 0).to_numpy()
    kfs = (KeyframeView(0, np.eye(4), np.zeros((4, 4, 3), np.uint8)),)

    class Websocket:
        state = State.OPEN

    def drawn(version, state="running"):
        assert layer.update(MapSnapshot(version, state, 5, 20, version, m, kfs))
        return layer.style

    layer = MapLayer(server, policy="continuous")
    assert layer.running_style == "auto"
    assert drawn(1) == "splats"                                    # a plain viser server: nobody said so
    pages = page_shim.SoftwarePages()
    page_shim.attach(server, pages)
    assert drawn(2) == "splats"                                    # no page yet
    page = Websocket()
    pages.add(page)
    assert drawn(3) == "points" and page_shim.software_pages(server) == 1
    assert drawn(4, "paused") == "splats"
    assert drawn(5) == "points"
    page.state = State.CLOSED                                      # the page left
    assert drawn(6) == "splats" and page_shim.software_pages(server) == 0


def test_browse_mode_snapshot(tmp_path):
    from app.browse import load_run

    run = make_run(tmp_path)
    snap = load_run(run)
    assert snap.state == "browse" and snap.num_gaussians == 400 and len(snap.estimated_c2w) == 3
    assert load_run(run / "map.ply").num_gaussians == 400
    with pytest.raises(InputError, match="map.ply"):
        load_run(tmp_path)


def test_export_command(tmp_path):
    run = make_run(tmp_path)
    r = run_cli("export", str(run), "--format", "splat", "--out", str(tmp_path / "m.splat"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "m.splat").stat().st_size == 400 * 32
    r = run_cli("export", str(run), "--out", str(tmp_path / "copy.ply"))
    assert r.returncode == 0, r.stderr
    assert len(read_ply(tmp_path / "copy.ply")["means"]) == 400
    r = run_cli("export", str(tmp_path / "nowhere"), "--format", "ply", "--out", str(tmp_path / "x.ply"))
    assert r.returncode == 2 and "nowhere" in r.stderr and "Traceback" not in r.stderr


def test_render_command(tmp_path):
    import cv2

    run = make_run(tmp_path)
    r = run_cli("render", str(run), "--trajectory", str(run / "trajectory.txt"), "--out", str(tmp_path / "img"),
                "--width", "48", "--height", "36", "--backend", "reference")
    assert r.returncode == 0, r.stderr
    files = sorted((tmp_path / "img").glob("*.png"))
    assert [f.name for f in files] == ["000000.png", "000001.png", "000002.png"]
    img = cv2.imread(str(files[0]))
    assert img.shape == (36, 48, 3)
    assert img[18, 24, 2] > 150 and img[18, 24, 0] < 100        # the red patch, seen head-on (BGR)
    r = run_cli("render", str(run), "--trajectory", str(run / "trajectory.txt"), "--out", str(tmp_path / "d"),
                "--mode", "depth", "--width", "32", "--height", "24", "--backend", "reference")
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "d").glob("*.png"))) == 3


def test_viewer_refuses_a_busy_explicit_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        r = run_cli_viewer("--port", str(port), "--open", "nowhere.ply")
        assert r.returncode == 2
    from app.commands.viewer import port_is_free, start_server
    assert port_is_free("127.0.0.1", port)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        with pytest.raises(InputError, match="already in use"):
            start_server("127.0.0.1", s.getsockname()[1])


def run_cli_viewer(*argv, timeout=60):
    code = "import sys; from app.cli import viewer_main; sys.exit(viewer_main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=timeout)


def test_viewer_cli_open_prints_the_real_port(tmp_path):
    run = make_run(tmp_path)
    code = "import sys; from app.cli import viewer_main; sys.exit(viewer_main(sys.argv[1:]))"
    p = subprocess.Popen([sys.executable, "-c", code, "--open", str(run), "--port", "0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        url = None
        while time.monotonic() < deadline and url is None:
            line = p.stdout.readline()
            if line.startswith("URL "):
                url = line.split()[1]
        assert url and url.startswith("http://127.0.0.1:") and not url.endswith(":0/")
        import urllib.request
        assert b"<html" in urllib.request.urlopen(url, timeout=10).read(2000).lower()
    finally:
        p.terminate()
        p.wait(timeout=20)
