"""What the benchmarks (and the browser tests) share: paths, the machine's description, Chromium.

Run a benchmark from the repository root (`python benchmarks/NAME.py`); each puts the root on
sys.path itself so it measures this checkout's code.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"           # real sequences with reference poses (see its README)
REAL = ["7scenes_redkitchen_300", "sun3d_3dmatch_fragment1", "sun3d_3dmatch_fragment2"]

# Debian's Chromium, driven by Playwright; never a browser downloaded at run time. Software WebGL
# (SwiftShader), no background network traffic (this machine has no network but the registries).
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                 "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict:
    """The machine a figure was measured on: CPU model, cores, Python, torch, Numba, GPU."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    info = {"cpu": cpu_model(), "cores": cores, "python": platform.python_version(), "system": platform.system(),
            "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")}
    try:
        import torch
        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads()
        if torch.cuda.is_available():
            info["gpu"] = torch.cuda.get_device_name(0)
    except ImportError:
        pass
    try:
        import numba
        info["numba"] = numba.__version__
        info["numba_threads"] = numba.config.NUMBA_NUM_THREADS
    except ImportError:
        pass
    return info


def machine_line() -> str:
    """One line: 'CPU model, N cores'."""
    m = machine()
    return f"{m['cpu']}, {m['cores']} cores" + (f", {m['gpu']}" if "gpu" in m else "")


def changed_pixels(a, b, threshold: int = 40) -> int:
    """Pixels whose RGB differ by more than `threshold` (summed over channels) between two screenshots."""
    import numpy as np
    return int((np.abs(np.asarray(a[..., :3], np.int32) - np.asarray(b[..., :3], np.int32)).sum(axis=-1) > threshold).sum())
