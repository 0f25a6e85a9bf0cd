"""Live rate side by side: the sequential engine on the `cpu` preset against the live engine on the
`live` preset (and that run again as a real-time playback, `--realtime`), per sequence, in one
invocation. Prints a markdown table (and, with --json, the rows).

    python benchmarks/live_rate.py                                   # synthetic + 7-Scenes (first 100 frames)
    python benchmarks/live_rate.py --sequences synthetic --max-frames 30
    python benchmarks/live_rate.py --max-frames 60 --no-realtime --before ../before   # + the live row of another checkout
    python benchmarks/live_rate.py --sequences 7scenes_redkitchen_300,7scenes_redkitchen_600 --max-frames 600 --only-realtime

--before DIR adds rows per sequence: the live engine on the `live` preset as that checkout (a
`git worktree` of an earlier commit) runs it, right after this checkout's, and its real-time row
right after this checkout's real-time row, for before/after figures from one invocation.
--max-frames applies to the synthetic sequence too when given.

s/frame: `wall_seconds` of metrics.json (end of one frame to the end of the next; the median skips
frame 0, the mean includes frame 0 and the final drain of the live mapper). CPU s/frame: the run's
process CPU time (every thread, both cores, the end included) per frame (`cpu_seconds_per_frame`):
what the frames cost whatever else shares the machine; wall time on a quiet 2-core machine is about
half of it where both cores are busy. Lag: frame index minus
the newest frame in the map version it was tracked against (live engine only). A real-time row
processes only the frames it was handed (the others dropped): its ATE and PSNR are over those;
`frames lost` is metrics.json's `frames_lost` (tracking lost: pose held, frame not mapped), and the
share processed is frames over frames received. keyframes: metrics.json `keyframes`, with the keyframes
deferred while the mapper was behind (live.pace_keyframes; `live.keyframes_deferred`) beside them.
--only-realtime: the real-time rows alone (--before adds its real-time row).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, ROOT, machine_line  # noqa: E402

RUNS = [("cpu", "sequential", None), ("live", "live", None), ("live", "live", "realtime")]


def run(input_path, preset: str, engine: str, realtime: str | None, out: Path, max_frames: int | None,
        root: Path = ROOT) -> dict:
    cmd = [sys.executable, "-m", "app.cli", "run", "--input", str(input_path), "--out", str(out), "--config", preset,
           "--engine", engine, "--device", "cpu", "--quiet"] + (["--realtime"] if realtime else [])
    if max_frames:
        cmd += ["--max-frames", str(max_frames)]
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    m = json.loads((out / "metrics.json").read_text())
    live = m.get("live", {})
    return dict(frames=m["frames"], received=m.get("received"), dropped=m.get("dropped"),
                median=m.get("wall_seconds_per_frame_median"), mean=m.get("wall_seconds_per_frame"),
                cpu=m.get("cpu_seconds_per_frame"),
                ate=m.get("ate_rmse_cm"), psnr=m.get("psnr"), lag_median=live.get("lag_frames_median"),
                lag_max=live.get("lag_frames_max"), lag_kf_max=live.get("lag_keyframes_max"),
                wait=live.get("tracker_wait_seconds"), keyframes=m.get("keyframes"), lost=m.get("frames_lost"),
                deferred=live.get("keyframes_deferred"),
                share=m.get("processed_share"))


def fmt(value, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", default="synthetic,7scenes_redkitchen_300")
    p.add_argument("--max-frames", type=int, default=None, help="limit the real sequences (default 100) and, when "
                   "given, the synthetic one")
    p.add_argument("--no-realtime", action="store_true", help="leave out the --realtime rows")
    p.add_argument("--no-sequential", action="store_true", help="leave out the sequential `cpu` rows (the "
                   "real-time targets compare with the all-frames live row)")
    p.add_argument("--only-realtime", action="store_true", help="only the --realtime rows")
    p.add_argument("--before", default=None, help="another checkout: its live engine on `live` as a row too")
    p.add_argument("--work", default=None)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="live_rate_"))
    load = os.getloadavg()
    print(f"{datetime.date.today()} · {machine_line()} · load average at start "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)
    rows = []
    for seq in args.sequences.split(","):
        path = "synthetic" if seq == "synthetic" else DATA / seq
        limit = args.max_frames if seq == "synthetic" else (args.max_frames or 100)
        runs = [r + (ROOT, "") for r in RUNS if not (args.no_realtime and r[2])
                and not (args.no_sequential and r[1] == "sequential") and not (args.only_realtime and not r[2])]
        if args.before:
            before = Path(args.before).resolve()
            commit = subprocess.run(["git", "-C", str(before), "rev-parse", "--short", "HEAD"], capture_output=True,
                                    text=True).stdout.strip()
            if not args.only_realtime:
                runs.insert(1 if args.no_sequential else 2, ("live", "live", None, before, f" (before: {commit})"))
            if not args.no_realtime:
                runs.append(("live", "live", "realtime", before, f" (before: {commit})"))
        for preset, engine, realtime, root, note in runs:
            out = work / f"{seq}__{preset}__{engine}{'__rt' if realtime else ''}{'__before' if note else ''}"
            row = dict(sequence=seq if limit is None else f"{seq} (first {limit})", preset=preset + note,
                       engine=engine + (" --realtime" if realtime else ""),
                       **run(path, preset, engine, realtime, out, limit, root))
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    print("\n| sequence | preset | engine | frames (of received, share processed) | median s/frame | frames/s (median) | "
          "mean s/frame incl. drain | CPU s/frame (both cores) | ATE cm | PSNR dB | lag frames median / max | lag keyframes max | keyframes | "
          "frames lost |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['sequence']} | {r['preset']} | {r['engine']} | error: {r['error']} ||||||||||")
            continue
        frames = str(r["frames"])
        if r["received"] is not None:           # a real-time row: of the frames that arrived
            frames += f" of {r['received']}" + (f" ({100 * r['share']:.0f} %)" if r["share"] is not None else "")
        rate = fmt(1.0 / r["median"], 1) if r["median"] else "–"
        lag = "–" if r["lag_median"] is None else f"{r['lag_median']:g} / {r['lag_max']}"
        deferred = f" ({r['deferred']} deferred)" if r.get("deferred") else ""
        print(f"| {r['sequence']} | {r['preset']} | {r['engine']} | {frames} | {fmt(r['median'])} | {rate} | "
              f"{fmt(r['mean'])} | {fmt(r['cpu'])} | {fmt(r['ate'])} | {fmt(r['psnr'])} | {lag} | {fmt(r['lag_kf_max'])} | "
              f"{fmt(r['keyframes'])}{deferred} | {fmt(r['lost'])} |")
    load = os.getloadavg()
    print(f"\nload average at end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
