"""`--realtime` playback, repeated: how often a preset meets issue 42's real-time target.

A real-time run processes whichever frames the tracker is free for, so one run says little: this
plays one capture N times per preset, the presets interleaved round by round (the same load for
each), and counts the runs that met the target: no frame lost and ATE <= --factor x the line.

    python benchmarks/realtime_repeats.py --sequence 7scenes_redkitchen_600 --presets live,live+X.yaml --rounds 6
    python benchmarks/realtime_repeats.py --sequence 7scenes_redkitchen_600 --presets live --rounds 6 --busy 1
    python benchmarks/realtime_repeats.py --sequence 7scenes_redkitchen_600 --presets live@../prev,live --rounds 3

PRESET@CHECKOUT runs another checkout's code (a `git worktree` of an earlier commit) with its own
presets, as `slam.py` does: before/after figures from one invocation.

--ate-line CM: the all-frames live run's ATE the target is relative to (default: one all-frames run
of the first preset with the live engine, made first). --busy K adds K processes that spin on a core
for the whole benchmark: a loaded machine, reproducibly. Each run's lowest tracking coverage (the
share of the frame's valid depth the map covered; `lost_tracking.min_coverage` calls a frame lost
under it), its frames under 0.25, keyframes and mapper steps cut short (`live.hurry_coverage`) are
listed beside it. Prints a markdown table and, with --json,
the rows.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, ROOT, machine_line  # noqa: E402
from live_rate import fmt, run  # noqa: E402


def spin() -> None:
    while True:
        pass


def coverage(out: Path) -> tuple[float | None, int, int | None]:
    """(lowest tracking coverage, frames under 0.25, mapper steps cut short: live.hurry_coverage) of a run."""
    metrics = json.loads((out / "metrics.json").read_text())
    cov = [r["tracking_coverage"] for r in metrics["per_frame"] if r.get("tracking_coverage") is not None]
    return (min(cov) if cov else None), sum(c < 0.25 for c in cov), metrics.get("live", {}).get("hurried_steps")


def _split(entry: str) -> tuple[str, Path]:
    """PRESET[@CHECKOUT] -> (preset, the checkout whose code runs it)."""
    preset, _, checkout = entry.partition("@")
    return preset, (Path(checkout).resolve() if checkout else ROOT)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequence", default="7scenes_redkitchen_600")
    p.add_argument("--presets", default="live", help="comma-separated presets or '+'-compositions, each "
                   "optionally @CHECKOUT (another checkout's code)")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--factor", type=float, default=1.5)
    p.add_argument("--ate-line", type=float, default=None)
    p.add_argument("--busy", type=int, default=0)
    p.add_argument("--work", default=None)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    presets = args.presets.split(",")
    path = DATA / args.sequence
    work = Path(args.work or tempfile.mkdtemp(prefix="realtime_repeats_"))
    spinners = [multiprocessing.Process(target=spin, daemon=True) for _ in range(args.busy)]
    for s in spinners:
        s.start()
    try:
        line = args.ate_line
        if line is None:
            name, root = _split(presets[0])
            line = run(path, name, "live", None, work / "all_frames", None, root=root).get("ate")
            if line is None:
                sys.exit(f"realtime_repeats: the all-frames run of {presets[0]} on {path} gave no ATE (see {work})")
        rows = []
        for r in range(1, args.rounds + 1):
            for preset in presets:
                out = work / f"{r}_{preset.replace('/', '_').replace('@', '_')}"
                name, root = _split(preset)
                row = dict(round=r, preset=preset, **run(path, name, "live", "realtime", out, None, root=root))
                if "error" not in row:
                    row["coverage_min"], row["frames_under_25"], row["hurried"] = coverage(out)
                    row["met"] = row["lost"] == 0 and row["ate"] is not None and row["ate"] <= args.factor * line
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    finally:
        for s in spinners:
            s.terminate()
    print(f"{args.sequence}, --realtime, {args.rounds} rounds; {machine_line()}; {args.busy} busy process(es); "
          f"target: none lost, ATE <= {args.factor} x {fmt(line)} cm\n")
    print("| round | preset | frames (of received) | lost | ATE cm | PSNR dB | lowest coverage | frames under 25 % "
          "| keyframes | steps cut short | met |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if "error" in row:
            print(f"| {row['round']} | {row['preset']} | error: {row['error']} | | | | | | | | |")
            continue
        print(f"| {row['round']} | {row['preset']} | {row['frames']} of {fmt(row['received'])} | {row['lost']} | "
              f"{fmt(row['ate'])} | {fmt(row['psnr'])} | {fmt(row['coverage_min'])} | {row['frames_under_25']} | "
              f"{row['keyframes']} | {fmt(row['hurried'])} | {'yes' if row['met'] else 'no'} |")
    print()
    for preset in presets:
        mine = [r for r in rows if r["preset"] == preset and "error" not in r]
        print(f"- {preset}: met {sum(r['met'] for r in mine)} of {len(mine)}; no frame lost in "
              f"{sum(r['lost'] == 0 for r in mine)}")
    if args.json:
        print(json.dumps(dict(machine=machine_line(), line=line, rows=rows)))


if __name__ == "__main__":
    main()
