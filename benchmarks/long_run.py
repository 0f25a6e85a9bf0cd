"""Long runs: memory per frame on a capture that revisits one room, and per-frame time on one that
keeps exploring; prints JSON (one object per run).

    python benchmarks/long_run.py memory --frames 1000 --size 320x240
    python benchmarks/long_run.py memory --frames 1000 --size 640x480
    python benchmarks/long_run.py memory --frames 400 --code OLD_CHECKOUT     # the same run on other code
    python benchmarks/long_run.py time --frames 1000 --size 320x240 --preset cpu
    python benchmarks/long_run.py time --frames 1000 --size 160x120 --given-poses   # mapping's cost alone
    python benchmarks/long_run.py worker --frames 1000 --size 160x120 [--code OLD_CHECKOUT]

memory: the synthetic room (splat_core/synthetic/) at twice the hand-held speed, so the camera orbits the
room more than once, with the reference poses given (tracking.use_reference_poses) and short
mapping (1 iteration a frame), as the issue that asked for it measured. RSS is read from
/proc/self/status after every frame; the least-squares slope of RSS over frames 100..N is
`slope_mb_per_frame`; `growth_mb_per_frame` compares the median RSS of
frames 100-150 with that of the last 50 (single iterations' spikes cancel out); `map_mb` is what
the Gaussians themselves take. Until the camera has gone once round the room (`first_orbit`: about 437
frames at twice hand-held speed) it keeps seeing walls it has not seen, and the map grows with
them; `revisit` is the same growth from the end of that first orbit, while the camera only sees
again what the map holds.

time: the corridor (splat_core/synthetic/corridor.py), full SLAM with the given preset, run folder and
checkpoints as `splatam run` writes them; the median s/frame (records' wall_seconds) of frames
[N/10, N/5) against [0.9 N, N) (100-200 and 900-1000 for N = 1000) and their ratio, also over
keyframes alone (`keyframe_s`: loop detection runs after each keyframe); the RSS after each frame
too (each window's median, `rss_growth_mb_per_frame` from N/10 on as `memory` computes it).
`--engine live --preset live` times the live engine (wall_seconds: what the tracker spent on a frame).
Accuracy over the run: the ATE of the first k frames at every eighth of it (`ate_first_frames_cm`:
where a drift starts), frames lost, and frames whose tracking kept the constant-velocity
prediction (`tracking_start`).

worker: the memory run's capture and settings, run by the viewer's SlamWorker (app/worker.py;
no server, no live panel): the time its own bookkeeping after each frame takes on the SLAM
thread (history, ATE, the snapshot the viewer reads: `SlamWorker._after_frame`), median ms over
frames [N/10, N/5) and over the last tenth, and their ratio: work that grows with the run
slows SLAM in the viewer however fast tracking is.

Each run is a child process of this script (so RSS is per run); `--code DIR` puts another
checkout first on its PYTHONPATH, to measure the code before a change in the same session.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPEED = 2.0          # memory: the room's camera at twice hand-held speed
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import machine  # noqa: E402


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def slope(xs, ys) -> float:
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def growth(rss: list[float], first: int, span: int = 50) -> float:
    """RSS growth per frame from frame `first` to the end, between medians of `span` frames (robust
    to the spikes of single iterations)."""
    span = min(span, (len(rss) - first) // 2)
    a, b = statistics.median(rss[first:first + span]), statistics.median(rss[-span:])
    return (b - a) / (len(rss) - span - first)


def first_orbit(c2w) -> int:
    """The frame at which the camera has gone once round the middle of its path (what older
    checkouts' paths allow too: --code)."""
    eyes = np.asarray(c2w)[:, :3, 3]
    middle = eyes.mean(axis=0)
    azimuth = np.unwrap(np.arctan2(eyes[:, 2] - middle[2], eyes[:, 0] - middle[0]))
    done = np.flatnonzero(np.abs(azimuth - azimuth[0]) >= 2 * np.pi)
    return int(done[0]) if done.size else len(eyes)


def child_memory(args) -> dict:
    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import SyntheticSource

    w, h = args.size
    cfg = load_config(args.preset, overrides={
        "resolution": [w, h], "tracking": {"use_reference_poses": True},
        "mapping": {"iterations": 1, "first_frame_iterations": 20}, "eval_every": 10**9})
    with tempfile.TemporaryDirectory() as tmp:
        source = SyntheticSource(n_frames=args.frames, width=w, height=h, speed=SPEED)
        pipe = Pipeline(source, cfg, Path(tmp) / "run")
        rss, gaussians = [], []
        start = time.perf_counter()
        while pipe.step() is not None:
            rss.append(rss_mb())
            gaussians.append(len(pipe.engine.slam.map))
        seconds = time.perf_counter() - start
        store = pipe.engine.slam.keyframes
        resident = store.resident_bytes() / 2**20 if hasattr(store, "resident_bytes") else None
    first = min(100, len(rss) // 2)
    orbit = first_orbit(source.c2w)
    revisit = None
    if len(rss) >= orbit + 100:
        revisit = dict(frames=[orbit, len(rss)], growth_mb_per_frame=round(growth(rss, orbit), 4),
                       slope_mb_per_frame=round(slope(range(orbit, len(rss)), rss[orbit:]), 4),
                       gaussians_at={str(orbit): gaussians[orbit - 1], str(len(rss)): gaussians[-1]})
    bytes_per_gaussian = 4 * 14 + 8       # means, colours, quaternion, opacity, 3 log-scales; birth frame
    return dict(mode="memory", frames=len(rss), size=f"{w}x{h}", code=args.code or str(ROOT),
                rss_mb_at={str(first): round(rss[first - 1], 1), str(len(rss)): round(rss[-1], 1)},
                growth_mb_per_frame=round(growth(rss, first), 4),
                slope_mb_per_frame=round(slope(range(first, len(rss)), rss[first:]), 4),
                rss_mb_every_50=[round(v, 1) for v in rss[49::50]],
                peak_rss_mb=round(max(rss), 1),
                gaussians_at={str(first): gaussians[first - 1], str(len(rss)): gaussians[-1]},
                map_mb_at_end=round(gaussians[-1] * bytes_per_gaussian / 2**20, 1), revisit=revisit,
                keyframes=len(store), keyframes_resident_mb=None if resident is None else round(resident, 1),
                seconds_per_frame=round(seconds / len(rss), 3), machine=machine())


def child_time(args) -> dict:
    from splat_core.config import load_config
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.metrics import ate_errors
    from splat_core.run import Pipeline
    from splat_core.synthetic import CorridorSource

    w, h = args.size
    overrides = {"resolution": [w, h], "eval_every": 10**9}
    if args.given_poses:
        overrides["tracking"] = {"use_reference_poses": True}
    cfg = load_config(args.preset, overrides=overrides)
    n = args.frames
    with tempfile.TemporaryDirectory() as tmp:
        pipe = Pipeline(CorridorSource(n_frames=n, width=w, height=h), cfg, Path(tmp) / "run", engine=args.engine)
        rss = []
        while pipe.step() is not None:
            rss.append(rss_mb())
        metrics = pipe.finish()
        stamps, c2w = read_tum_trajectory(Path(tmp) / "run" / "trajectory.txt")
    records = metrics["per_frame"]
    reference = np.asarray(pipe.source.c2w)[[r["source_index"] for r in records]]
    # where a drift starts: the ATE of the first k frames, at every eighth of the run
    ate_growth = {str(k): round(100 * float(np.sqrt(np.mean(ate_errors(np.asarray(c2w)[:k], reference[:k]) ** 2))), 2)
                  for k in range(n // 8, n + 1, n // 8)}

    def window(lo, hi):
        part = records[lo:hi]
        keyframes = [r["wall_seconds"] for r in part if r.get("is_keyframe")] or [float("nan")]
        return dict(frames=[lo, hi], s_per_frame=round(statistics.median(r["wall_seconds"] for r in part), 3),
                    keyframe_s=round(statistics.median(keyframes), 3),
                    tracking_s=round(statistics.median(r["tracking_seconds"] for r in part), 3),
                    mapping_s=round(statistics.median(r["mapping_seconds"] for r in part), 3),
                    gaussians=part[-1]["num_gaussians"], rss_mb=round(statistics.median(rss[lo:hi]), 1))
    early, late = window(n // 10, n // 5), window(n - n // 10, n)
    return dict(mode="time", frames=n, size=f"{w}x{h}", preset=args.preset, engine=args.engine,
                poses="given" if args.given_poses else "tracked",
                code=args.code or str(ROOT), early=early, late=late,
                ratio_late_to_early=round(late["s_per_frame"] / early["s_per_frame"], 3),
                keyframe_ratio_late_to_early=round(late["keyframe_s"] / early["keyframe_s"], 3),
                rss_growth_mb_per_frame=round(growth(rss, n // 10), 4), peak_rss_mb=round(max(rss), 1),
                loop_closure=cfg.loop_closure.enabled,
                ate_rmse_cm=metrics["ate_rmse_cm"], ate_first_frames_cm=ate_growth,
                frames_lost=metrics["frames_lost"],
                prediction_kept=sum(r.get("tracking_start") == "prediction" for r in records), machine=machine())


def child_worker(args) -> dict:
    from app.worker import SlamWorker
    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import SyntheticSource

    w, h = args.size
    cfg = load_config(args.preset, overrides={
        "resolution": [w, h], "tracking": {"use_reference_poses": True},
        "mapping": {"iterations": 1, "first_frame_iterations": 20}, "eval_every": 10**9})
    source = SyntheticSource(n_frames=args.frames, width=w, height=h, speed=SPEED)
    worker = SlamWorker(Pipeline(source, cfg, None), live_render=False)
    took = []
    after_frame = worker._after_frame

    def timed(result):
        t0 = time.perf_counter()
        after_frame(result)
        took.append(time.perf_counter() - t0)
    worker._after_frame = timed
    worker.start()
    worker.join()
    if worker.error is not None:
        raise worker.error
    n = len(took)

    def window(lo, hi):
        return dict(frames=[lo, hi], ms=round(1e3 * statistics.median(took[lo:hi]), 3))
    early, late = window(n // 10, n // 5), window(n - n // 10, n)
    return dict(mode="worker", frames=n, size=f"{w}x{h}", code=args.code or str(ROOT),
                early=early, late=late, ratio_late_to_early=round(late["ms"] / early["ms"], 3),
                ms_every_100=[round(1e3 * statistics.median(took[k:k + 10]), 3) for k in range(0, n, 100)],
                machine=machine())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=["memory", "time", "worker"])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--size", default="320x240", type=lambda s: tuple(int(v) for v in s.lower().split("x")))
    p.add_argument("--preset", default="cpu")
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"])
    p.add_argument("--given-poses", action="store_true",
                   help="time: map with the reference poses (the cost of mapping alone, whatever tracking does)")
    p.add_argument("--code", default=None, help="another checkout to import splat_core from")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        child = {"memory": child_memory, "time": child_time, "worker": child_worker}[args.mode]
        print(json.dumps(child(args)))
        return 0
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
    code = Path(args.code).resolve() if args.code else ROOT
    env["PYTHONPATH"] = os.pathsep.join([str(code), env.get("PYTHONPATH", "")])
    argv = [a for a in (argv if argv is not None else sys.argv[1:])]
    proc = subprocess.run([sys.executable, __file__, *argv, "--child"], cwd=code, env=env,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        print(json.dumps({"mode": args.mode, "error": proc.stderr.strip().splitlines()[-1:]}))
        return 1
    print(proc.stdout.strip().splitlines()[-1])
    return 0


if __name__ == "__main__":
    sys.exit(main())
