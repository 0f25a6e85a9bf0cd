"""Meshes of finished runs (`splatam export --format mesh`), both depth sources; prints JSON.

    python benchmarks/mesh.py [RUN_DIR ...] [--synthetic-run DIR] [--synthetic-frames 40]
                              [--synthetic-seed 0] [--synthetic-noise 0] [--synthetic-holes 0]
                              [--synthetic-speed 1] [--synthetic-kind room|corridor]
                              [--frames keyframes 3 2 all]
                              [--timing-run RUN_DIR] [--modes captured rendered]

- Synthetic: a run of the procedural room (SyntheticSource, 320x240, the cpu preset; or the corridor
  walk, CorridorSource, with its 5 m depth range; made in
  --synthetic-run when that folder has no run yet), its mesh scored against the scene's exact
  surfaces: accuracy (mesh surface samples to the nearest surface: median / mean / p90 cm) and
  completion (surface the capture saw: exact depth of EVERY frame at the exact poses, within the
  sensor's range, within 2 cm of
  the mesh; `completion_keyframes`: the keyframes' surface alone). Each --frames choice
  (keyframes, every Nth frame, all) is meshed, the extra frames re-read from the re-created source.
- Real runs (RUN_DIR, e.g. of ../shared/data/7scenes_redkitchen_300 and the SUN3D fragments): the
  same two figures against the captured depth of every 5th processed frame back-projected with the
  REFERENCE poses (so pose drift counts against the mesh). Both are put in the run's world frame
  by the first frame's pose, as the run itself is.
- --timing-run: wall time and peak memory (ru_maxrss) of `splatam export RUN --format mesh` in a
  fresh process per depth source (imports and Numba's cached kernels included).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
from common import machine  # noqa: E402
from mesh_score import depth_points, score_against_points, score_against_scene  # noqa: E402

from splat_core.camera import invert_pose  # noqa: E402
from splat_core.export.mesh import build_mesh  # noqa: E402
from splat_core.refine.run_data import load_run_data, open_run_capture  # noqa: E402

SYN_SIZE = (320, 240)


def synthetic_run(folder: Path, n_frames: int, seed: int = 0, noise: float = 0.0, holes: float = 0.0,
                  speed: float = 1.0, kind: str = "room"):
    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import CorridorSource, SyntheticSource

    kind_source = CorridorSource if kind == "corridor" else SyntheticSource
    src = kind_source(n_frames=n_frames, width=SYN_SIZE[0], height=SYN_SIZE[1], seed=seed, noise=noise, holes=holes,
                      speed=speed)
    if not (folder / "map.ply").exists():
        pipe = Pipeline(src, load_config("cpu"), folder)
        while pipe.step() is not None:
            pass
        pipe.finish()
    return src


def mesh_in(run, mode: str, frames: str = "keyframes", source=None):
    t0 = time.perf_counter()
    mesh = build_mesh(run, depth=mode, frames=frames, source=source)
    return mesh, time.perf_counter() - t0


def score_synthetic(folder: Path, n_frames: int, modes, frames=("keyframes",), seed: int = 0,
                    noise: float = 0.0, holes: float = 0.0, speed: float = 1.0, kind: str = "room") -> dict:
    src = synthetic_run(folder, n_frames, seed, noise, holes, speed, kind)
    run = load_run_data(folder)
    first = src.c2w[int(run.records[0]["source_index"])]
    truth = {}
    for k in range(len(run.records)):
        c2w = src.c2w[int(run.records[k]["source_index"])]
        depth = src.render_view(c2w, run.intrinsics)[1]
        if src.max_depth:                       # the sensor's range: what no frame can see is not missed
            depth = np.where(depth <= src.max_depth, depth, 0.0)
        truth[k] = depth_points(depth, c2w, run.intrinsics, 2)
    seen = np.concatenate(list(truth.values()))
    kf_seen = np.concatenate([truth[k] for k in run.keyframe_indices])
    out = dict(run=str(folder), kind=kind, seed=seed, noise=noise, holes=holes, speed=speed, frames=len(run.records),
               keyframes=len(run.keyframes),
               ate_rmse_cm=_metrics(folder).get("ate_rmse_cm"))
    for mode in modes:
        for which in frames:
            mesh, seconds = mesh_in(run, mode, which, src)
            mesh.apply_transform(first)
            kf_score = score_against_scene(mesh, src.scene, kf_seen)
            out[f"{mode}/{which}"] = dict(seconds=round(seconds, 2), fused=mesh.metadata["fused"],
                                          voxel=mesh.metadata["voxel"], trunc=mesh.metadata["trunc"],
                                          completion_keyframes=kf_score["completion"],
                                          **score_against_scene(mesh, src.scene, seen))
    return out


def score_real(folder: Path, modes, every: int = 5, frames=("keyframes",)) -> dict:
    from splat_core.run.frame_feed import prepare_frame

    run = load_run_data(folder)
    source = open_run_capture(run)
    ref = source.reference_c2w()
    first = ref[int(run.records[0]["source_index"])]
    to_run = invert_pose(first)
    truth = []
    for k in range(0, len(run.records), every):
        si = int(run.records[k]["source_index"])
        if not np.all(np.isfinite(ref[si])):
            continue
        frame = prepare_frame(source, si, run.intrinsics, run.config.max_depth)
        truth.append(depth_points(frame.depth, to_run @ ref[si], run.intrinsics, 2))
    truth = np.concatenate(truth)
    out = dict(run=str(folder), capture=run.capture["path"], frames=len(run.records), keyframes=len(run.keyframes),
               ate_rmse_cm=_metrics(folder).get("ate_rmse_cm"), reference_points=len(truth))
    for mode in modes:
        for which in frames:
            mesh, seconds = mesh_in(run, mode, which)
            out[f"{mode}/{which}"] = dict(seconds=round(seconds, 2), fused=mesh.metadata["fused"],
                                          voxel=mesh.metadata["voxel"], trunc=mesh.metadata["trunc"],
                                          **score_against_points(mesh, truth))
    return out


def timing(folder: Path, modes) -> dict:
    """Wall time and peak RSS of the CLI export, one fresh process per depth source."""
    out = dict(run=str(folder))
    with tempfile.TemporaryDirectory() as tmp:
        for mode in modes:
            code = ("import json, resource, sys, time; from app.cli import splatam_main; t = time.perf_counter(); "
                    f"rc = splatam_main(['export', {str(folder)!r}, '--format', 'mesh', '--depth', {mode!r}, "
                    f"'--out', {str(Path(tmp) / 'm.ply')!r}, '--quiet']); "
                    "print(json.dumps(dict(rc=rc, wall_seconds=time.perf_counter() - t, "
                    "peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))")
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
            lines = res.stdout.strip().splitlines()
            out[mode] = dict(json.loads(lines[-1]), export=json.loads(lines[-2]),
                             process_seconds=round(time.perf_counter() - t0, 2))
    return out


def _metrics(folder: Path) -> dict:
    try:
        return json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="*", metavar="RUN_DIR", help="finished runs of real captures with reference poses")
    p.add_argument("--synthetic-run", default=None, help="folder of the synthetic run (made when empty)")
    p.add_argument("--synthetic-frames", type=int, default=40)
    p.add_argument("--synthetic-seed", type=int, default=0, help="another room and path (seed of SyntheticSource)")
    p.add_argument("--synthetic-noise", type=float, default=0.0, help="depth noise std / depth^2 (1/m)")
    p.add_argument("--synthetic-holes", type=float, default=0.0, help="share of depth pixels invalid, in blobs")
    p.add_argument("--synthetic-speed", type=float, default=1.0, help="camera motion per frame (1: hand-held)")
    p.add_argument("--synthetic-kind", default="room", choices=["room", "corridor"], help="the scene and path")
    p.add_argument("--frames", nargs="+", default=["keyframes"], help="keyframes, all, N (every Nth)")
    p.add_argument("--timing-run", default=None, help="run folder to time the CLI export on")
    p.add_argument("--modes", nargs="+", default=["captured", "rendered"], choices=["captured", "rendered"])
    args = p.parse_args()
    result = dict(benchmark="mesh", machine=machine(), date=time.strftime("%Y-%m-%d"))
    if args.synthetic_run:
        result["synthetic"] = score_synthetic(Path(args.synthetic_run), args.synthetic_frames, args.modes,
                                              args.frames, args.synthetic_seed, args.synthetic_noise,
                                              args.synthetic_holes, args.synthetic_speed, args.synthetic_kind)
    result["real"] = [score_real(Path(r), args.modes, frames=args.frames) for r in args.runs]
    if args.timing_run:
        result["timing"] = timing(Path(args.timing_run), args.modes)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
