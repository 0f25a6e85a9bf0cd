"""A first run (issue 45): with an empty kernel cache `splatam-viewer` serves its page before the CPU
kernels compile, the page shows the compile's progress while the process has not yet said it is
done, and the map reaches the page afterwards. A real subprocess and Chromium; state polling only."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import pytest

from common import CHROMIUM  # noqa: F401 (benchmarks/common.py, on sys.path via conftest)
from helpers.viewer import wait_until

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [pytest.mark.browser, pytest.mark.slow,
              pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed")]


class ViewerProcess:
    """`splatam-viewer` in a subprocess; `lines` collects its stdout and stderr as they come."""

    def __init__(self, tmp: Path, *args: str):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "numba-cache"), PYTHONUNBUFFERED="1",
                   PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        (tmp / "numba-cache").mkdir()
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; from app.cli import viewer_main; sys.exit(viewer_main())",
             "--port", "0", "--out", str(tmp / "run"), *args],
            cwd=tmp, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def said(self, word: str) -> bool:
        return any(word in line for line in self.lines)

    def url(self) -> str | None:
        return next((line.split(" ", 1)[1] for line in self.lines if line.startswith("URL ")), None)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(120)
        except subprocess.TimeoutExpired:
            self.proc.kill()


@pytest.mark.timeout(1200)      # a cold compile on a busy 2-core machine: its waits add up past the default
def test_page_shows_the_compile_then_the_map(browser, tmp_path):
    viewer = ViewerProcess(tmp_path, "--max-frames", "3")
    try:
        url = wait_until(viewer.url, 120, interval=0.05, what="the URL line")
        assert not viewer.said("compiled")
        assert urllib.request.urlopen(url, timeout=30).status == 200    # served before the kernels compile
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        page.goto(url, timeout=120_000)
        page.wait_for_function("() => document.body.innerText.includes('Compiling the CPU kernels')",
                               timeout=120_000)
        assert not viewer.said("compiled"), viewer.lines       # the page showed it while it compiled
        assert re.search(r"\d+ / \d+ kernels", page.inner_text("body"))
        assert viewer.said("compiling the CPU kernels")           # and the terminal said so too
        wait_until(lambda: viewer.said("CPU kernels compiled in"), 600, interval=0.5, what="the compile's end")
        page.wait_for_function(r"() => /Gaussians\s+[1-9]/.test(document.body.innerText)", timeout=300_000)
        assert viewer.proc.poll() is None, viewer.lines
        page.close()
    finally:
        viewer.stop()
