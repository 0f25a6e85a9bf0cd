"""Where a run on the synthetic corridor goes wrong, frame by frame (issue 42: the live preset lost it).

    python benchmarks/corridor_frames.py --frames 300 --preset live --engine live
    python benchmarks/corridor_frames.py --frames 300 --preset live --engine live \
        --set '{"tracking": {"align": {"reuse_rival": false}}}'
    python benchmarks/corridor_frames.py --frames 280 --preset live --engine sequential --set '{"mapping": {"map_every": 5}}'

The corridor (splat_core/synthetic/corridor.py) at 320x240, SLAM with the given preset, engine and
overrides (`--set`: JSON merged over the preset). One JSON line per frame: the camera-centre error
against the reference relative to frame 0 (`err_cm`, no alignment), the error of the step from the
frame before (`step_cm`; `step_xyz_cm` in that camera's axes: x right, y down, z forward), keyframe,
the start the tracker's polish kept (`start`), lost reason, map version and its lag in frames (live
engine), Gaussians. Then one summary line: ATE over the run (metrics.json), frames lost, the error
at a few frames and the largest error over frames 230-270 (looking down the corridor), the live
engine's stats. The live engine is not deterministic: compare several runs.
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

from splat_core.camera import invert_pose  # noqa: E402
from splat_core.config import load_config  # noqa: E402
from splat_core.run import Pipeline  # noqa: E402
from splat_core.synthetic import CorridorSource  # noqa: E402


def merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for k, v in extra.items():
        out[k] = merge(out.get(k, {}), v) if isinstance(v, dict) else v
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--preset", default="live")
    p.add_argument("--engine", default="live", choices=["sequential", "live"])
    p.add_argument("--set", default="{}", help="JSON overrides merged over the preset")
    args = p.parse_args(argv)
    cfg = load_config(args.preset, overrides=merge({"resolution": [320, 240], "eval_every": 10**9},
                                                   json.loads(args.set)))
    source = CorridorSource(n_frames=args.frames, width=320, height=240)
    ref = np.asarray(source.c2w)
    errors = {}
    with tempfile.TemporaryDirectory() as tmp:
        pipe = Pipeline(source, cfg, Path(tmp) / "run", engine=args.engine)
        engine = pipe.engine
        while (r := pipe.step()) is not None:
            t, c2w = r.index, invert_pose(r.w2c)
            truth = np.linalg.inv(ref[0]) @ ref[r.source_index]
            row = dict(t=t, err_cm=round(100 * float(np.linalg.norm(c2w[:3, 3] - truth[:3, 3])), 2))
            if t > 0:
                step = np.linalg.inv(invert_pose(engine.slam.w2cs[t - 1])) @ c2w
                step_ref = np.linalg.inv(ref[t - 1]) @ ref[t]
                d = 100 * (step[:3, 3] - step_ref[:3, 3])
                row.update(step_cm=round(float(np.linalg.norm(d)), 3), step_xyz_cm=[round(float(v), 2) for v in d])
            lags = getattr(engine, "lags", None)
            row.update(keyframe=bool(r.is_keyframe), start=r.tracking_start, lost=r.lost, map_version=r.map_version,
                       lag=lags[-1] if lags and t > 0 else None, gaussians=r.num_gaussians)
            errors[t] = row["err_cm"]
            print(json.dumps(row), flush=True)
        metrics = pipe.finish()
    corridor = [e for t, e in errors.items() if 230 <= t <= 270]
    print(json.dumps(dict(summary=True, preset=args.preset, engine=args.engine, overrides=json.loads(args.set),
                          frames=args.frames, ate_cm=metrics["ate_rmse_cm"], frames_lost=metrics["frames_lost"],
                          err_cm_at={str(k): errors.get(k) for k in (100, 200, 240, 260, 299)},
                          max_err_cm_230_270=max(corridor) if corridor else None, live=metrics.get("live"))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
