"""Compile the CPU kernels ahead of time: `python -m app.warmup` (what `make demo` runs first).

The Numba kernels (renderer, SSIM, mapping loss, alignment) compile on their first use, about a
minute on two cores, and are cached next to their modules (`cache=True`), so only a first run
pays it. This runs SLAM on two frames of the synthetic scene into a temporary folder, which uses
every kernel the viewer's first frame would. `kernels_compiled()` tells whether the cache is there
(the viewer then says "compiling the CPU renderer: first run only" while frame 1 takes long).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import splat_core

COMPILING_NOTE = "compiling the CPU renderer: first run only (about a minute; `make demo` does it ahead of time)"


def kernels_compiled() -> bool:
    """Whether Numba's cache holds the renderer's forward kernel (index files beside the module, or
    under NUMBA_CACHE_DIR when that is set)."""
    import os

    if os.environ.get("NUMBA_CACHE_DIR"):
        return any(Path(os.environ["NUMBA_CACHE_DIR"]).rglob("cpu._forward_kernel-*.nbi"))
    cache = Path(splat_core.__file__).parent / "render" / "__pycache__"
    return any(cache.glob("cpu._forward_kernel-*.nbi"))


def warm_up(frames: int = 2) -> float:
    """Run SLAM on `frames` synthetic frames (sequential engine, cpu preset); seconds taken."""
    from app.run_setup import setup_run

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="splatam-warmup-") as tmp:
        run = setup_run(None, out=Path(tmp) / "run", config="cpu", device="cpu", engine="sequential",
                        max_frames=frames)
        pipe = run.start()
        while pipe.step() is not None:
            pass
        run.source.close()
    return time.perf_counter() - t0


def main() -> int:
    if kernels_compiled() and "--force" not in sys.argv:
        print("CPU kernels already compiled", file=sys.stderr)
        return 0
    print(COMPILING_NOTE.split(" (")[0] + " ...", file=sys.stderr, flush=True)
    seconds = warm_up()
    print(f"CPU kernels compiled in {seconds:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
