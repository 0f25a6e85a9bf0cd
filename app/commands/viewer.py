"""`splatam-viewer`: live SLAM in the browser, or `--open` a finished run / .ply to browse it."""

from __future__ import annotations

import argparse
import contextlib
import io
import shlex
import socket
import sys
import time
from datetime import datetime
from pathlib import Path

from app.console_commands import command
from app.run_setup import add_run_arguments, setup_from_args
from app.snapshot import MAP_UPDATE_POLICIES, RUNNING_STYLES
from app.viewer.access import SHARE_MODES
from splat_core.errors import InputError

DEFAULT_PORT = 8080


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--input", default=None, help="capture folder or .r3d/.zip, or nerfcapture:// for the NeRFCapture "
                   "iPhone app's live stream, recorded to OUT/capture (default: the synthetic demo scene)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; any other address, e.g. "
                        "0.0.0.0 for the network, needs an access token, printed in the URL)")
    p.add_argument("--share", default="control", choices=SHARE_MODES,
                   help="what visitors with the shared URL may do: control (default: pause, export, refine, ...) "
                        "or view (a view-only page; a second URL with a control token is printed for you)")
    p.add_argument("--token", default=None,
                   help="the shared URL's access token (default: generated; needed off loopback, see docs/viewer.md)")
    p.add_argument("--port", type=int, default=None,
                   help=f"port (default {DEFAULT_PORT}, or the next free one; an explicit port must be free; 0 = any)")
    p.add_argument("--out", default=None, help="run folder to write (default: runs/viewer-<time>)")
    add_run_arguments(p, engine_default="live")
    p.add_argument("--open", default=None, metavar="RUN_DIR|MAP.ply",
                   help="browse a finished run folder or a 3DGS .ply instead of running SLAM")
    p.add_argument("--paused", action="store_true", help="start with SLAM paused (press Resume or Step)")
    p.add_argument("--map-updates", default="keyframes", choices=MAP_UPDATE_POLICIES,
                   help="when the browser's 3D view (the growing map, current camera, trajectory) follows "
                        "SLAM: at each keyframe (default), also between keyframes, or only when paused / "
                        "finished (the page's 'Map updates')")
    p.add_argument("--browser-splats", type=positive_int, default=None, metavar="N",
                   help="while SLAM runs, send the browser at most about N Gaussians (a thinned preview with "
                        "larger splats; the whole map when paused or finished): for a browser that draws "
                        "WebGL in software on the machine running SLAM (default: the whole map)")
    p.add_argument("--draw-while-running", default="auto", choices=RUNNING_STYLES,
                   help="how the browser draws the growing map while SLAM runs: splats, or a point per "
                        "Gaussian, which costs a browser that draws WebGL in software a tenth of a splat; "
                        "auto (default): points while a page that draws in software is connected, splats "
                        "otherwise; splats when paused or finished (the page's 'Draw while running')")


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text}: expected a positive number")
    return value


def port_is_free(host: str, port: int) -> bool:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def start_server(host: str, port: int | None, access=None):
    """A viser server; an explicitly requested port must be free (viser would silently move on).
    `access` (app.viewer.access.Access): its tokens guard every request and websocket. The page is
    served with app.viewer.page_shim's script either way. viser prints a banner with the page's URL
    (verbose=False does not stop it): with a token, that URL would not open the page, so the banner
    is dropped and the caller prints the URL with its token."""
    import viser

    from app.viewer.access import check_bind, tolerate_malformed_messages
    from app.viewer.page_shim import attach, serving

    check_bind(host)
    tolerate_malformed_messages()
    explicit = port is not None and port != 0
    if explicit and not port_is_free(host, port):
        raise InputError(f"--port {port}: {host}:{port} is already in use; choose another port or pass --port 0")
    quiet = contextlib.redirect_stdout(io.StringIO()) if access is not None and access.required \
        else contextlib.nullcontext()
    with (access.guard() if access is not None else serving()) as pages, quiet:
        server = viser.ViserServer(host=host, port=DEFAULT_PORT if port is None else port, verbose=False)
    attach(server, pages)
    if access is not None:
        access.port = server.get_port()
    if explicit and server.get_port() != port:
        server.stop()
        raise InputError(f"--port {port}: {host}:{port} is already in use")
    return server


def _stop_on_sigterm() -> None:
    """SIGTERM (a service manager, `kill`) shuts down like Ctrl-C: the run folder is still written."""
    import signal
    import threading

    def handler(signum, frame):
        raise KeyboardInterrupt
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)


def main(args) -> int:
    from app.viewer import StaticSource, build_viewer
    from app.viewer.access import Access

    access = Access.for_host(args.host, share=args.share, token=args.token)
    preview = compiling = None

    worker = stream = None
    if args.open:
        from app.browse import load_run

        opened = Path(args.open)
        snapshot = load_run(opened)
        source = StaticSource(snapshot)
        export_dir = Path(args.out) if args.out else (
            opened / "export" if opened.is_dir() else opened.parent / f"{opened.stem}_export")
        what = f"browsing {opened} ({snapshot.num_gaussians:,} Gaussians)"
    else:
        from app.worker import SlamWorker

        out = Path(args.out) if args.out else Path("runs") / datetime.now().strftime("viewer-%Y%m%d-%H%M%S")
        run = setup_from_args(args, out=out, idle_timeout=None)   # a stream runs until Ctrl-C / --max-frames
        if run.live:
            if not run.realtime:
                print(run.waiting_message(), file=sys.stderr, flush=True)
            stream = run.source
        from app.warmup import KernelCompile, kernels_compiled

        if not kernels_compiled():      # a first run: the page opens at once and shows the compile
            compiling = KernelCompile()
        if not run.live or run.realtime:
            preview = run.source[0]
        worker = SlamWorker(run.start(), start_paused=args.paused,
                            prepare=compiling.run if compiling is not None else None)
        source, export_dir = worker, out
        what = "\n".join(run.lines())

    server = start_server(args.host, args.port, access)
    app = build_viewer(server, source, export_dir=export_dir, map_updates=args.map_updates,
                      browser_splats=args.browser_splats, draw_while_running=args.draw_while_running,
                      access=access, preview_frame=preview)
    _stop_on_sigterm()
    announced = False
    try:                                # from here on Ctrl-C stops SLAM and writes the run folder
        if worker is not None:
            worker.start()
        print(what, file=sys.stderr)
        print_urls(access, args.host, server.get_port())
        progress = CompileProgress(compiling)
        while True:
            time.sleep(0.5)
            progress.tick()
            if worker is not None and not announced and not worker.is_alive():
                announced = True
                snap = worker.latest()
                print(f"SLAM {snap.state}: {snap.message}; the viewer stays up for browsing", flush=True)
                report_written(worker)
    except KeyboardInterrupt:
        pass
    finally:
        if stream is not None:
            stream.close()              # a step waiting for a frame returns; the run folder is written
        if worker is not None and worker.is_alive():
            print("stopping SLAM after this frame and writing the run folder (Ctrl-C again to abort)…",
                  file=sys.stderr, flush=True)
            worker.stop(join_timeout=600)
        if worker is not None and not announced:
            report_written(worker)      # as a run that ended by itself says it (above)
        app.close()
        server.stop()
    return 0


def print_urls(access, host: str, port: int) -> None:
    url = access.url(host, port)
    print(f"splatam-viewer listening on {url}  (Ctrl-C to quit)", flush=True)
    if access.share == "view":
        print(f"  that URL opens a view-only page; yours, with the controls: {access.url(host, port, 'control')}",
              flush=True)
    elif access.required:
        print("  anyone with this URL (its token) can control the run; --share view gives a view-only URL",
              flush=True)
    print(f"URL {url}", flush=True)   # machine-readable line for scripts and tests


class CompileProgress:
    """The kernel compile's progress in the terminal (app.warmup.KernelCompile): a bar redrawn in
    place on a terminal, a line per kernel otherwise; then one line when it is done."""

    def __init__(self, compiling, stream=sys.stderr):
        self.compiling, self.stream = compiling, stream
        self.tty = stream.isatty()
        self._shown = None

    def tick(self) -> None:
        job = self.compiling
        if job is None or job.started_at is None:
            return
        if job.finished:
            print(("\r" if self.tty else "") + f"CPU kernels compiled in {job.seconds:.0f} s; starting SLAM",
                  file=self.stream, flush=True)
            self.compiling = None
            return
        line = job.bar()
        if self.tty:
            print("\r" + line, end="", file=self.stream, flush=True)
        elif line.rsplit(" · ", 1)[0] != self._shown:
            self._shown = line.rsplit(" · ", 1)[0]
            print(line, file=self.stream, flush=True)


def report_written(worker) -> None:
    """Where SLAM wrote its run folder and how to open it, once it has been written."""
    snap = worker.latest()
    if snap is not None and snap.state in ("finished", "stopped") and worker.out_dir is not None:
        out = shlex.quote(str(worker.out_dir))
        print(f"wrote {worker.out_dir}: view it later with {command('splatam-viewer')} --open {out}", flush=True)
