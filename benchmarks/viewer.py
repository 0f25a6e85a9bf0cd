"""Viewer costs: server-side map updates as the map grows, and time to first splats in a browser.

    python benchmarks/viewer.py [--json] [--sizes 10000,100000,500000] [--client-sizes 10000,100000]
    python benchmarks/viewer.py --slam-frames 30 [--engine live] [--config cpu] [--map-updates keyframes|continuous|off]
                                [--browser-splats N] [--draw-while-running splats,points] [--layers] --sizes '' --client-sizes ''
    python benchmarks/viewer.py --sizes '' --client-sizes '' --idle-sizes 5000,100000 --idle-styles splats,points [--idle-pages viewer,viser]
                                [--idle-viewports 800x600,400x300] [--idle-redraw full]

--slam-frames N: SLAM's rate on the first N synthetic frames headless (Pipeline alone) and in the
viewer with a browser connected (SlamWorker + build_viewer on the server `splatam-viewer` starts,
its page scripts included, + headless Chromium on the page, once for each --draw-while-running style), one after the other in this process
(headless first in even repeats, last in odd ones: --first-repeat numbers them); the median wall-clock
s/frame of each (frame 0 left out) and their ratio (viewer fps / headless fps), the same with the
mean s/frame (frames after 0: the waits for the mapper, and the frames that paid for a viewer
update, included: mean_rate_over_headless), and the CPU the browser used meanwhile (browser_cpu_cores:
Chromium's CPU seconds per wall-clock second while SLAM ran in the viewer). --before DIR: the same
measurement of another checkout's app and engine (a child process importing from DIR), each
repeat right after this checkout's, as `slam_rate_before`. --layers: also SLAM's rate in the
viewer's layers one by one (the SLAM worker without and with the live panel's render, the viewer
with no browser), where the viewer's cost goes.

Server side (no browser): snapshot build (numpy copies of a GaussianMap), the first push of a
map of N Gaussians split into keyframe chunks, a consolidation (set_gaussians on every chunk),
and adding one new 5k-Gaussian keyframe chunk.
Client side: headless Debian Chromium with SOFTWARE WebGL (SwiftShader), measured by polling
client.get_render until the splats show. --idle-sizes N,...: Chromium's CPU (cores) and frames
per second over 20 s on a page that shows a static map of N Gaussians and receives nothing (the
page as splatam-viewer serves it, or viser's own: --idle-pages).
These figures are worst cases that say nothing about a real GPU; sizes above --client-sizes are
skipped because SwiftShader needs minutes there.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

# As splatam-viewer, before torch (splat_core/openmp_env.py; not imported from here: --before's
# child imports DIR's splat_core, which may not have it).
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ.update(OMP_WAIT_POLICY="PASSIVE", GOMP_SPINCOUNT="10000")
CODE = os.environ.get("SPLATAM_CODE") or str(Path(__file__).resolve().parent.parent)   # --before's child: DIR
sys.path.insert(0, CODE)
sys.path.insert(0, str(Path(__file__).resolve().parent))

from app.snapshot import MAP_UPDATE_POLICIES, RUNNING_STYLES, KeyframeView, MapSnapshot, freeze_gaussians  # noqa: E402
from app.viewer.scene import MapLayer  # noqa: E402
from splat_core.gaussians import GaussianMap  # noqa: E402

from common import CHROMIUM, CHROMIUM_ARGS, changed_pixels, machine  # noqa: E402


def synthetic_map(n: int, keyframes: int, seed: int = 0) -> GaussianMap:
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-2, -1, 1], [2, 1, 4], (n, 3))
    m = GaussianMap.from_points(pts, rng.uniform(0, 1, (n, 3)), rng.uniform(0.005, 0.03, n), 0)
    m.birth_frame = np.sort(rng.integers(0, keyframes * 5, n))
    import torch
    m.birth_frame = torch.as_tensor(m.birth_frame)
    return m


def snapshot_of(arrays: dict, keyframe_frames, version: int = 1) -> MapSnapshot:
    kfs = tuple(KeyframeView(int(f), np.eye(4), np.zeros((4, 4, 3), np.uint8)) for f in keyframe_frames)
    return MapSnapshot(version=version, state="running", frame_index=int(max(keyframe_frames)),
                       total_frames=int(max(keyframe_frames)) + 1, map_version=version,
                       gaussians=arrays, keyframes=kfs)


def timed(fn, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def server_side(n: int) -> dict:
    import viser

    K = 20
    m = synthetic_map(n, K)
    kf_frames = list(range(0, K * 5, 5))
    snap_s = timed(lambda: freeze_gaussians(m.to_numpy()))
    arrays = freeze_gaussians(m.to_numpy())
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        layer = MapLayer(server, consolidate_every=10**9, consolidate_interval_s=1e9)
        t0 = time.perf_counter()
        layer.update(snapshot_of(arrays, kf_frames, 1))
        first_push = time.perf_counter() - t0
        t0 = time.perf_counter()
        layer.update(snapshot_of(arrays, kf_frames, 2), force_consolidate=True)
        consolidate = time.perf_counter() - t0
        extra = synthetic_map(5000, 1, seed=1)
        extra.birth_frame[:] = K * 5
        m.append(extra)
        grown = freeze_gaussians(m.to_numpy())
        t0 = time.perf_counter()
        layer.update(snapshot_of(grown, kf_frames + [K * 5], 3))
        chunk = time.perf_counter() - t0
    finally:
        server.stop()
    return dict(gaussians=n, snapshot_build_s=round(snap_s, 4), first_push_s=round(first_push, 4),
                consolidation_s=round(consolidate, 4), add_5k_chunk_s=round(chunk, 4),
                chunks=K + 1)


@contextlib.contextmanager
def chromium_page(server, init_script: str | None = None, viewport=(800, 600), query: str = ""):
    """Headless Chromium (software WebGL, the browser tests' flags) on the server's page (`query`:
    the URL's ?... part), connected."""
    from playwright.sync_api import sync_playwright

    pw = sync_playwright().start()
    browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
    try:
        page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
        if init_script:
            page.add_init_script(init_script)
        page.goto(f"http://127.0.0.1:{server.get_port()}/{query}")
        page.wait_for_function("() => !document.body.innerText.includes('Connecting')", timeout=60_000)
        yield page
    finally:
        browser.close()
        pw.stop()


def client_side(n: int, timeout: float) -> dict:
    import viser

    from app.viewer import StaticSource, build_viewer
    from app.viewer.page_camera import place

    m = synthetic_map(n, 20)
    snap = snapshot_of(freeze_gaussians(m.to_numpy()), list(range(0, 100, 5)))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        with chromium_page(server):
            t_wait = time.monotonic()
            while not server.get_clients() and time.monotonic() - t_wait < 60:
                time.sleep(0.05)
            client = next(iter(server.get_clients().values()))
            place(client, (0.0, 0.0, -1.5), (0.0, 0.0, 2.5))
            empty = np.asarray(client.get_render(120, 160, timeout=60), np.int32)
            t0 = time.monotonic()
            app = build_viewer(server, StaticSource(snap))   # the viewer starts pushing now
            seen = None
            while time.monotonic() - t0 < timeout:
                img = np.asarray(client.get_render(120, 160, timeout=max(5.0, timeout)), np.int32)
                if changed_pixels(img, empty) > 1000:
                    seen = time.monotonic() - t0
                    break
                time.sleep(0.2)
            app.close()
    finally:
        server.stop()
    return dict(gaussians=n, first_splats_in_browser_s=None if seen is None else round(seen, 2),
                timed_out=seen is None)


def browser_cpu_seconds() -> float:
    """User + system CPU seconds of the running Chromium processes (from Linux's /proc; 0 elsewhere)."""
    ticks = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:          # the process ended meanwhile
            continue
        if "chrom" in text[text.find("(") + 1:text.rfind(")")]:
            fields = text[text.rfind(")") + 2:].split()
            ticks += int(fields[11]) + int(fields[12])    # utime, stime
    return ticks / os.sysconf("SC_CLK_TCK") if ticks else 0.0


def idle_browser(n: int, style: str = "splats", seconds: float = 20.0, served: str = "viewer",
                 viewport: tuple = (800, 600), redraw: str | None = None) -> dict:
    """Chromium's CPU and frame rate on a page showing a static map of n Gaussians drawn as `style`
    (the viewer's splats or points), nothing changing; `served`: "viewer" (the page as
    splatam-viewer serves it, app/viewer/page_shim.py's scripts included) or "viser" (viser's own);
    `viewport`: the page's size in CSS pixels; `redraw`: the page's ?redraw= (page_shim.py: "full"
    draws every animation frame). cpu_seconds_per_draw: Chromium's CPU per view drawn (the frames
    when every frame draws)."""
    import viser

    from app.commands.viewer import start_server
    from app.viewer.scene import MapLayer

    server = start_server("127.0.0.1", 0) if served == "viewer" else viser.ViserServer(host="127.0.0.1", port=0,
                                                                                        verbose=False)
    if n:
        layer = MapLayer(server, running_style=style)
        layer.update(dataclasses.replace(snapshot_of(freeze_gaussians(synthetic_map(n, 1).to_numpy()), [0]),
                                         state="running"))
    count_frames = """(() => { window.__frames = 0; const raf = window.requestAnimationFrame.bind(window);
        window.requestAnimationFrame = (cb) => raf((t) => { window.__frames++; cb(t); }); })();"""
    try:
        with chromium_page(server, count_frames, viewport, "?redraw=" + redraw if redraw else "") as page:
            time.sleep(15)                                    # the splats arrive, sort and fade in
            drawn = "(window.__splatamRedraw || {}).drawn"           # frames the view drew (page_shim.py)
            cpu0, frames0, t0 = browser_cpu_seconds(), page.evaluate("window.__frames"), time.monotonic()
            drawn0 = page.evaluate(drawn)
            time.sleep(seconds)
            dt = time.monotonic() - t0
            drawn1 = page.evaluate(drawn)
            cpu = browser_cpu_seconds() - cpu0
            frames = page.evaluate("window.__frames") - frames0
            counted = drawn0 is not None and redraw != "full"      # the shim counts only held pages' draws
            draws = drawn1 - drawn0 if counted else frames
            return dict(gaussians=n, style=style, page=served, viewport=list(viewport), redraw=redraw,
                        browser_cpu_cores=round(cpu / dt, 3), frames_per_second=round(frames / dt, 2),
                        drawn_per_second=round(draws / dt, 2) if counted else None,
                        cpu_seconds_per_draw=round(cpu / draws, 3) if draws else None)
    finally:
        server.stop()


def layer_rate(headless: float, runs: list) -> dict:
    """A --layers record: the median s/frame of `runs` and its rate over the headless median's."""
    import statistics

    m = statistics.median(runs)
    return dict(s_per_frame=round(m, 3), fps_over_headless_fps=round(headless / m, 3), runs=runs)


def style_option(style: str) -> dict:
    """build_viewer's draw_while_running, or nothing (its default) where the checkout measured does
    not know the style (--before an older checkout: "auto" is newer)."""
    return dict(draw_while_running=style) if style in RUNNING_STYLES else {}


def slam_rate(frames: int, engine: str, config: str, repeats: int = 1, map_updates: str = "keyframes",
              browser_splats: int | None = None, styles: tuple = ("splats",), layers: bool = False,
              first_repeat: int = 0) -> dict:
    """Median s/frame of SLAM headless and inside the viewer with a browser watching, for each
    way of drawing the map while SLAM runs (`styles`); each repeat runs headless and each style, headless
    first in even repeats and last in odd ones, counting from `first_repeat` (so that neither side
    always runs first on a machine that warms up or is disturbed in step with the repeats).
    `layers`: each repeat also runs SLAM in the viewer's layers one by one, where its cost goes:
    the SLAM worker alone without and with the live panel's render, and the viewer (server,
    worker, live panel) with no browser."""
    import statistics

    from app.commands.viewer import start_server
    from app.viewer import build_viewer
    from app.worker import SlamWorker
    from splat_core.config import load_config
    from splat_core.run import Pipeline, open_input

    def pipeline():
        return Pipeline(open_input(None), load_config(config), None, max_frames=frames, engine=engine)

    def median(records):
        return statistics.median(r["wall_seconds"] for r in records[1:])

    def mean(records):     # frames after 0, the waits for the mapper and the viewer's slower frames included
        return statistics.fmean(r["wall_seconds"] for r in records[1:])

    def run_headless():
        pipe = pipeline()
        while pipe.step() is not None:
            pass
        pipe.finish()
        headless.append(median(pipe.records))
        headless_means.append(mean(pipe.records))

    def layer(with_viewer: bool, live_render: bool = True):
        """SLAM's median s/frame in the worker alone, or in the viewer with no browser."""
        pipe = pipeline()
        worker = SlamWorker(pipe, live_render=live_render)
        server = start_server("127.0.0.1", 0) if with_viewer else None
        try:
            app = server and build_viewer(server, worker, map_updates=map_updates, browser_splats=browser_splats,
                                          **style_option(styles[0]))
            worker.start()
            worker.join()
            if app:
                app.close()
        finally:
            if server:
                server.stop()
        return median(pipe.records)

    layer_runs = {"worker, no live panel": [], "worker and live panel": [], "viewer, no browser": []}
    headless, headless_means = [], []
    viewer = {style: [] for style in styles}
    viewer_means = {style: [] for style in styles}
    browser_cpu = {style: [] for style in styles}
    redraw = {style: None for style in styles}      # the page's draw counts (page_shim.py), if it has them
    for repeat in range(first_repeat, first_repeat + repeats):
        if repeat % 2 == 0:
            run_headless()
        if layers:
            layer_runs["worker, no live panel"].append(layer(False, live_render=False))
            layer_runs["worker and live panel"].append(layer(False))
            layer_runs["viewer, no browser"].append(layer(True))
        for style in styles:
            pipe = pipeline()
            server = start_server("127.0.0.1", 0)      # as splatam-viewer serves its page
            try:
                worker = SlamWorker(pipe, start_paused=True)
                app = build_viewer(server, worker, map_updates=map_updates, browser_splats=browser_splats,
                                   **style_option(style))
                with chromium_page(server) as page:
                    cpu0, t0 = browser_cpu_seconds(), time.monotonic()
                    worker.start()
                    worker.resume()
                    worker.join()
                    browser_cpu[style].append((browser_cpu_seconds() - cpu0) / (time.monotonic() - t0))
                    redraw[style] = page.evaluate("() => window.__splatamRedraw || null")
                viewer[style].append(median(pipe.records))
                viewer_means[style].append(mean(pipe.records))
                app.close()
            finally:
                server.stop()
        if repeat % 2 == 1:
            run_headless()
    h, hm = statistics.median(headless), statistics.median(headless_means)
    return dict(frames=frames, engine=engine, config=config, map_updates=map_updates, browser_splats=browser_splats,
                headless_s_per_frame=round(h, 3), headless_runs=headless,
                headless_mean_s_per_frame=round(hm, 3), headless_mean_runs=headless_means,
                viewer=[dict(draw_while_running=style if style in RUNNING_STYLES else f"{style}: unknown, the default",
                             viewer_s_per_frame=round(statistics.median(viewer[style]), 3),
                             viewer_fps_over_headless_fps=round(h / statistics.median(viewer[style]), 3),
                             viewer_mean_s_per_frame=round(statistics.median(viewer_means[style]), 3),
                             mean_rate_over_headless=round(hm / statistics.median(viewer_means[style]), 3),
                             browser_cpu_cores=round(statistics.median(browser_cpu[style]), 3),
                             page_redraw=redraw[style],
                             runs=dict(viewer=viewer[style], viewer_mean=viewer_means[style],
                                       browser_cpu_cores=browser_cpu[style]))
                        for style in styles],
                layers={name: layer_rate(h, runs) for name, runs in layer_runs.items() if runs})


def merged(rates: list[dict]) -> dict:
    """One slam_rate record from several one-repeat records: medians over them."""
    import statistics

    first = dict(rates[0])
    heads = [h for r in rates for h in r["headless_runs"]]
    h = statistics.median(heads)
    head_means = [h for r in rates for h in r.get("headless_mean_runs", [])]    # an older checkout's child: none
    hm = statistics.median(head_means) if head_means else None
    views = []
    for k, v in enumerate(first["viewer"]):
        runs = [r["viewer"][k]["runs"]["viewer"][0] for r in rates]
        means = [x for r in rates for x in r["viewer"][k]["runs"].get("viewer_mean", [])]
        cpu = [r["viewer"][k]["runs"]["browser_cpu_cores"][0] for r in rates]
        views.append(dict(draw_while_running=v["draw_while_running"],
                          viewer_s_per_frame=round(statistics.median(runs), 3),
                          viewer_fps_over_headless_fps=round(h / statistics.median(runs), 3),
                          viewer_mean_s_per_frame=round(statistics.median(means), 3) if means else None,
                          mean_rate_over_headless=round(hm / statistics.median(means), 3) if means and hm else None,
                          browser_cpu_cores=round(statistics.median(cpu), 3),
                          page_redraw=[r["viewer"][k].get("page_redraw") for r in rates],
                          runs=dict(viewer=runs, viewer_mean=means, browser_cpu_cores=cpu)))
    layers = {name: layer_rate(h, [x for r in rates for x in r["layers"][name]["runs"]])
              for name in first.get("layers", {})}
    first.update(headless_s_per_frame=round(h, 3), headless_runs=heads, viewer=views, layers=layers,
                 headless_mean_s_per_frame=None if hm is None else round(hm, 3), headless_mean_runs=head_means)
    return first


def slam_rate_of(code: Path, args, repeat: int) -> dict:
    """slam_rate() of another checkout (one repeat, number `repeat`), in a child process importing from `code`."""
    import subprocess

    cmd = [sys.executable, __file__, "--json", "--sizes", "", "--client-sizes", "", "--slam-frames",
           str(args.slam_frames), "--engine", args.engine, "--config", args.config, "--map-updates",
           args.map_updates, "--draw-while-running", args.draw_while_running, "--first-repeat", str(repeat)]
    if args.browser_splats is not None:
        cmd += ["--browser-splats", str(args.browser_splats)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, SPLATAM_CODE=str(code)),
                          check=True)
    return json.loads(done.stdout)["slam_rate"]


def commit_of(code: Path) -> str:
    import subprocess

    return subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true")
    p.add_argument("--sizes", default="10000,100000,500000")
    p.add_argument("--client-sizes", default="10000,100000",
                   help="sizes timed in headless Chromium (software WebGL); '' to skip")
    p.add_argument("--client-timeout", type=float, default=180.0)
    p.add_argument("--idle-sizes", default="",
                   help="also Chromium's CPU on a page showing a static map of these sizes, nothing changing")
    p.add_argument("--idle-styles", default="splats", help="... drawn as splats and/or points (comma-separated)")
    p.add_argument("--idle-pages", default="viewer", help="... on the viewer's page and/or viser's own (viewer,viser)")
    p.add_argument("--idle-viewports", default="800x600", help="... at these page sizes (CSS pixels, comma-separated)")
    p.add_argument("--idle-redraw", default=None, help="... with this ?redraw= (full: every frame draws; page_shim.py)")
    p.add_argument("--slam-frames", type=int, default=0, help="also compare SLAM's rate headless and in the viewer")
    p.add_argument("--engine", default="live")
    p.add_argument("--config", default="cpu")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--first-repeat", type=int, default=0,
                   help="number the repeats from this one: headless runs first in even repeats, last in odd ones")
    p.add_argument("--map-updates", default="keyframes", choices=MAP_UPDATE_POLICIES,
                   help="the viewer's map update policy during the --slam-frames run")
    p.add_argument("--browser-splats", type=int, default=None,
                   help="the viewer's --browser-splats during the --slam-frames run")
    p.add_argument("--layers", action="store_true",
                   help="--slam-frames: also SLAM in the viewer's layers one by one (the worker without and with "
                        "the live panel, the viewer with no browser), this checkout only")
    p.add_argument("--before", default=None, help="another checkout: its SLAM rate in the viewer too (--slam-frames)")
    p.add_argument("--draw-while-running", default="auto",
                   help="the viewer's --draw-while-running during the --slam-frames run; 'splats,points' "
                        "runs the viewer once with each after every headless run")
    args = p.parse_args()
    stdout = sys.stdout
    if args.json:            # viser prints its banner for every server: keep stdout to the JSON
        sys.stdout = sys.stderr
    out = dict(machine=machine(), python=platform.python_version(),
               server=[], client=[],
               client_caveat="headless Chromium with SwiftShader software WebGL: worst case, not GPU figures")
    for n in [int(s) for s in args.sizes.split(",") if s]:
        out["server"].append(server_side(n))
        if not args.json:
            print(out["server"][-1], flush=True)
    client_sizes = [int(s) for s in args.client_sizes.split(",") if s]
    skipped = [int(s) for s in args.sizes.split(",") if s and int(s) not in client_sizes]
    if client_sizes and not Path(CHROMIUM).exists():
        out["client_skipped"] = f"{CHROMIUM} not installed"
    else:
        for n in client_sizes:
            out["client"].append(client_side(n, args.client_timeout))
            if not args.json:
                print(out["client"][-1], flush=True)
        if skipped:
            out["client_skipped"] = (f"{skipped}: not timed in the browser (software WebGL needs "
                                     "minutes there; pass --client-sizes to include them)")
    if Path(CHROMIUM).exists():
        viewports = [tuple(int(v) for v in size.split("x")) for size in args.idle_viewports.split(",")]
        out["idle_browser"] = [idle_browser(int(n), style, served=page, viewport=viewport, redraw=args.idle_redraw)
                               for n in args.idle_sizes.split(",") if n for style in args.idle_styles.split(",")
                               for page in args.idle_pages.split(",") for viewport in viewports]
    if args.slam_frames:
        styles = tuple(args.draw_while_running.split(","))
        ours, before = [], []
        for i in range(args.repeats):    # one repeat each in turn: both see the same load
            ours.append(slam_rate(args.slam_frames, args.engine, args.config, 1, args.map_updates,
                                  args.browser_splats, styles, args.layers, first_repeat=args.first_repeat + i))
            if args.before:
                before.append(slam_rate_of(Path(args.before).resolve(), args, args.first_repeat + i))
        out["slam_rate"] = merged(ours)
        if before:
            out["slam_rate_before"] = dict(merged(before), code=str(Path(args.before).resolve()),
                                           commit=commit_of(Path(args.before)))
        if not args.json:
            print(out["slam_rate"], out.get("slam_rate_before", ""), flush=True)
    if args.json:
        print(json.dumps(out, indent=1), file=stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
