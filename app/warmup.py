"""Compile the CPU kernels, with their progress: in the viewer's SLAM worker before SLAM starts
(a first run of `splatam-viewer`), or ahead of time with `python -m app.warmup`.

The Numba kernels (renderer, SSIM, mapping loss, alignment) compile on their first use, about a
minute on two cores, and are cached next to their modules (`cache=True`, or under NUMBA_CACHE_DIR),
so only a first run pays it. `warm_up()` runs SLAM on two frames of the synthetic scene into a
temporary folder, which uses every kernel the viewer's first frame would. `KernelCompile` runs it
while listening to Numba's compile events, so the page and the terminal can say which kernel family
is compiling and how many of the kernels are done. `kernels_compiled()` tells whether the cache is there.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import splat_core

# Kernel families by module: what the progress names while one of its kernels compiles.
FAMILIES = {
    "splat_core.render.project_cpu": "renderer: projection",
    "splat_core.render.cpu": "renderer: rasterizer",
    "splat_core.render.cpu_pixels": "renderer: pixel losses",
    "splat_core.losses.mapping_loss_cpu": "mapping loss",
    "splat_core.losses.ssim_cpu": "SSIM",
    "splat_core.align.numba_backend": "direct alignment",
    "splat_core.registration": "registration",
    "splat_core.synthetic.raycast": "synthetic scene",
}
# How many of those kernels a warm-up compiles (counted on a first run; the progress never claims
# more than it has seen: past this it counts on without a total).
EXPECTED_KERNELS = 31


def kernels_compiled() -> bool:
    """Whether Numba's cache holds the renderer's forward kernel compiled for this process's CPU
    target (the cache keys each kernel by the target's CPU and features, so kernels compiled for
    other features, splat_core.parallel's vector width among them, do not count)."""
    try:
        from numba.core.registry import cpu_target

        from splat_core.render import cpu
        index = cpu._forward_kernel._cache._cache_file._load_index()
        target = cpu_target.target_context.codegen().magic_tuple()
        return any(key[1] == target for key in index)
    except (AttributeError, ImportError, IndexError, TypeError):   # Numba's internals moved
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


def family_of(dispatcher) -> str | None:
    """The family of a compiling Numba dispatcher; None for helpers (Numba's own overloads, closures)."""
    func = getattr(dispatcher, "py_func", None)
    if func is None or "<locals>" in func.__qualname__:
        return None
    return FAMILIES.get(func.__module__)


class KernelCompile:
    """Compiles the kernels (`run`, in any one thread) and tells how far it is (any thread).

    `run(report)` is the SlamWorker's `prepare` hook: `report(text)` is called with the page's
    progress line whenever a kernel starts or ends compiling."""

    def __init__(self, frames: int = 2):
        self.frames = frames
        self.started_at: float | None = None
        self.seconds: float | None = None       # set once compiled
        self.done = 0                           # kernels compiled
        self.current: str | None = None         # the family compiling now
        self.families_done: list[str] = []
        self._report = None

    @property
    def finished(self) -> bool:
        return self.seconds is not None

    def run(self, report=None) -> float:
        from numba.core import event

        compile_ = self

        class Listener(event.Listener):
            def on_start(self, ev):
                family = family_of(ev.data["dispatcher"])
                if family is not None:
                    compile_.current = family
                    compile_._tell()

            def on_end(self, ev):
                family = family_of(ev.data["dispatcher"])
                if family is not None:
                    compile_.done += 1
                    if family not in compile_.families_done:
                        compile_.families_done.append(family)
                    compile_._tell()

        self._report = report
        self.started_at = time.monotonic()
        self._tell()
        with event.install_listener("numba:compile", Listener()):
            warm_up(self.frames)
        self.seconds = time.monotonic() - self.started_at
        self.current = None
        return self.seconds

    def _tell(self) -> None:
        if self._report is not None:
            self._report(self.text())

    def elapsed(self) -> float:
        return 0.0 if self.started_at is None else time.monotonic() - self.started_at

    def counted(self) -> str:
        return f"{self.done} / {EXPECTED_KERNELS}" if self.done <= EXPECTED_KERNELS else str(self.done)

    def text(self) -> str:
        """The page's progress line (markdown)."""
        if self.finished:
            return f"CPU kernels compiled in {self.seconds:.0f} s; starting SLAM"
        now = f" · now: **{self.current}**" if self.current else ""
        return (f"⏳ **Compiling the CPU kernels** (first run only, about a minute on two cores): "
                f"{self.counted()} kernels{now} · {self.elapsed():.0f} s")

    def bar(self, width: int = 24) -> str:
        """The terminal's progress line: a bar over the kernels, the family compiling, the seconds."""
        fill = min(width, round(width * self.done / EXPECTED_KERNELS))
        now = f" · {self.current}" if self.current else ""
        return (f"compiling the CPU kernels (first run only) [{'#' * fill}{'.' * (width - fill)}] "
                f"{self.counted()}{now} · {self.elapsed():.0f} s")


def main() -> int:
    if kernels_compiled() and "--force" not in sys.argv:
        print("CPU kernels already compiled", file=sys.stderr)
        return 0
    job = KernelCompile()
    shown = [None]

    def report(_text):
        line = job.bar()
        if line.rsplit(" · ", 1)[0] != shown[0]:       # a line per kernel, not per second
            shown[0] = line.rsplit(" · ", 1)[0]
            print(line, file=sys.stderr, flush=True)
    seconds = job.run(report)
    print(f"CPU kernels compiled in {seconds:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
