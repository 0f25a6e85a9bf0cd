"""A first run of `splatam-viewer` from an empty kernel cache (issue 45): seconds from the start to
the printed URL answering, to the kernels compiled, and to the first map on the page (Chromium).
Prints JSON.  python benchmarks/first_run.py [--max-frames 3]"""

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
from common import CHROMIUM, CHROMIUM_ARGS  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-frames", type=int, default=3)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="first-run-"))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "numba-cache"), PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    lines: list[tuple[float, str]] = []
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from app.cli import viewer_main; sys.exit(viewer_main())",
                             "--port", "0", "--out", str(tmp / "run"), "--max-frames", str(args.max_frames)],
                            cwd=tmp, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    threading.Thread(target=lambda: [lines.append((time.monotonic() - t0, ln)) for ln in proc.stdout],
                     daemon=True).start()
    out = {}
    try:
        while not any(ln.startswith("URL ") for _, ln in lines):
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
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
