"""Is a change behaviour-neutral? Runs two checkouts side by side and compares their run folders.

    git worktree add ../before <commit before the change>
    python benchmarks/identical_outputs.py --before ../before              # synthetic + the real sequences
    python benchmarks/identical_outputs.py --before ../before --sequences synthetic --max-frames 20
    python benchmarks/identical_outputs.py --before ../before --sequences lap     # the drifting lap alone

Each sequence is run by both checkouts with the sequential engine (deterministic) and the given
preset (default cpu), one `splatam run` process each (benchmarks/slam.py's run_one), and the
SHA-256 of trajectory.txt and map.ply are compared. Prints JSON: one row per sequence with both
digests, `identical` per file, the ATE and s/frame median of both, and `all_identical`.

`lap` is the synthetic lap with drifting given poses whose loop corrections are applied
(benchmarks/drifting_loop.py, as tests/loop/test_loop_closure.py runs it): each checkout runs it with its
own harness and the digests of every frame's pose and of the map's arrays are compared.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, REAL, ROOT, machine  # noqa: E402
from slam import run_one  # noqa: E402

FILES = ("trajectory.txt", "map.ply")


def digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


LAP = dict(n_frames=40, width=128, height=96, overlap=0.3)
LAP_OVERRIDES = {"resolution": [128, 96], "checkpoint_every": 10, "eval_every": 100,
                 "mapping": {"iterations": 4, "first_frame_iterations": 20, "window_size": 4},
                 "loop_closure": {"enabled": True, "min_gap_frames": 20, "remap_iterations": 4}}


def lap_digests(preset: str) -> dict:
    """Run the drifting lap with this interpreter's splat_core (and the harness of the checkout on
    sys.path): digests of the poses and the map, the loops applied."""
    import numpy as np

    try:                                   # before the harness moved to benchmarks/
        from splat_core.loop.evaluate import run_drifting
    except ImportError:
        from drifting_loop import run_drifting
    from splat_core.config import load_config
    from splat_core.synthetic import LoopSource

    r = run_drifting(LoopSource(**LAP), load_config(preset, LAP_OVERRIDES), True, 0.002, 0.25)
    slam = r["slam"]
    arrays = slam.map.to_numpy()
    return {"trajectory": hashlib.sha256(np.ascontiguousarray(np.array(slam.w2cs)).tobytes()).hexdigest(),
            "map": hashlib.sha256(b"".join(np.ascontiguousarray(arrays[k]).tobytes() for k in sorted(arrays))).hexdigest(),
            "ate_rmse_cm": r["ate_rmse_cm"], "loops_applied": sum(bool(lp["applied"]) for lp in r["loops"])}


def run_lap(code: Path, preset: str) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(code), str(code / "benchmarks"),
                                                       os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, __file__, "--lap-digests", preset], cwd=code, env=env,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> int:
    if sys.argv[1:2] == ["--lap-digests"]:
        print(json.dumps(lap_digests(sys.argv[2])))
        return 0
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", required=True, help="checkout of the code before the change")
    p.add_argument("--after", default=str(ROOT), help="checkout of the code after it (default: this one)")
    p.add_argument("--sequences", default="synthetic," + ",".join(REAL) + ",lap")
    p.add_argument("--preset", default="cpu")
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"],
                   help="live: not deterministic; compare the rows' ATE and s/frame, not the digests")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--data", default=str(DATA))
    p.add_argument("--work", default=None, help="folder for the run folders (default: a temporary one)")
    args = p.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="splatam_identical_"))
    rows = []
    for seq in args.sequences.split(","):
        if seq == "lap":
            row = dict(sequence="lap", preset=args.preset, **{side: run_lap(Path(code).resolve(), args.preset)
                       for side, code in (("before", args.before), ("after", args.after))})
            row["identical"] = {name: row["before"].get(name) is not None and row["before"][name] == row["after"].get(name)
                                for name in ("trajectory", "map")}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
            continue
        path = "synthetic" if seq == "synthetic" else Path(args.data) / seq
        if seq != "synthetic" and not Path(path).is_dir():
            rows.append(dict(sequence=seq, skipped=f"{path} not found"))
            continue
        row = dict(sequence=seq, preset=args.preset)
        for side, code in (("before", args.before), ("after", args.after)):
            out = work / f"{seq}__{side}" if args.engine == "sequential" else work / f"{seq}__{args.engine}__{side}"
            m = run_one(path, args.preset, out, args.max_frames, "cpu", args.engine, Path(code).resolve())
            row[side] = dict(error=m.get("error"), ate_rmse_cm=m.get("ate_rmse_cm"),
                             seconds_per_frame_median=m.get("seconds_per_frame_median"),
                             **{name: digest(out / name) for name in FILES})
        row["identical"] = {name: row["before"][name] is not None and row["before"][name] == row["after"][name]
                            for name in FILES}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    ran = [r for r in rows if "identical" in r]
    result = dict(machine=machine(), before=str(Path(args.before).resolve()), after=str(Path(args.after).resolve()),
                  rows=rows, all_identical=bool(ran) and all(all(r["identical"].values()) for r in ran))
    print(json.dumps(result, indent=1))
    return 0 if result["all_identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
