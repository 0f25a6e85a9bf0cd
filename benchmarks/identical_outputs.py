"""Is a change behaviour-neutral? Runs two checkouts side by side and compares their run folders.

    git worktree add ../before <commit before the change>
    python benchmarks/identical_outputs.py --before ../before              # synthetic + the real sequences
    python benchmarks/identical_outputs.py --before ../before --sequences synthetic --max-frames 20

Each sequence is run by both checkouts with the sequential engine (deterministic) and the given
preset (default cpu), one `splatam run` process each (benchmarks/slam.py's run_one), and the
SHA-256 of trajectory.txt and map.ply are compared. Prints JSON: one row per sequence with both
digests, `identical` per file, the ATE and s/frame median of both, and `all_identical`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, REAL, ROOT, machine  # noqa: E402
from slam import run_one  # noqa: E402

FILES = ("trajectory.txt", "map.ply")


def digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", required=True, help="checkout of the code before the change")
    p.add_argument("--after", default=str(ROOT), help="checkout of the code after it (default: this one)")
    p.add_argument("--sequences", default="synthetic," + ",".join(REAL))
    p.add_argument("--preset", default="cpu")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--data", default=str(DATA))
    p.add_argument("--work", default=None, help="folder for the run folders (default: a temporary one)")
    args = p.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="splatam_identical_"))
    rows = []
    for seq in args.sequences.split(","):
        path = "synthetic" if seq == "synthetic" else Path(args.data) / seq
        if seq != "synthetic" and not Path(path).is_dir():
            rows.append(dict(sequence=seq, skipped=f"{path} not found"))
            continue
        row = dict(sequence=seq, preset=args.preset)
        for side, code in (("before", args.before), ("after", args.after)):
            out = work / f"{seq}__{side}"
            m = run_one(path, args.preset, out, args.max_frames, "cpu", "sequential", Path(code).resolve())
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
