"""Two cameras (issue 43): does a capture whose colour comes from a second camera, described by its
camera file, map as well as its registered twin (the same scene and poses seen by one camera)?

    python benchmarks/two_camera_map.py [--frames 24] [--size 320x240] [--stride 4] [--slam] [--raw] [--json]

Both captures are written by splat_core/synthetic/two_cameras.py: the two-camera one (colour focal
x0.9, colour camera 2.5 cm along x, described by color_intrinsics / depth_to_color, so its colour is
registered to depth when read) and its twin (colour rendered from the depth camera). Each is mapped
with the `cpu` preset at --size: by default mapping only, at the exact poses
(tracking.use_reference_poses); --slam tracks as well. Each map is rendered at its run's poses of
every processed frame and compared with the twin's frame there (the exact colour of the depth
camera): PSNR of each map, and the difference. Also printed: each map against its own frames
(what `splatam run` reports). --raw adds a third: the two-camera frames mapped as stored, colour
not registered (a camera file that only says `depth_registered_to_rgb: false`, with
`estimate_registration: false`): what the registration buys.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import machine  # noqa: E402


def map_capture(path: Path, config) -> tuple:
    """Run the pipeline over the capture (no run folder); returns (pipeline, seconds)."""
    from splat_core.io import open_capture
    from splat_core.run import Pipeline

    pipe = Pipeline(open_capture(path), config)
    t = time.perf_counter()
    while pipe.step() is not None:
        pass
    pipe.engine.drain()
    return pipe, time.perf_counter() - t


def psnrs(pipe, truth) -> tuple[float, float]:
    """(mean PSNR against `truth`'s frames, mean PSNR against the run's own frames) at the run's poses."""
    import torch

    from splat_core import metrics as M

    against_truth, own = [], []
    w2cs = pipe.engine.trajectory()
    for k, record in enumerate(pipe.records):
        out = pipe.engine.render(w2cs[k])
        i = int(record["source_index"])
        exact = torch.as_tensor(truth[i].color, device=out.color.device)
        mine = torch.as_tensor(pipe.frame(k).color, device=out.color.device)
        against_truth.append(float(M.psnr(out.color, exact)))
        own.append(float(M.psnr(out.color, mine)))
    return float(np.mean(against_truth)), float(np.mean(own))


def compare(root: Path, frames: int, width: int, height: int, stride: int, slam: bool, overrides=None,
            raw: bool = False) -> dict:
    """Write both captures under `root`, map them and compare (module doc)."""
    from splat_core.config import load_config
    from splat_core.io import open_capture
    from splat_core.synthetic.two_cameras import COLOR_FOCAL_RATIO, DEPTH_TO_COLOR, write_two_camera_tum

    two = write_two_camera_tum(root / "two", n=frames, width=width, height=height, stride=stride)
    write_two_camera_tum(root / "twin", n=frames, width=width, height=height, stride=stride,
                         ratio=1.0, translation=[0.0, 0.0, 0.0])
    names = ["twin", "two"]
    if raw:
        write_two_camera_tum(root / "raw", n=frames, width=width, height=height, stride=stride, describe=False)
        names.append("raw")
    truth = open_capture(root / "twin")
    assert truth.two_cameras is None and open_capture(root / "two").two_cameras is not None
    settings = {"resolution": [width, height], "eval_every": 10**9, **(overrides or {})}
    if not slam:
        settings["tracking"] = {**settings.get("tracking", {}), "use_reference_poses": True}
    config = load_config("cpu", overrides=settings)
    out = {"frames": frames, "size": [width, height], "stride": stride, "slam": slam,
           "color_focal_ratio": COLOR_FOCAL_RATIO, "depth_to_color_m": list(map(float, DEPTH_TO_COLOR)),
           "depth_fx": two.depth_intr.fx}
    for name in names:
        cfg = config if name != "raw" else load_config("cpu", overrides={**settings, "estimate_registration": False})
        pipe, seconds = map_capture(root / name, cfg)
        exact, own = psnrs(pipe, truth)
        out[name] = {"psnr_vs_exact": exact, "psnr_vs_own_frames": own, "seconds": seconds,
                     "gaussians": pipe.engine.num_gaussians(), "ate_cm": pipe.ate_cm()}
        pipe.engine.close()
    out["difference_db"] = out["twin"]["psnr_vs_exact"] - out["two"]["psnr_vs_exact"]
    return out


def parse_size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--size", type=parse_size, default=(320, 240))
    ap.add_argument("--stride", type=int, default=4, help="every Nth frame of the synthetic orbit")
    ap.add_argument("--slam", action="store_true", help="track too (default: mapping at the exact poses)")
    ap.add_argument("--raw", action="store_true", help="also map the two-camera frames unregistered")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        result = compare(Path(tmp), args.frames, *args.size, args.stride, args.slam, raw=args.raw)
    result["machine"] = machine()
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    w, h = result["size"]
    print(f"{result['frames']} frames at {w}x{h}, {'SLAM' if args.slam else 'mapping at the exact poses'} (cpu preset)")
    for name, label in (("twin", "registered twin (one camera)"), ("two", "two cameras, camera file"),
                        ("raw", "two cameras, not registered")):
        if name not in result:
            continue
        r = result[name]
        ate = "" if r["ate_cm"] is None else f", ATE {r['ate_cm']:.2f} cm"
        print(f"  {label:30s} PSNR {r['psnr_vs_exact']:.2f} dB against the exact colour "
              f"({r['psnr_vs_own_frames']:.2f} against its own frames), {r['gaussians']} Gaussians, "
              f"{r['seconds']:.0f} s{ate}")
    print(f"  difference {result['difference_db']:.2f} dB (target: within 4 dB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
