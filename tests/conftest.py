"""Fixtures the test files share: a viser server on loopback, headless Chromium, the real data.

tests/ is on sys.path under pytest (helpers/ is imported from there); the repository root too,
so the browser tests use the benchmarks' Chromium settings (benchmarks/common.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import CHROMIUM, CHROMIUM_ARGS, DATA  # noqa: E402


def shared_sequence(name: str) -> Path:
    """../shared/data/NAME, or a skip when this checkout has no ../shared beside it."""
    path = DATA / name
    if not path.is_dir():
        pytest.skip(f"{path} not present (real data lives in ../shared/data)")
    return path


@pytest.fixture
def server():
    """A viser server on 127.0.0.1 at a free port."""
    import viser
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


@pytest.fixture(scope="module")
def browser():
    """Debian's headless Chromium through Playwright (skipped when either is missing)."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
    pw = sync_api.sync_playwright().start()
    b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
    yield b
    b.close()
    pw.stop()
