"""SLAM's rate headless and inside the viewer with a headless websocket client; prints JSON.

    python benchmarks/viewer_gpu.py --frames 40 --config gpu --size 640x480 [--device cuda] [--json]

For machines without a browser (the GPU machine of benchmarks/gpu.sh): the same comparison as
benchmarks/viewer.py --slam-frames, but the client is a plain websocket client speaking viser's
subprotocol that receives (and counts) every message the viewer sends, instead of Chromium.
So it measures what serving a client costs SLAM on the server (scene and map updates, the live
panel's renders on the device), not a browser's drawing.

Runs, one after the other in this process: the Pipeline alone on the first --frames synthetic
frames (live engine), then the same inside the viewer (SlamWorker + build_viewer) with the
client connected. Reports the median wall-clock s/frame of each (frame 0 left out), their ratio
(viewer fps / headless fps; the issue's target is >= 0.9), the bytes and messages the client
received, and peak GPU memory (CUDA).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def camera_message(width: int = 800, height: int = 600) -> bytes:
    """The page's first message: its camera (looking along +z from 1.5 m behind the origin)."""
    import msgspec
    from viser._messages import ViewerCameraMessage

    msg = ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, -1.5), fov=1.0, near=0.01, far=100.0,
                              image_height=height, image_width=width, look_at=(0.0, 0.0, 1.0),
                              up_direction=(0.0, -1.0, 0.0))
    return msgspec.msgpack.encode(msg.as_serializable_dict())


class WebsocketClient(threading.Thread):
    """Connects to a viser server as its page would (subprotocol viser-v<version>), sends a
    camera, and reads every message until stopped."""

    def __init__(self, port: int):
        super().__init__(name="ws-client", daemon=True)
        self.port = port
        self.messages = 0
        self.bytes = 0
        self.error: str | None = None
        self.connected = threading.Event()
        self._halt = threading.Event()

    def run(self) -> None:
        import viser
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect

        try:
            with connect(f"ws://127.0.0.1:{self.port}", subprotocols=[f"viser-v{viser.__version__}"],
                         max_size=None, compression=None, open_timeout=30) as ws:
                ws.send(camera_message())      # the server counts a client as connected from its first camera
                self.connected.set()
                while not self._halt.is_set():
                    try:
                        message = ws.recv(timeout=0.2)
                    except TimeoutError:
                        continue
                    except ConnectionClosed:
                        break
                    self.messages += 1
                    self.bytes += len(message)
        except Exception as e:          # reported in the JSON
            self.error = f"{type(e).__name__}: {e}"
            self.connected.set()

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=10)


def _pipeline(frames: int, config: str, size: tuple[int, int], device: str):
    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import SyntheticSource

    source = SyntheticSource(n_frames=frames, width=size[0], height=size[1], seed=0)
    return Pipeline(source, load_config(config), None, device=device, engine="live")


def _median(records) -> float:
    return statistics.median(r["wall_seconds"] for r in records[1:])


def measure(frames: int, config: str, size: tuple[int, int], device: str) -> dict:
    import torch
    import viser

    from app.viewer import build_viewer
    from app.worker import SlamWorker

    pipe = _pipeline(frames, config, size, device)
    while pipe.step() is not None:
        pass
    pipe.finish()
    headless = _median(pipe.records)

    pipe = _pipeline(frames, config, size, device)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    client = WebsocketClient(server.get_port())
    try:
        worker = SlamWorker(pipe, start_paused=True)
        app = build_viewer(server, worker)
        client.start()
        client.connected.wait(30)
        t0 = time.monotonic()
        while not server.get_clients() and time.monotonic() - t0 < 30:
            time.sleep(0.05)
        clients = len(server.get_clients())
        worker.start()
        worker.resume()
        worker.join()
        time.sleep(0.5)                  # the last updates reach the client
        app.close()
    finally:
        client.stop()
        server.stop()
    if worker.error is not None:
        raise RuntimeError(f"SLAM failed in the viewer: {worker.error}")
    viewer = _median(pipe.records)
    out = dict(frames=frames, config=config, size=list(size), device=str(pipe.device), engine="live",
               headless_s_per_frame=round(headless, 4), viewer_s_per_frame=round(viewer, 4),
               headless_fps=round(1.0 / headless, 2), viewer_fps=round(1.0 / viewer, 2),
               viewer_fps_over_headless_fps=round(headless / viewer, 3), target_ratio=0.9,
               clients_connected=clients, client_messages=client.messages, client_bytes=client.bytes,
               client_error=client.error)
    if pipe.device.type == "cuda":
        out["peak_gpu_memory_mb"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--config", default="gpu")
    p.add_argument("--size", default="640x480", help="synthetic frames' WxH")
    p.add_argument("--device", default="auto")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    stdout = sys.stdout
    sys.stdout = sys.stderr          # viser prints banners: keep stdout to the JSON
    result = measure(args.frames, args.config, (w, h), args.device)
    print(json.dumps(result, indent=1 if args.json else None), file=stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
