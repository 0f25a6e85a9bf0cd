"""Export sizes: bytes per format for one map, the SPZ / PLY ratio, and what the lossy formats
lose (largest position error, after undoing SPZ's axis change); prints JSON.

    python benchmarks/export_size.py [--gaussians 100000] [--frames 4] [--map RUN_DIR|MAP_FILE]

Default map: SplaTAM's initialisation on the synthetic room (splat_core.synthetic), i.e. the
back-projected pixels of --frames views spread along the camera path, --gaussians in all, each an
isotropic Gaussian of one-pixel radius at opacity 0.5 with the pixel's colour. Then a random
perturbation of opacity (logit + N(0, 1.5)) and log-scale (+ N(0, 0.3)) so those are not all equal,
as they are not after mapping. --map measures a real run's map instead.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

from app.exports import FORMATS, EXPORT_SUFFIXES, export_map, load_arrays  # noqa: E402
from splat_core.io.compressed import spatial_order  # noqa: E402
from splat_core.io.map_files import read_map_file  # noqa: E402


def synthetic_map(n: int, frames: int, seed: int = 0) -> dict:
    from splat_core.camera import invert_pose
    from splat_core.config import DensifyConfig
    from splat_core.densify import gaussians_from_pixels
    from splat_core.synthetic import SyntheticSource

    src = SyntheticSource(n_frames=30 * frames, seed=seed)
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(frames):
        f = src[30 * k]
        valid = np.flatnonzero(f.depth.ravel() > 0)
        mask = np.zeros(f.depth.size, bool)
        mask[rng.choice(valid, min(len(valid), n // frames), replace=False)] = True
        parts.append(gaussians_from_pixels(f.color, f.depth, mask.reshape(f.depth.shape), f.intrinsics,
                                           invert_pose(f.c2w_ref), k, DensifyConfig(), True))
    m = parts[0]
    for p in parts[1:]:
        m.append(p)
    a = m.to_numpy()
    a["logit_opacities"] = (a["logit_opacities"] + rng.normal(0, 1.5, len(m))).astype(np.float32)
    a["log_scales"] = (a["log_scales"] + rng.normal(0, 0.3, a["log_scales"].shape)).astype(np.float32)
    return a


def max_position_error_mm(arrays: dict, path: Path) -> float:
    """Largest per-coordinate error (mm) of a file written in spatial order."""
    back = read_map_file(path)["means"]   # our readers undo SPZ's RUB axes
    want = np.asarray(arrays["means"], np.float32)[spatial_order(arrays["means"])]
    return float(np.abs(back - want).max() * 1e3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gaussians", type=int, default=100_000)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--map", default=None, help="measure this run folder or map file instead")
    args = ap.parse_args(argv)
    arrays = load_arrays(args.map) if args.map else synthetic_map(args.gaussians, args.frames)
    n = len(arrays["means"])
    sizes, seconds, errors = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in FORMATS:
            path = Path(tmp) / f"map{EXPORT_SUFFIXES[fmt]}"
            t0 = time.perf_counter()
            export_map(arrays, fmt, path)
            seconds[fmt] = round(time.perf_counter() - t0, 3)
            sizes[fmt] = path.stat().st_size
            if fmt in ("spz", "compressed-ply"):
                errors[fmt] = round(max_position_error_mm(arrays, path), 4)
    print(json.dumps({
        "map": args.map or f"synthetic room, {args.frames} views, SplaTAM initialisation (perturbed)",
        "gaussians": n, "bytes": sizes,
        "bytes_per_gaussian": {f: round(s / n, 2) for f, s in sizes.items()},
        "ratio_spz_to_ply": round(sizes["spz"] / sizes["ply"], 4),
        "ratio_compressed_ply_to_ply": round(sizes["compressed-ply"] / sizes["ply"], 4),
        "max_position_error_mm": errors, "write_seconds": seconds, "machine": machine(),
    }, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
