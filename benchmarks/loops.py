"""Loop closure: the real sequences with and without it (side by side with Open3D), a synthetic loop
with drifting odometry, and captures that never return (no loop may close there). Prints JSON.

    python benchmarks/loops.py --sequences 7scenes_redkitchen_600 --modes on,off --open3d --json
    python benchmarks/loops.py --sequences 7scenes_redkitchen_300,sun3d_3dmatch_fragment1,sun3d_3dmatch_fragment2
    python benchmarks/loops.py --sequences none --synthetic-loop 120 --corridor 300
    python benchmarks/loops.py --sequences none --live-lap 240 --detect-cost 400 --json

Real sequences run `splatam run` (benchmarks/slam.py's run_one, default preset cpu) with
loop_closure on and off; each row adds loops_closed and the loops (frames, inliers, correction),
ate_rmse_split_cm where the reference has a flagged step, the largest error after that alignment
(ate_max_split_cm), and the ATE of each stretch of --segment frames aligned on its own
(segment_ate_cm: where a run's error grows).

--synthetic-loop N: splat_core.synthetic.LoopSource of N frames at 160x120 with DriftingOdometry
(1 mm and 0.1 degree per frame), with and without loop closure, and at the exact poses: ATE and
the map's depth error against the noise-free depth at the estimated poses (a doubled surface shows
there; the exact-pose row is the error of a map without one). --corridor N: the synthetic corridor
walk with the same drift; any loop closed there is false.

--live-lap N: the live engine on the lap with every loop applied: how long a correction locks the
poses (the longest the tracker can wait) against its time per frame. --detect-cost K: one
keyframe's loop detection time at K/8 ... K keyframes before it, bounded against matching every
old keyframe (what the code did before the bound), side by side.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import DATA, machine_line as machine  # noqa: E402
from slam import run_one, split_ate_cm  # noqa: E402


def trajectory_errors(run_dir: Path, src, breaks: list[int], segment: int) -> dict:
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.metrics import ate_errors

    if not (run_dir / "trajectory.txt").exists():
        return {}
    stamps, est = read_tum_trajectory(run_dir / "trajectory.txt")
    index = {round(float(t), 4): i for i, t in enumerate(src.timestamps)}
    frames = [index[round(float(t), 4)] for t in stamps]
    ref = src.reference_c2w()[frames]
    cuts = [0] + [k + 1 for k, f in enumerate(frames[:-1]) if any(f <= b < frames[k + 1] for b in breaks)] + [len(est)]
    err = np.concatenate([ate_errors(est[a:b], ref[a:b]) for a, b in zip(cuts, cuts[1:])])
    segments = [100 * float(np.sqrt(np.mean(ate_errors(est[a:a + segment], ref[a:a + segment]) ** 2)))
                for a in range(0, len(est) - segment // 2, segment)]
    return dict(ate_max_split_cm=100 * float(err.max()), segment_frames=segment,
                segment_ate_cm=[round(s, 2) for s in segments])


def real_rows(args, work: Path) -> list[dict]:
    from splat_core.io import open_capture
    from splat_core.io.checks import reference_breaks

    rows = []
    for seq in [s for s in args.sequences.split(",") if s and s != "none"]:
        path = Path(args.data) / seq
        if not path.is_dir():
            rows.append({"sequence": seq, "skipped": f"{path} not found"})
            continue
        src = open_capture(path)
        breaks = reference_breaks(src)
        for mode in args.modes.split(","):
            preset = work / f"{args.preset}_loops_{mode}.yaml"
            preset.write_text(f"base: {args.preset}\nloop_closure: {{enabled: {'true' if mode == 'on' else 'false'}}}\n")
            out = work / f"{seq}__{args.preset}__loops_{mode}"
            row = {"sequence": seq, "preset": args.preset, "loop_closure": mode,
                   **run_one(path, str(preset), out, args.max_frames, "cpu"), "machine": machine(), "run_dir": str(out)}
            if breaks:
                row["reference_breaks"] = breaks
                row["ate_rmse_split_cm"] = split_ate_cm(out, src, breaks)
            row.update(trajectory_errors(out, src, breaks, args.segment))
            if (out / "metrics.json").exists():
                m = json.loads((out / "metrics.json").read_text())
                row["loops_closed"] = m.get("loops_closed", 0)
                row["loops_rejected"] = m.get("loops_rejected", 0)
                row["loops"] = [{k: lp[k] for k in ("frames", "inliers", "correction_cm", "correction_deg", "applied",
                                                     "seconds")} for lp in m.get("loops", [])]
            rows.append(row)
            if not args.json:
                print(json.dumps(row), flush=True)
    return rows


def synthetic_rows(args) -> list[dict]:
    from drifting_loop import run_drifting
    from splat_core.config import load_config
    from splat_core.synthetic import CorridorSource
    from splat_core.synthetic import LoopSource

    rows = []
    config = load_config(args.preset, {"resolution": [160, 120]})
    jobs = []       # (name, source, loop closure, drift per frame (m, degrees))
    if args.synthetic_loop:
        loop = LoopSource(n_frames=args.synthetic_loop, width=160, height=120)
        jobs += [("synthetic_loop", loop, True, (0.001, 0.1)), ("synthetic_loop", loop, False, (0.001, 0.1)),
                 ("synthetic_loop", loop, False, (0.0, 0.0))]       # exact poses: the map's own depth error
    if args.corridor:
        jobs += [("synthetic_corridor", CorridorSource(n_frames=args.corridor, width=160, height=120, speed=2.0), True,
                  (0.001, 0.1))]
    for name, source, lc, (bias_m, bias_deg) in jobs:
        gap = min(config.loop_closure.min_gap_frames, len(source) // 3)
        cfg = load_config(args.preset, {"resolution": [160, 120], "loop_closure": {"min_gap_frames": gap}})
        r = run_drifting(source, cfg, lc, bias_m, bias_deg)
        r.pop("slam")
        drift = f"{1000 * bias_m:g} mm, {bias_deg:g} deg" if bias_m or bias_deg else "none (exact poses)"
        row = {"sequence": name, "preset": args.preset, "loop_closure": "on" if lc else "off", "min_gap_frames": gap,
               "drift_per_frame": drift, **r, "machine": machine()}
        row["loops_closed"] = len(row.pop("loops"))
        rows.append(row)
        if not args.json:
            print(json.dumps(row), flush=True)
    return rows


def live_lap_rows(args) -> list[dict]:
    """The live engine on the synthetic lap (tracked, 320x240), every verified loop applied
    (min_correction 0: the lap's tracking hardly drifts, and the point is the stall): how long
    each correction held the pose lock (the longest the tracker can wait for it) against the
    tracker's median time per frame, and the tracker's longest frame."""
    import statistics

    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import LoopSource

    if not args.live_lap:
        return []
    n = args.live_lap
    cfg = load_config(args.preset, {"checkpoint_every": 0, "eval_every": 10**9, "loop_closure": {
        "enabled": True, "min_gap_frames": min(100, n // 3), "min_correction": 0.0, "min_correction_deg": 0.0}})
    pipe = Pipeline(LoopSource(n_frames=n, width=cfg.resolution[0], height=cfg.resolution[1]), cfg, engine="live")
    records = []
    while (r := pipe.step()) is not None:
        records.append(r)
    metrics = pipe.finish()
    tracking = [r.tracking_seconds for r in records[1:]]
    loops = metrics.get("loops", [])
    row = {"sequence": "synthetic_loop (live engine)", "preset": args.preset, "frames": n,
           "size": "x".join(map(str, cfg.resolution)), "loops_closed": len(loops),
           "loops_applied": sum(bool(lp["applied"]) for lp in loops),
           "apply_seconds": [round(lp.get("apply_seconds", 0.0), 4) for lp in loops if lp["applied"]],
           "loop_seconds": [round(lp["seconds"], 3) for lp in loops],
           "tracking_s_per_frame_median": round(statistics.median(tracking), 4),
           "tracking_s_max": round(max(tracking), 4),
           "wall_s_per_frame_median": round(metrics["wall_seconds_per_frame_median"], 4),
           "ate_rmse_cm": metrics["ate_rmse_cm"], "machine": machine()}
    if not args.json:
        print(json.dumps(row), flush=True)
    return [row]


def detect_cost_rows(args) -> list[dict]:
    """Seconds of one keyframe's loop detection (LoopClosure.after_keyframe without verification)
    against the number of keyframes before it: bounded ORB matching with its features cached
    ("bounded") and with none cached (every partner's ORB recomputed: "bounded, cold"), against
    every old keyframe matched with every feature cached (the code before 2026-12-05's bound);
    side by side in one process, medians of 5."""
    import statistics
    import time
    from dataclasses import replace
    from types import SimpleNamespace

    import torch

    from splat_core.camera import invert_pose
    from splat_core.config import load_config
    from splat_core.loop import LoopClosure
    from splat_core.synthetic import CorridorSource

    if not args.detect_cost:
        return []
    cfg = load_config(args.preset)
    w, h = cfg.resolution
    every = 5
    frames = every * args.detect_cost
    source = CorridorSource(n_frames=frames, width=w, height=h, speed=1000 / frames)
    kfs = []
    for k in range(args.detect_cost):
        f = source[every * k]
        color8 = (np.clip(f.color, 0, 1) * 255).astype(np.uint8)
        kfs.append(SimpleNamespace(frame_index=every * k, w2c=invert_pose(source.reference_c2w()[every * k]),
                                   depth=f.depth, color=f.color, images8=lambda c=color8: (c, None)))
    only_detection = dict(min_visible=2.0, min_orb_matches=10**9)      # no candidate: detection alone
    settings = {"bounded": replace(cfg.loop_closure, enabled=True, **only_detection),
                "every old keyframe": replace(cfg.loop_closure, enabled=True, orb_by_map=10**9,
                                              feature_cache=10**9, **only_detection)}
    rows = []
    for n in sorted({max(1, args.detect_cost // 8), args.detect_cost // 4, args.detect_cost // 2, args.detect_cost}):
        slam = SimpleNamespace(keyframes=kfs[:n], intrinsics=source.intrinsics,
                               map=SimpleNamespace(means=torch.zeros(0, 3),
                                                   birth_frame=torch.zeros(0, dtype=torch.int64)))
        closers = {name: LoopClosure(c) for name, c in settings.items()}
        closers["bounded, cold"] = LoopClosure(settings["bounded"])
        for closer in closers.values():             # features of the old keyframes computed once beforehand
            closer.after_keyframe(slam, kfs[n - 1].frame_index)
        times = {name: [] for name in closers}
        for _ in range(5):
            for name, closer in closers.items():
                closer.edges.clear()
                if name.endswith("cold"):
                    closer._features.clear()
                start = time.perf_counter()
                closer.after_keyframe(slam, kfs[n - 1].frame_index)
                times[name].append(time.perf_counter() - start)
        row = {"sequence": "detection cost", "keyframes": n, "size": f"{w}x{h}",
               **{f"{name} s": round(statistics.median(t), 4) for name, t in times.items()},
               "cached features (bounded)": len(closers["bounded"]._features), "machine": machine()}
        rows.append(row)
        if not args.json:
            print(json.dumps(row), flush=True)
    return rows


def open3d_rows(args) -> list[dict]:
    import subprocess

    real = [s for s in args.sequences.split(",") if s and s != "none"]
    if not (args.open3d and real):
        return []
    cmd = [sys.executable, str(ROOT / "benchmarks" / "baseline_open3d.py"), "--sequences", ",".join(real),
           "--voxel-size", args.open3d_voxels, "--methods", "dense"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    if not args.json:
        for row in rows:
            print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", default="7scenes_redkitchen_600")
    p.add_argument("--modes", default="on,off", help="loop closure on, off or both")
    p.add_argument("--preset", default="cpu")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--segment", type=int, default=100, help="frames per stretch of segment_ate_cm")
    p.add_argument("--data", default=str(DATA))
    p.add_argument("--work", default=None, help="folder for run outputs (kept; reruns resume)")
    p.add_argument("--open3d", action="store_true", help="Open3D dense SLAM on the same sequences")
    p.add_argument("--open3d-voxels", default="0.01,0.0058,0.02")
    p.add_argument("--synthetic-loop", type=int, default=0, help="frames of the synthetic loop (0: skip)")
    p.add_argument("--corridor", type=int, default=0, help="frames of the corridor walk (0: skip)")
    p.add_argument("--live-lap", type=int, default=0,
                   help="frames of the synthetic lap run by the live engine, loops applied (0: skip)")
    p.add_argument("--detect-cost", type=int, default=0,
                   help="keyframes (corridor, every 5th frame) for the detection-cost rows (0: skip)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    work = Path(args.work).resolve() if args.work else Path(tempfile.mkdtemp(prefix="splatam_loops_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = (real_rows(args, work) + open3d_rows(args) + synthetic_rows(args) + live_lap_rows(args)
            + detect_cost_rows(args))
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
