"""A first run of `splatam-viewer` from an empty kernel cache (issue 45): seconds from the start to
the printed URL answering, to the kernels compiled, and to the first map on the page (Chromium).
Prints JSON.  python benchmarks/first_run.py [--max-frames 3] [--before OLD_CHECKOUT]

--before DIR: then the same from `make demo` as an older checkout ran it (its warm-up command,
which compiled every kernel before the viewer started, then its viewer), for the side-by-side
figure "the first map reaches the page no later than before"."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))
from common import CHROMIUM, CHROMIUM_ARGS, machine  # noqa: E402


VIEWER = "import sys; from app.cli import viewer_main; sys.exit(viewer_main())"


def first_run(root: Path, max_frames: int, warmup_first: bool) -> dict:
    """Seconds from the start of `make demo`'s command in `root` (the viewer; `warmup_first`: the
    warm-up command, then the viewer, as `make demo` ran before the page served the compile) to the
    URL answering, the kernels compiled and the first map on the page, from an empty kernel cache."""
    tmp = Path(tempfile.mkdtemp(prefix="first-run-"))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "numba-cache"), PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    viewer = [sys.executable, "-c", VIEWER, "--port", "0", "--out", str(tmp / "run"), "--max-frames", str(max_frames)]
    cmd = viewer if not warmup_first else ["bash", "-c", f'"{sys.executable}" -m app.warmup && exec "$@"', "demo", *viewer]
    lines: list[tuple[float, str]] = []
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=tmp, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    threading.Thread(target=lambda: [lines.append((time.monotonic() - t0, ln)) for ln in proc.stdout],
                     daemon=True).start()
    out = dict(tree=str(root), command="warm-up, then viewer" if warmup_first else "viewer")
    try:
        while not any(ln.startswith("URL ") for _, ln in lines):
            if proc.poll() is not None:
                raise RuntimeError("the viewer ended before printing its URL:\n" + "".join(ln for _, ln in lines))
            time.sleep(0.05)
        url = next(ln.split()[1] for _, ln in lines if ln.startswith("URL "))
        while True:
            try:
                urllib.request.urlopen(url, timeout=5)
                break
            except OSError:
                time.sleep(0.05)
        out["url_answers_s"] = round(time.monotonic() - t0, 1)
        from playwright.sync_api import sync_playwright
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            page = browser.new_page()
            page.goto(url)
            page.wait_for_function(r"() => /Gaussians\s+[1-9]/.test(document.body.innerText)", timeout=900_000)
            out["first_map_on_page_s"] = round(time.monotonic() - t0, 1)
            browser.close()
        out["compiled_s"] = next(round(t, 1) for t, ln in lines if "CPU kernels compiled in" in ln)
    finally:
        proc.terminate()
        proc.wait(120)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-frames", type=int, default=3)
    ap.add_argument("--before", type=Path, default=None,
                    help="also time `make demo` of an older checkout (warm-up, then viewer), right after")
    args = ap.parse_args()
    out = dict(machine=machine(), runs=[first_run(ROOT, args.max_frames, warmup_first=False)])
    if args.before is not None:
        out["runs"].append(first_run(args.before.resolve(), args.max_frames, warmup_first=True))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
