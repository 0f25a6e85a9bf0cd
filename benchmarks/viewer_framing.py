"""How much of the page the map fills in the viewer's default view during a live run (issue 45
item 2): `splatam-viewer`'s run (the live engine and the CPU default preset) on a capture, one
headless Chromium page (1280x800) connected from the start and never touched; at frame N the run is
paused (what the page's Pause does) and the page's canvas, as the page draws it, is compared with
the same canvas with the map hidden: map pixels are those that change (frustum images, the panel
over the canvas and the background do not). Prints JSON; --shots DIR keeps both screenshots.
(viser's get_render is not used: at its own resolution it drops most splats of a real map.)

    python benchmarks/viewer_framing.py --input ../shared/data/7scenes_redkitchen_300 --at 200 [--shots DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import changed_pixels, machine  # noqa: E402
from viewer import chromium_page  # noqa: E402


def canvas(page) -> np.ndarray:
    """The page's 3D canvas as it shows it (RGB)."""
    import cv2

    png = page.locator("canvas").first.screenshot(timeout=300_000, animations="disabled")
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(np.int32)


def settled(page, timeout: float = 120.0) -> np.ndarray:
    """The canvas once two shots in a row agree (frustum images decode over a few frames)."""
    last, deadline = canvas(page), time.monotonic() + timeout
    while time.monotonic() < deadline:
        time.sleep(1.0)
        img = canvas(page)
        if changed_pixels(img, last) < 0.002 * img.shape[0] * img.shape[1]:
            return img
        last = img
    return last


def map_share(page, no_map: np.ndarray, quiet: float = 20.0, timeout: float = 900.0) -> tuple[float, np.ndarray]:
    """The share of the canvas that the map changes, once it has not grown for `quiet` seconds (the
    map streams to the page in chunks and its splats fade in: two equal shots can fall between
    chunks)."""
    best, best_img, since = -1.0, None, time.monotonic()
    deadline = since + timeout
    while time.monotonic() < deadline and time.monotonic() - since < quiet:
        img = canvas(page)
        share = changed_pixels(img, no_map) / (img.shape[0] * img.shape[1])
        if share > best + 0.002:
            best, best_img, since = share, img, time.monotonic()
        time.sleep(1.0)
    return best, best_img


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--input", required=True)
    p.add_argument("--at", type=int, default=200, help="the frame at which the run is paused and the page measured")
    p.add_argument("--shots", type=Path, default=None)
    args = p.parse_args()
    stdout, sys.stdout = sys.stdout, sys.stderr      # viser's banner: keep stdout to the JSON

    import viser

    from app.run_setup import setup_run
    from app.viewer import build_viewer
    from app.worker import SlamWorker

    run = setup_run(args.input, out=Path(tempfile.mkdtemp(prefix="framing-")) / "run", engine="live")
    worker = SlamWorker(run.start())
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    app = build_viewer(server, worker, preview_frame=run.source[0])
    from splat_core.config import describe_layers

    out = dict(machine=machine(), input=args.input, at_frame=args.at, engine=run.engine,
               settings=describe_layers(run.config))
    t0 = time.monotonic()
    try:
        with chromium_page(server, viewport=(1280, 800)) as page:
            while not server.get_clients():
                time.sleep(0.1)
            client = next(iter(server.get_clients().values()))
            worker.start()
            snap = worker.wait_for(lambda s: s is not None and s.frame_index >= args.at, timeout=7200)
            worker.pause()
            worker.wait_for(lambda s: s is not None and s.state == "paused", timeout=600)
            out["slam_seconds"] = round(time.monotonic() - t0, 1)
            out["frame"] = int(snap.frame_index)
            out["keyframes"] = len(worker.latest().keyframes)
            out["page_follows_framing"] = app.framing.follows(client.client_id)
            hidden = client.scene.add_frame("/map", show_axes=False, visible=False)
            no_map = settled(page)
            hidden.remove()
            share, full = map_share(page, no_map)
            out["map_pixel_share"] = round(share, 3)
            if args.shots:
                import cv2

                args.shots.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(args.shots / "default_view.png"), full[..., ::-1].astype(np.uint8))
                cv2.imwrite(str(args.shots / "map_hidden.png"), no_map[..., ::-1].astype(np.uint8))
    finally:
        worker.stop(join_timeout=600)
        app.close()
        server.stop()
    print(json.dumps(out), file=stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
