"""Is a stretch's error the tracker's, or the map's it tracks against? (issue 28, item 5)

    python benchmarks/tracking_stretch.py [--sequence 7scenes_redkitchen_600] [--start 452] [--end 510]
                                          [--preset cpu] [--json]

Two runs of the same preset (sequential engine) over frames 0 .. end-1:
- tracked:   every frame tracked, as `splatam run` does;
- reference: frames before --start mapped at the reference poses (tracking.use_reference_poses),
             frames from --start on tracked against that map.
Both report the ATE of frames start .. end-1 aligned on their own (metrics.ate_rmse), the mean
frame-to-frame translation error there, and, at a few frames of the stretch, which part of the run
the Gaussians in view were born in (share of the Gaussians whose centres project into the view,
opacity > 0.5, by 50-frame birth stretch). If the tracker, given a map built at the reference
poses, follows the stretch well while the tracked run does not, the stretch's error comes from the
map (parts of it made at drifted poses), not from tracking that frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import DATA, machine_line  # noqa: E402


def births_in_view(pipe, t: int, bins: int = 50) -> dict:
    """Share of the Gaussians whose centres fall in frame t's view, by birth stretch (frames)."""
    g = pipe.engine.slam.map
    means = g.params["means"].detach().cpu().numpy()
    opacity = 1.0 / (1.0 + np.exp(-g.params["logit_opacities"].detach().cpu().numpy().reshape(-1)))
    birth = g.birth_frame.cpu().numpy()
    w2c, intr = pipe.engine.slam.w2cs[t], pipe.intrinsics
    p = means @ w2c[:3, :3].T + w2c[:3, 3]
    z = np.maximum(p[:, 2], 1e-6)
    u, v = intr.fx * p[:, 0] / z + intr.cx, intr.fy * p[:, 1] / z + intr.cy
    seen = (p[:, 2] > 0.1) & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height) & (opacity > 0.5)
    counts = np.bincount(birth[seen] // bins)
    total = max(int(seen.sum()), 1)
    return {f"{k * bins}-{k * bins + bins - 1}": round(float(c) / total, 3) for k, c in enumerate(counts) if c}


def run(mode: str, path: Path, preset: str, start: int, end: int) -> dict:
    from splat_core.config import load_config
    from splat_core.io import open_capture
    from splat_core.metrics import ate_rmse, relative_pose_errors
    from splat_core.run.pipeline import Pipeline

    source = open_capture(path)
    config = load_config(preset)
    pipe = Pipeline(source, config, None, device="cpu", max_frames=end)
    if mode == "reference":
        pipe.config = dataclasses.replace(pipe.config, tracking=dataclasses.replace(
            pipe.config.tracking, use_reference_poses=True))
    views = {}
    looks = sorted({start, (start + end) // 2, end - 1})
    while (result := pipe.step()) is not None:
        if result.index == start - 1 and mode == "reference":
            pipe.config = dataclasses.replace(pipe.config, tracking=dataclasses.replace(
                pipe.config.tracking, use_reference_poses=False))
        if result.index in looks:
            views[result.index] = births_in_view(pipe, result.index)
    est = np.stack(pipe.estimated_c2w())[start:end]
    ref = np.stack(pipe.reference_c2w())[start:end]
    steps, _ = relative_pose_errors(est, ref, 1)
    return dict(mode=mode, frames=f"{start}-{end - 1}", ate_cm=round(100 * ate_rmse(est, ref), 2),
                step_error_mm=round(1000 * float(np.mean(steps)), 2), births_in_view=views)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sequence", default="7scenes_redkitchen_600")
    p.add_argument("--data", default=str(DATA))
    p.add_argument("--start", type=int, default=452)
    p.add_argument("--end", type=int, default=510)
    p.add_argument("--preset", default="cpu")
    p.add_argument("--modes", default="tracked,reference")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    path = Path(args.data) / args.sequence
    rows = []
    for mode in args.modes.split(","):
        row = dict(sequence=args.sequence, preset=args.preset, **run(mode, path, args.preset, args.start, args.end))
        rows.append(row)
        print(json.dumps(row) if args.json else
              f"{mode:9s} frames {row['frames']}: ATE {row['ate_cm']} cm, step error {row['step_error_mm']} mm; "
              f"births in view {row['births_in_view']}", flush=True)
    print(json.dumps({"machine": machine_line()}) if args.json else machine_line())
    return 0


if __name__ == "__main__":
    sys.exit(main())
