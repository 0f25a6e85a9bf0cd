"""benchmarks/gpu.sh's last step: slam.json and summary.json from the stages' outputs.

    python benchmarks/gpu_summary.py --work /tmp/splatam_gpu_work --out gpu_out --gpu-preset gpu --ref-preset splatam

slam.json: every run's row (benchmarks/slam.py's fields) and, per sequence, the `gpu` preset live
against the `splatam` preset sequential with the issue's targets checked: median frames/s >= 10
(moonshot 30), ATE no worse (and on 7-Scenes the ATE split at its flagged reference step), PSNR
within 1 dB. The reference runs ran while pytest did (gpu.sh), so their s/frame is marked
concurrent; the `gpu` runs ran alone. summary.json: machine, each stage's exit code and seconds,
the targets, peak GPU memory over every run, the paths of the other files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if line.startswith("{"):
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                pass
    return rows


def _json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _fps(row: dict | None) -> float | None:
    s = (row or {}).get("seconds_per_frame_median")
    return round(1.0 / s, 2) if s else None


def compare(seq: str, gpu: dict | None, ref: dict | None) -> dict:
    out = {"sequence": seq, "gpu_ran": bool(gpu and "error" not in gpu), "ref_ran": bool(ref and "error" not in ref)}
    if gpu:
        out.update(gpu_fps_median=_fps(gpu), gpu_s_per_frame_median=gpu.get("seconds_per_frame_median"),
                   gpu_ate_cm=gpu.get("ate_rmse_cm"), gpu_ate_split_cm=gpu.get("ate_rmse_split_cm"),
                   gpu_psnr=gpu.get("psnr"), gpu_peak_gpu_memory_mb=gpu.get("peak_gpu_memory_mb"),
                   gpu_frames=gpu.get("frames"), gpu_error=gpu.get("error"))
    if ref:
        out.update(ref_fps_median_concurrent=_fps(ref), ref_ate_cm=ref.get("ate_rmse_cm"),
                   ref_ate_split_cm=ref.get("ate_rmse_split_cm"), ref_psnr=ref.get("psnr"),
                   ref_peak_gpu_memory_mb=ref.get("peak_gpu_memory_mb"), ref_frames=ref.get("frames"),
                   ref_error=ref.get("error"))
    targets = {}
    if out.get("gpu_fps_median") is not None:
        targets["fps_ge_10"] = out["gpu_fps_median"] >= 10
        targets["fps_ge_30_moonshot"] = out["gpu_fps_median"] >= 30
    if out.get("gpu_ate_cm") is not None and out.get("ref_ate_cm") is not None:
        targets["ate_no_worse"] = out["gpu_ate_cm"] <= out["ref_ate_cm"]
    if out.get("gpu_ate_split_cm") is not None and out.get("ref_ate_split_cm") is not None:
        targets["ate_split_no_worse"] = out["gpu_ate_split_cm"] <= out["ref_ate_split_cm"]
    if out.get("gpu_psnr") is not None and out.get("ref_psnr") is not None:
        targets["psnr_within_1db"] = out["gpu_psnr"] >= out["ref_psnr"] - 1.0
    out["targets"] = targets
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--gpu-preset", default="gpu")
    p.add_argument("--ref-preset", default="splatam")
    p.add_argument("--sequences", default="")
    p.add_argument("--dry-run", default="0")
    args = p.parse_args()
    work, out = Path(args.work), Path(args.out)

    gpu_rows = _rows(work / "gpu_runs.jsonl")
    ref_rows = [r for f in sorted(work.glob("ref_*.jsonl")) for r in _rows(f)]
    for r in ref_rows:
        r["concurrent_with"] = "pytest -m cuda and the other reference runs (gpu.sh): s/frame not alone on the GPU"
    sequences = [s for s in args.sequences.split(",") if s] or sorted({r.get("sequence") for r in gpu_rows + ref_rows})
    by = lambda rows, seq: next((r for r in rows if r.get("sequence") == seq and "skipped" not in r), None)  # noqa: E731
    comparisons = []
    for seq in sequences:
        skipped = next((r["skipped"] for r in gpu_rows + ref_rows if r.get("sequence") == seq and "skipped" in r), None)
        row = compare(seq, by(gpu_rows, seq), by(ref_rows, seq))
        if skipped:
            row["skipped"] = skipped
        comparisons.append(row)
    slam = dict(gpu_preset=args.gpu_preset, ref_preset=args.ref_preset, dry_run_cpu=args.dry_run == "1",
                comparisons=comparisons, gpu_runs=gpu_rows, ref_runs=ref_rows)
    (out / "slam.json").write_text(json.dumps(slam, indent=1))

    stages = _rows(work / "stages.jsonl")
    render = _json(out / "render.json")
    viewer = _json(out / "viewer.json")
    pytest_cuda = _json(out / "pytest_cuda.json")
    peaks = [r.get("peak_gpu_memory_mb") for r in gpu_rows + ref_rows]
    peaks += [r.get("peak_gpu_mem_mb") for r in render or [] if isinstance(r, dict)]
    peaks += [(viewer or {}).get("peak_gpu_memory_mb")]
    peaks = [float(x) for x in peaks if x is not None]
    smi = (work / "smi.txt").read_text().strip() if (work / "smi.txt").is_file() else None
    all_targets = {f"{c['sequence']}:{k}": v for c in comparisons for k, v in c["targets"].items()}
    if viewer and viewer.get("viewer_fps_over_headless_fps") is not None:
        all_targets["viewer_ratio_ge_0.9"] = viewer["viewer_fps_over_headless_fps"] >= 0.9
    if pytest_cuda and "tests" in pytest_cuda:
        all_targets["pytest_cuda_green"] = (pytest_cuda["failures"] == 0 and pytest_cuda["errors"] == 0
                                            and pytest_cuda.get("passed", 0) > 0)
    summary = dict(
        dry_run_cpu=args.dry_run == "1", setup=_json(work / "setup.json"), nvidia_smi=smi,
        machine=(gpu_rows or ref_rows or [{}])[0].get("machine"), stages=stages,
        targets=all_targets, targets_met=bool(all_targets) and all(all_targets.values()),
        peak_gpu_memory_mb=max(peaks) if peaks else None,
        fps=[dict(sequence=c["sequence"], gpu_fps_median=c.get("gpu_fps_median")) for c in comparisons],
        pytest_cuda={k: (pytest_cuda or {}).get(k) for k in ("tests", "passed", "failures", "errors", "skipped", "error")},
        viewer=None if viewer is None else {k: viewer.get(k) for k in (
            "headless_fps", "viewer_fps", "viewer_fps_over_headless_fps", "clients_connected", "client_error")},
        render=None if render is None else [{k: r.get(k) for k in ("backend", "width", "height", "gaussians",
                                                                 "forward_ms", "forward_backward_ms")} for r in render],
        files=sorted(p.name for p in out.iterdir()) + ["summary.json"])
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(dict(targets_met=summary["targets_met"], stages=[(s["stage"], s["rc"]) for s in stages])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
