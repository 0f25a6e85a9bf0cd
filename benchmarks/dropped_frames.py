"""Tracking across dropped frames, without a clock: a capture handed to SLAM as a real-time playback
would hand it, but with the frames to process fixed in advance (a gap pattern, or the frames a
real `--realtime` run processed), so the result does not depend on the machine's speed or load.

    python benchmarks/dropped_frames.py --sequences 7scenes_redkitchen_300 --gaps 3,11
    python benchmarks/dropped_frames.py --sequences 7scenes_redkitchen_300 --replay RUN/metrics.json
    python benchmarks/dropped_frames.py --gaps 3,11 --configs live,cpu --engine live --before ../before

--gaps 3,11: capture frames 0, 1, 4, 15, 18, 29, ... (frame 0, then gaps cycling through the list;
the first gap is 1, as a playback hands frame 1 once frame 0 is mapped). --replay: the capture
frames of a run folder's metrics.json (`per_frame` source_index). Each (sequence, config,
checkout) is one process (this checkout's, and --before DIR's: a `git worktree` of an earlier
commit) running the Pipeline on a scripted live source (the frames in that order, every other
frame counted as dropped). Prints a markdown table: frames processed, keyframes, frames lost
(metrics.json `frames_lost`), ATE against the capture's reference (7-Scenes: groundtruth.txt;
`benchmarks/three_lenses.py --run OUT/...` for both references). With the sequential engine the
figures are deterministic; the live engine's depend on its mapper's timing.
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


def gap_indices(gaps: list[int], count: int) -> list[int]:
    """Frame 0, frame 1, then gaps cycling through `gaps`, below `count`."""
    indices, k = [0, 1], 0
    while indices[-1] + gaps[k % len(gaps)] < count:
        indices.append(indices[-1] + gaps[k % len(gaps)])
        k += 1
    return indices


def child(args) -> None:
    """In the checkout on PYTHONPATH: run the Pipeline on the scripted source, print metrics."""
    from splat_core.config import load_config
    from splat_core.io.source import LiveSource
    from splat_core.run import Pipeline
    from splat_core.run.frame_feed import open_input

    class Scripted(LiveSource):
        """The capture's frames `indices` in order, as a playback would hand them over."""

        def __init__(self, inner, indices):
            self.inner, self.indices, self.position, self._arrived = inner, indices, 0, 0
            self.format_name, self.path, self.registered = inner.format_name, inner.path, inner.registered
            self.registered_by = inner.registered_by

        def next_index(self, timeout=None):
            if self.position >= len(self.indices):
                return None
            index = self.indices[self.position]
            self.position += 1
            self.delivered += 1
            self._arrived = index + 1
            return index

        def next_frame(self, timeout=None):
            index = self.next_index()
            return None if index is None else self.inner[index]

        def stop(self):
            self.position = len(self.indices)

        def __len__(self):
            return self._arrived

        def __getitem__(self, i):
            return self.inner[i]

        intrinsics = property(lambda self: self.inner.intrinsics)
        timestamps = property(lambda self: self.inner.timestamps[: self._arrived])
        has_reference_poses = property(lambda self: self.inner.has_reference_poses)

        def reference_c2w(self):
            ref = self.inner.reference_c2w()
            return None if ref is None else ref[: self._arrived]

        def frame_at_size(self, i, width, height):
            return self.inner.frame_at_size(i, width, height)

        def raw_pair(self, i):
            return self.inner.raw_pair(i)

        def _name(self, i, kind):
            return self.inner._name(i, kind)

    inner = open_input(args.input)
    indices = json.loads(args.indices)
    pipe = Pipeline(Scripted(inner, indices), load_config(args.config), out_dir=Path(args.out), device="cpu",
                    engine=args.engine)
    while pipe.step() is not None:
        pass
    m = pipe.finish()
    print(json.dumps(dict(frames=m["frames"], keyframes=m.get("keyframes"), lost=m.get("frames_lost"),
                          ate=m.get("ate_rmse_cm"), psnr=m.get("psnr"),
                          lost_at=[r["source_index"] for r in m.get("lost", [])])))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", default="7scenes_redkitchen_300")
    p.add_argument("--gaps", default="3,11", help="the gap pattern in capture frames (cycled)")
    p.add_argument("--replay", default=None, help="a run folder's metrics.json: its processed frames instead")
    p.add_argument("--max-frames", type=int, default=None, help="capture frames to play (default: all)")
    p.add_argument("--configs", default="live", help="presets or YAML files, comma-separated")
    p.add_argument("--engine", default="sequential", choices=["sequential", "live"])
    p.add_argument("--before", default=None, help="another checkout: the same runs by it")
    p.add_argument("--work", default=None)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--input", help=argparse.SUPPRESS)
    p.add_argument("--indices", help=argparse.SUPPRESS)
    p.add_argument("--config", help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        return child(args)
    work = Path(args.work or tempfile.mkdtemp(prefix="dropped_frames_"))
    load = os.getloadavg()
    print(f"{datetime.date.today()} · {machine_line()} · load average at start "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)
    checkouts = [(ROOT, "this")]
    if args.before:
        before = Path(args.before).resolve()
        commit = subprocess.run(["git", "-C", str(before), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        checkouts.append((before, f"before: {commit}"))
    rows = []
    for seq in args.sequences.split(","):
        path = DATA / seq
        if args.replay:
            records = json.loads(Path(args.replay).read_text())["per_frame"]
            indices, pattern = [int(r["source_index"]) for r in records], f"replay of {args.replay}"
        else:
            count = args.max_frames or len(list((path / "rgb").iterdir()))
            indices, pattern = gap_indices([int(g) for g in args.gaps.split(",")], count), f"gaps {args.gaps}"
        if args.max_frames:
            indices = [i for i in indices if i < args.max_frames]
        for config in args.configs.split(","):
            for root, name in checkouts:
                out = work / f"{seq}__{Path(config).stem}__{args.engine}__{name.split(':')[0]}"
                cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--input", str(path), "--indices",
                       json.dumps(indices), "--config", config, "--out", str(out), "--engine", args.engine]
                proc = subprocess.run(cmd, cwd=root, env=dict(os.environ, PYTHONPATH=str(root)), capture_output=True,
                                      text=True)
                lines = proc.stdout.strip().splitlines()
                result = json.loads(lines[-1]) if proc.returncode == 0 and lines else \
                    {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
                row = dict(sequence=seq, pattern=pattern, config=config, engine=args.engine, checkout=name,
                           run=str(out), **result)
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    print("\n| sequence | frames handed over | config | engine | checkout | frames | keyframes | frames lost | "
          "ATE cm |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['sequence']} | {r['pattern']} | {r['config']} | {r['engine']} | {r['checkout']} | "
                  f"error: {r['error']} ||||")
            continue
        print(f"| {r['sequence']} | {r['pattern']} | {r['config']} | {r['engine']} | {r['checkout']} | {r['frames']} | "
              f"{r['keyframes']} | {r['lost']} | {r['ate']:.2f} |")
    load = os.getloadavg()
    print(f"\nload average at end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    main()
