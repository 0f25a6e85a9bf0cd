"""Two cameras (issue 43): the cost of registering colour to depth at load, and the colour camera
estimated from a capture's own edges against the literature's.

    python benchmarks/registration.py [--sequence 7scenes_redkitchen_300] [--repeat 20] [--json]
                                      [--also sun3d_3dmatch_fragment1,tum_fr1_xyz_pair]

1. Registration time: `register_frame` on --frames frames of the sequence at their own size (640x480
   for 7-Scenes) with the literature's Kinect v1 colour camera (focal 525, depth_to_color
   (-0.0254, -0.00013, -0.00218) m), each --repeat times after one warm-up call (Numba compile);
   median ms per frame, and the share of valid depth made invalid (unseen by the colour camera).
2. Estimation (`estimate_registration`, ~10 frames): seconds, focal and offset found, and the edge
   agreement of the frames as yielded with no registration, with the estimate and with the
   literature calibration (10 frames each, `edge_agreement`).
3. For each --also sequence: the estimate and whether it says "already registered".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT.parent / "shared" / "data"
LITERATURE = dict(focal=525.0, translation=(-0.0254, -0.00013, -0.00218))


def literature_cameras(width: int, height: int):
    from splat_core.camera import Intrinsics
    from splat_core.registration import TwoCameras

    return TwoCameras(Intrinsics(LITERATURE["focal"], LITERATURE["focal"], 320.0, 240.0, 640, 480).scaled(width, height),
                      None, np.array(LITERATURE["translation"]))


def time_registration(source, cams, frames: int, repeat: int) -> dict:
    from splat_core.registration import register_frame

    times, dropped = [], []
    ids = np.linspace(0, len(source) - 1, frames).round().astype(int)
    for i in ids:
        color, depth = source.raw_pair(int(i))
        intr = source.intrinsics.scaled(depth.shape[1], depth.shape[0])
        register_frame(color, depth, intr, cams)   # warm-up (compile on the first)
        for _ in range(repeat):
            t = time.perf_counter()
            _, d = register_frame(color, depth, intr, cams)
            times.append(time.perf_counter() - t)
        dropped.append(1 - (d > 0).sum() / max(1, (depth > 0).sum()))
    return {"size": [int(depth.shape[1]), int(depth.shape[0])], "median_ms": 1000 * float(np.median(times)),
            "p90_ms": 1000 * float(np.quantile(times, 0.9)), "calls": len(times),
            "valid_depth_made_invalid": float(np.mean(dropped))}


def estimate(path: Path) -> dict:
    from splat_core.io import open_capture
    from splat_core.registration_estimate import edge_agreement, estimate_registration

    source = open_capture(path)
    t = time.perf_counter()
    e = estimate_registration(source)
    seconds = time.perf_counter() - t
    out = {"sequence": path.name, "seconds": seconds, "focal_ratio": e.focal_ratio, "color_fx": e.cameras.color.fx,
           "translation_m": list(e.translation), "shift_px": e.shift_px, "already_registered": e.registered,
           "edge_agreement_as_stored": edge_agreement(source)}
    if not e.registered:
        source.use_two_cameras(e.cameras)
        out["edge_agreement_estimate"] = edge_agreement(source)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="7scenes_redkitchen_300")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--also", default="sun3d_3dmatch_fragment1,tum_fr1_xyz_pair")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from splat_core.io import open_capture
    from splat_core.registration_estimate import edge_agreement

    path = DATA / args.sequence
    source = open_capture(path)
    w, h = source.raw_pair(0)[1].shape[::-1]
    result = {"registration": time_registration(source, literature_cameras(w, h), args.frames, args.repeat),
              "estimates": [estimate(path)] + [estimate(DATA / s) for s in args.also.split(",") if s]}
    lit = open_capture(path)
    lit.use_two_cameras(literature_cameras(w, h))
    result["edge_agreement_literature"] = edge_agreement(lit)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    r = result["registration"]
    print(f"registration {r['size'][0]}x{r['size'][1]}: median {r['median_ms']:.1f} ms/frame (p90 {r['p90_ms']:.1f}, "
          f"{r['calls']} calls); {r['valid_depth_made_invalid'] * 100:.2f}% of valid depth unseen by colour")
    for e in result["estimates"]:
        tx, ty, _ = e["translation_m"]
        print(f"{e['sequence']}: {e['seconds']:.1f} s, focal x{e['focal_ratio']:.3f} (fx {e['color_fx']:.1f}), "
              f"tx {tx * 100:+.2f} cm, ty {ty * 100:+.2f} cm, shift {e['shift_px']:.1f} px -> "
              + ("already registered" if e["already_registered"] else "not registered")
              + f"; edge agreement as stored {e['edge_agreement_as_stored']:.2f}"
              + (f", with the estimate {e['edge_agreement_estimate']:.2f}" if "edge_agreement_estimate" in e else ""))
    print(f"{args.sequence} with the literature calibration (525, {LITERATURE['translation']}): edge agreement "
          f"{result['edge_agreement_literature']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
