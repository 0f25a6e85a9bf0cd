"""Many viewers and a stalled one: what they cost SLAM and the server's memory (loopback only).

    python benchmarks/viewer_clients.py [--json] [--frames 24] [--clients 10] [--repeats 2] [--engine sequential|live]
                                        [--stall-seconds 60] [--skip-rate]
    python benchmarks/viewer_clients.py --first-page [--first-page-timeout 30]

Clients are websocket clients that read everything the server sends but draw nothing (no browser):
each sends one camera message, as a page does, so the viewer builds its per-page panels for it.

- rate: SLAM (the real pipeline, cpu preset, --engine, synthetic scene) in the viewer with 1
  reading client, then with --clients reading clients, alternating --repeats times after a short
  warm-up run; the median wall-clock s/frame of each run (frame 0 left out) and `ratio` = fps with
  many / fps with one over the medians (target >= 0.9).
- stall: SLAM in the viewer with one reading client and one client that completes the handshake,
  sends its camera message and then never reads again; the server process's resident memory (VmRSS)
  when the stall begins and --stall-seconds later, while SLAM keeps publishing (target < 50 MB growth).
  `stalled_disconnected` says whether the server dropped the stalled client meanwhile; while it is
  connected, what the server holds for it: bytes waiting in its socket's write buffer, messages in
  its own queue, and how far it lags in the shared broadcast buffer (whose size is the scene's, newer
  updates of a node replacing older ones, whoever has not read them).
- first page (--first-page): `splatam-viewer` started as a fresh clone would run it (an empty Numba
  cache: NUMBA_CACHE_DIR in a temporary folder, so the kernels compile), then the seconds from the URL
  answering until headless Chromium shows the first frame's images and the status line. Target < 10 s.
Each part stops by itself (a bounded number of frames or seconds).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from common import CHROMIUM, CHROMIUM_ARGS, machine  # noqa: E402 (benchmarks/common.py)


def rss_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


CAMERA = {"type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, -0.3, -1.0], "fov": 1.0,
          "near": 0.01, "far": 100.0, "image_height": 480, "image_width": 640, "look_at": [0.0, 0.0, 1.5],
          "up_direction": [0.0, -1.0, 0.0]}


class ReadingClient(threading.Thread):
    """A websocket client that reads (and counts) every message until stopped; draws nothing."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        import msgspec
        import viser
        from websockets.sync.client import connect

        self.ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                          max_size=None, open_timeout=30)
        self.ws.send(msgspec.msgpack.encode(CAMERA))
        self.bytes = 0
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                self.bytes += len(self.ws.recv(timeout=0.5))
            except TimeoutError:
                continue
            except Exception:   # noqa: BLE001 - closed
                return

    def close(self) -> None:
        self.stop.set()
        self.ws.close()


def stalled_client(port: int):
    """A raw socket: handshake and a camera message, then nothing is ever read."""
    import base64
    import socket

    import msgspec
    import viser

    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                  f"Sec-WebSocket-Protocol: viser-v{viser.__version__}\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert b" 101 " in head.split(b"\r\n")[0], head
    payload = msgspec.msgpack.encode(CAMERA)
    mask = os.urandom(4)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    sock.sendall(bytes([0x82, 0x80 | 126]) + len(payload).to_bytes(2, "big") + mask + masked)
    return sock


def viewer_run(frames: int, *, readers: int, stall_seconds: float = 0.0, config: str = "cpu",
               engine: str = "live") -> dict:
    """SLAM in the viewer with `readers` reading clients (and a stalled one when stall_seconds > 0)."""
    import viser

    from app.viewer import build_viewer
    from app.worker import SlamWorker
    from splat_core.config import load_config
    from splat_core.run import Pipeline, open_input

    n = frames if not stall_seconds else 10_000
    source = open_input(None, n_frames=600) if stall_seconds else open_input(None)
    pipe = Pipeline(source, load_config(config), None, max_frames=n, engine=engine)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    worker = SlamWorker(pipe, start_paused=True)
    app = build_viewer(server, worker)
    port = server.get_port()
    clients = [ReadingClient(port) for _ in range(readers)]
    for c in clients:
        c.start()
    out = {"readers": readers}
    try:
        worker.start()
        worker.resume()
        if stall_seconds:
            worker.wait_for(lambda s: s.processed >= 2, 600)   # kernels warm, a map to send
            sock = stalled_client(port)
            before, t0 = rss_mb(), time.monotonic()
            peak, frames_at_start = before, worker.latest().processed
            while time.monotonic() - t0 < stall_seconds and worker.is_alive():
                time.sleep(1.0)
                peak = max(peak, rss_mb())
            after = rss_mb()
            ws_server = server._websock_server  # noqa: SLF001 - what the server holds for the stalled client
            live = len(ws_server._live_connections)  # noqa: SLF001
            stalled_id = max(ws_server._live_connections, default=None)  # noqa: SLF001 (the newest)
            if stalled_id is not None and live > readers:
                conn = ws_server._live_connections[stalled_id]  # noqa: SLF001
                state = ws_server._client_state_from_id.get(stalled_id)  # noqa: SLF001
                out["stalled_write_buffer_mb"] = round(conn.transport.get_write_buffer_size() / 2**20, 2)
                out["stalled_pending_messages"] = len(state.message_buffer.message_from_id) if state else 0
                cursor = ws_server._broadcast_buffer.generator_cursors.get(stalled_id, -1)  # noqa: SLF001
                out["stalled_broadcast_lag_messages"] = ws_server._broadcast_buffer.message_counter - 1 - cursor  # noqa: SLF001
                out["broadcast_buffer_messages"] = len(ws_server._broadcast_buffer.message_from_id)  # noqa: SLF001
            out.update(rss_before_mb=round(before, 1), rss_after_mb=round(after, 1), rss_peak_mb=round(peak, 1),
                       growth_mb=round(after - before, 1), peak_growth_mb=round(peak - before, 1),
                       stall_seconds=stall_seconds, frames_during_stall=worker.latest().processed - frames_at_start,
                       connections_at_end=live, stalled_disconnected=live <= readers)
            sock.close()
            worker.stop(join_timeout=600)
        else:
            worker.join()
            records = pipe.records
            out["s_per_frame"] = statistics.median(r["wall_seconds"] for r in records[1:])
            out["frames"] = len(records)
            out["bytes_read_per_client"] = int(statistics.median(c.bytes for c in clients)) if clients else 0
    finally:
        for c in clients:
            c.close()
        app.close()
        server.stop()
    return out


def first_page(timeout: float) -> dict:
    """Seconds from the viewer's URL answering to the first frame's images and status on the page,
    with an empty Numba cache (the kernels compile meanwhile)."""
    import urllib.request

    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="splatam-fresh-") as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=tmp, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        cmd = [sys.executable, "-c", "import sys; from app.cli import viewer_main; sys.exit(viewer_main())",
               "--port", "0", "--out", str(Path(tmp) / "run"), "--max-frames", "3"]
        started = time.monotonic()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        url, lines = None, []
        try:
            while url is None:
                line = proc.stdout.readline()
                if not line:
                    raise RuntimeError("viewer exited:\n" + "".join(lines))
                lines.append(line)
                if line.startswith("URL "):
                    url = line.split()[1]
            threading.Thread(target=lambda: [lines.append(x) for x in proc.stdout], daemon=True).start()
            while True:
                try:
                    urllib.request.urlopen(url, timeout=2)
                    break
                except OSError:
                    time.sleep(0.05)
            answered = time.monotonic()
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1000, "height": 800})
                page.goto(url)
                page.wait_for_function("() => document.body.innerText.includes('Frame #0')"
                                       " && document.body.innerText.includes('Processing frame')",
                                       timeout=timeout * 1000)
                shown = time.monotonic()
                body = page.evaluate("() => document.body.innerText")
                browser.close()
        finally:
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
    return {"seconds_to_url": round(answered - started, 2), "seconds_url_to_page": round(shown - answered, 2),
            "compile_note_shown": "compiling the CPU renderer: first run only" in body,
            "status_text": body[body.find("Processing"):][:160],
            "terminal_note": any("compiling the CPU renderer" in x for x in lines)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--stall-seconds", type=float, default=60.0, help="0: skip the stalled-client part")
    ap.add_argument("--skip-rate", action="store_true")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--engine", default="sequential", choices=("sequential", "live"),
                    help="the rate runs' engine (sequential: a frame's time includes its mapping)")
    ap.add_argument("--first-page", action="store_true", help="only the fresh-clone first-page measurement")
    ap.add_argument("--first-page-timeout", type=float, default=60.0)
    args = ap.parse_args()
    result = {"machine": machine(), "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:])}
    with contextlib.redirect_stdout(sys.stderr):      # viser's banners: stdout stays one JSON document
        measure(args, result)
    print(json.dumps(result, indent=None if args.json else 2))
    return 0


def measure(args, result: dict) -> None:
    if args.first_page:
        result["first_page"] = first_page(args.first_page_timeout)
    else:
        if not args.skip_rate:
            viewer_run(4, readers=0, engine=args.engine)    # warm-up: kernels compiled and loaded
            ones, manys = [], []
            for _ in range(args.repeats):                   # alternate, so drift hits both alike
                ones.append(viewer_run(args.frames, readers=1, engine=args.engine))
                manys.append(viewer_run(args.frames, readers=args.clients, engine=args.engine))
            one = statistics.median(r["s_per_frame"] for r in ones)
            many = statistics.median(r["s_per_frame"] for r in manys)
            result["rate"] = {"one_client_s_per_frame": [round(r["s_per_frame"], 3) for r in ones],
                              "many_clients_s_per_frame": [round(r["s_per_frame"], 3) for r in manys],
                              "clients": args.clients, "engine": args.engine, "bytes_read_per_client": manys[-1]["bytes_read_per_client"],
                              "ratio": round(one / many, 3)}
        if args.stall_seconds:
            result["stall"] = viewer_run(args.frames, readers=1, stall_seconds=args.stall_seconds)


if __name__ == "__main__":
    sys.exit(main())
