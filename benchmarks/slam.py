"""SLAM accuracy and speed per preset and sequence; prints JSON (one object per run).

    python benchmarks/slam.py --json                               # synthetic + ../shared/data
    python benchmarks/slam.py --sequences synthetic --presets cpu --max-frames 20
    python benchmarks/slam.py --json --open3d                     # + Open3D baselines side by side
                                                                  #   (dense SLAM at 2 cm and 5.8 mm voxels)
    python benchmarks/slam.py --engines sequential,live --presets cpu_dense,cpu   # both engines, one run
    python benchmarks/slam.py --presets cpu_dense@sequential,cpu@live,cpu@sequential --open3d
                                                                  # PRESET@ENGINE: that engine only
    git worktree add /tmp/before HEAD~3
    python benchmarks/slam.py --presets cpu@sequential@/tmp/before,cpu@live,cpu@sequential --open3d
                                                                  # PRESET@ENGINE@CHECKOUT: another checkout's
                                                                  #   code (the code before a change, same run)

s/frame is wall-clock time per frame (`wall_seconds` in metrics.json: from the end of one frame to
the end of the next, so the live engine's waits for its mapper count, and the time its mapper
needs after the last frame is added to that frame); the median skips frame 0.

Each run is a separate `splatam run` process (so peak memory is per run) writing into
--work (default: a temporary folder); figures come from its metrics.json.

A real sequence whose reference poses have a step that its own depth contradicts
(splat_core.io.checks.inconsistent_steps; 7-Scenes redkitchen: 121 -> 122) also gets
reference_breaks and ate_rmse_split_cm: the ATE with the trajectory cut there and each piece
aligned on its own, so that one wrong reference step is not charged to the estimate.
ate_rmse_cm stays the ATE against the reference as published.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DATA, REAL, ROOT, machine_line  # noqa: E402


def run_one(input_path, preset: str, out: Path, max_frames: int | None, device: str,
            engine: str = "sequential", code: Path = ROOT) -> dict:
    cmd = [sys.executable, "-m", "app.cli", "run", "--input", str(input_path), "--out", str(out),
           "--config", preset, "--device", device, "--engine", engine, "--quiet"]
    if max_frames:
        cmd += ["--max-frames", str(max_frames)]
    if out.exists():
        cmd += ["--resume"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(code), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    m = json.loads((out / "metrics.json").read_text())
    keep = ("frames", "frames_skipped", "frames_lost", "ate_rmse_cm", "ate_mean_legacy_cm", "psnr", "ssim", "depth_l1_cm",
            "tracking_seconds_per_frame", "mapping_seconds_per_frame", "wall_seconds_per_frame", "cpu_seconds_per_frame",
            "num_gaussians", "peak_memory_mb", "peak_gpu_memory_mb", "resolution", "device", "engine", "live")
    result = {k: m.get(k) for k in keep if k in m}
    later = [f["wall_seconds"] for f in m.get("per_frame", [])[1:]]
    if later:   # frame 0 runs the long first mapping; the median of the rest is the steady cost
        result["seconds_per_frame_median"] = statistics.median(later)
    return result


def split_ate_cm(run_dir: Path, src, breaks: list[int]) -> float | None:
    """ATE of a run with the reference cut at `breaks`, each piece aligned on its own
    (metrics.ate_rmse_segments); frames matched by timestamp. None if the run left no trajectory."""
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.metrics import ate_rmse_segments

    if not (run_dir / "trajectory.txt").exists():
        return None
    stamps, est = read_tum_trajectory(run_dir / "trajectory.txt")
    index = {round(float(t), 4): i for i, t in enumerate(src.timestamps)}
    frames = [index[round(float(t), 4)] for t in stamps]
    ref = src.reference_c2w()[frames]
    cuts = [k for k, f in enumerate(frames[:-1]) if any(f <= b < frames[k + 1] for b in breaks)]
    return 100.0 * ate_rmse_segments(est, ref, cuts)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", default="synthetic," + ",".join(REAL))
    p.add_argument("--presets", default="cpu")
    p.add_argument("--engines", default="sequential",
                   help="comma-separated: sequential, live (for presets given without @ENGINE)")
    p.add_argument("--max-frames", type=int, default=None, help="limit every sequence (default: all)")
    p.add_argument("--device", default="auto")
    p.add_argument("--data", default=str(DATA), help="folder holding the real sequences (default: %(default)s)")
    p.add_argument("--work", default=None, help="folder for run outputs (kept; reruns resume)")
    p.add_argument("--open3d", action="store_true",
                   help="also run benchmarks/baseline_open3d.py on the real sequences (needs the bench extra)")
    p.add_argument("--open3d-voxels", default="0.02,0.0058",
                   help="TSDF voxel sizes of the Open3D dense SLAM runs (default: the issue's two, %(default)s)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    sys.path.insert(0, str(ROOT))
    from splat_core.io import open_capture
    from splat_core.io.checks import reference_breaks

    work = Path(args.work).resolve() if args.work else Path(tempfile.mkdtemp(prefix="splatam_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    results, checks = [], {}
    for seq in args.sequences.split(","):
        if seq == "synthetic":
            path = "synthetic"          # the built-in 60-frame 320x240 scene
        else:
            path = Path(args.data) / seq
            if not path.is_dir():
                results.append({"sequence": seq, "skipped": f"{path} not found"})
                continue
            src = open_capture(path)
            checks[seq] = (src, reference_breaks(src))    # docs/benchmarks.md, Accuracy (7-Scenes' reference)
        for entry in args.presets.split(","):
            preset, _, rest = entry.partition("@")
            engine_of_entry, _, checkout = rest.partition("@")
            code = Path(checkout).resolve() if checkout else ROOT
            for engine in [engine_of_entry] if engine_of_entry else args.engines.split(","):
                tag = f"__{code.name}" if checkout else ""
                # every part of a '+'-composition named (cpu+A.yaml+S1.yaml is not cpu+S1.yaml's folder)
                name = "_".join(Path(part).stem for part in preset.split("+"))
                out = work / f"{seq}__{name}__{engine}{tag}"
                row = {"sequence": seq, "preset": preset, "engine": engine,
                       **({"code": str(code)} if checkout else {}),
                       **run_one(path, preset, out, args.max_frames, args.device, engine, code),
                       "machine": machine_line(), "run_dir": str(out)}
                src, breaks = checks.get(seq, (None, []))
                if breaks:
                    row["reference_breaks"] = breaks
                    row["ate_rmse_split_cm"] = split_ate_cm(out, src, breaks)
                results.append(row)
                if not args.json:
                    print(json.dumps(row), flush=True)
    real = [s for s in args.sequences.split(",") if s != "synthetic"]
    if args.open3d and real:
        cmd = [sys.executable, str(ROOT / "benchmarks" / "baseline_open3d.py"), "--sequences", ",".join(real),
               "--voxel-size", args.open3d_voxels]
        if args.max_frames:
            cmd += ["--max-frames", str(args.max_frames)]
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        lines = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
        if proc.returncode != 0 and not lines:
            lines = [{"method": "open3d", "error": proc.stderr.strip().splitlines()[-1:]}]
        for row in lines:
            results.append({"preset": row.pop("method", "open3d"), **row})
            if not args.json:
                print(json.dumps(results[-1]), flush=True)
    if args.json:
        print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
