"""Where the SLAM thread's time goes per frame, headless and in the viewer: on a CPU, waiting for a
CPU (Linux's run queue), or off CPU (Python's lock, the mapper, other waits). Prints JSON (the
last line of its output).

    python benchmarks/viewer_sched.py --frames 60 --modes headless,server,page --repeats 2
    python benchmarks/viewer_sched.py --frames 60 --modes page --running-update-hz 1,2 --repeats 3

SLAM on the first N synthetic frames (live engine, `live` preset), as benchmarks/viewer.py runs it:
`headless` (the Pipeline alone), `server` (SlamWorker and the viewer on a viser server, no page),
`page` (the same with one headless Chromium on the page, software WebGL). Around each
Pipeline.step, the calling thread's /proc/thread-self/schedstat (nanoseconds on a CPU, nanoseconds
runnable but waiting for one) and the wall clock; per run the medians over frames 1..N-2 (frame 0
and the last frame's drain left out) in ms, and Chromium's CPU (cores) while SLAM ran. Modes and
rates are interleaved within each repeat. `--running-update-hz`: the viewer's update rate while
SLAM runs (app/viewer/app.py), one run per value. Linux only.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine  # noqa: E402


def schedstat() -> tuple[int, int, int]:
    """(ns on a CPU, ns waiting for a CPU, wall ns) of the calling thread."""
    with open("/proc/thread-self/schedstat") as f:
        run, wait, _ = f.read().split()
    return int(run), int(wait), time.perf_counter_ns()


def one_run(frames: int, mode: str, running_update_hz: float) -> dict:
    from app.commands.viewer import start_server
    from app.viewer import build_viewer
    from app.worker import SlamWorker
    from splat_core.config import load_config
    from splat_core.run import Pipeline, open_input
    from viewer import browser_cpu_seconds, chromium_page, style_option

    pipe = Pipeline(open_input(None), load_config("live"), None, max_frames=frames, engine="live")
    rows = []
    step = pipe.step

    def timed_step():
        a = schedstat()
        result = step()
        b = schedstat()
        rows.append([(y - x) / 1e6 for x, y in zip(a, b)])
        return result
    pipe.step = timed_step
    cores = None
    if mode == "headless":
        while pipe.step() is not None:
            pass
        pipe.finish()
    else:
        server = start_server("127.0.0.1", 0)
        try:
            worker = SlamWorker(pipe, start_paused=True)
            app = build_viewer(server, worker, running_update_hz=running_update_hz, **style_option("auto"))
            if mode == "page":
                with chromium_page(server):
                    cpu0, t0 = browser_cpu_seconds(), time.monotonic()
                    worker.start()
                    worker.resume()
                    worker.join()
                    cores = (browser_cpu_seconds() - cpu0) / (time.monotonic() - t0)
            else:
                worker.start()
                worker.resume()
                worker.join()
            app.close()
        finally:
            server.stop()
    body = rows[1:-1]
    med = lambda xs: round(statistics.median(xs), 2)  # noqa: E731
    return dict(mode=mode, running_update_hz=None if mode == "headless" else running_update_hz,
                wall_ms=med([r[2] for r in body]), on_cpu_ms=med([r[0] for r in body]),
                run_queue_ms=med([r[1] for r in body]), off_cpu_ms=med([r[2] - r[0] - r[1] for r in body]),
                browser_cpu_cores=None if cores is None else round(cores, 3))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--modes", default="headless,server,page")
    p.add_argument("--running-update-hz", default="1", help="comma-separated rates, one viewer run each")
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args()
    if not Path("/proc/thread-self/schedstat").exists():
        print("viewer_sched.py: needs Linux's /proc/thread-self/schedstat", file=sys.stderr)
        return 2
    rates = [float(x) for x in args.running_update_hz.split(",")]
    runs = []
    for _ in range(args.repeats):
        for mode in args.modes.split(","):
            for hz in ([rates[0]] if mode == "headless" else rates):
                runs.append(one_run(args.frames, mode, hz))
    summary = {}
    for r in runs:
        key = r["mode"] if r["mode"] == "headless" else f"{r['mode']} at {r['running_update_hz']:g} Hz"
        summary.setdefault(key, []).append(r)
    fields = ("wall_ms", "on_cpu_ms", "run_queue_ms", "off_cpu_ms")
    medians = {key: {k: round(statistics.median(r[k] for r in rs), 2) for k in fields} for key, rs in summary.items()}
    print(json.dumps(dict(frames=args.frames, machine=machine(), runs=runs, medians=medians)))   # the last line (viser prints banners)
    return 0


if __name__ == "__main__":
    sys.exit(main())
