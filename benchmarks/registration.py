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
3. For each --also sequence: the estimate and whether it says "already registered". A capture
   registered by its writer (`registered_by_writer`: its camera file says so, or its format) is
   not estimated by `splatam info`; the search is run here anyway, to show what it finds there.
4. --motion SEQ (a TUM-layout capture with associations.txt and groundtruth.txt): is what the
   search finds the motion between colour and depth exposures? Per frame, the edge agreement with
   the depth points moved by the reference poses' motion over dt before the colour stamp
   (dt from -20 to +60 ms; the stamps' own difference marked), and the search's best before and
   after moving them by the best dt.
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


def estimate_anyway(path: Path) -> dict:
    """`estimate`, noting a capture registered by its writer (which `splatam info` does not estimate)."""
    from splat_core.io import open_capture
    from splat_core.registration_estimate import registered_by_writer

    out = estimate(path)
    out["registered_by"] = registered_by_writer(open_capture(path))
    return out


def motion_check(path: Path) -> list[dict]:
    """Section 4 of the module doc, one dict per frame."""
    from splat_core.camera import invert_pose
    from splat_core.io import open_capture
    from splat_core.io.trajectory import parse_tum_lines, read_tum_trajectory
    from splat_core.io.tum import interpolate_pose
    from splat_core.registration_estimate import gather_edges, search

    source = open_capture(path)
    stamps = [(float(f[0]), float(f[2])) for _, f in parse_tum_lines(path / "associations.txt", 4)]
    gt_t, gt_T = read_tum_trajectory(path / "groundtruth.txt")
    order = np.argsort(gt_t)
    gt_t, gt_T = gt_t[order], gt_T[order]
    rows = []
    for i, (t_rgb, t_depth) in enumerate(stamps[: len(source)]):
        data = gather_edges([source.raw_pair(i)], source.intrinsics)
        points = data.points.copy()
        c2w_rgb = interpolate_pose(gt_t, gt_T, t_rgb, 0.02)

        def moved(dt):   # depth points as the colour camera would see them dt after the depth exposure
            rel = invert_pose(c2w_rgb) @ interpolate_pose(gt_t, gt_T, t_rgb - dt, 0.02)
            data.points = points @ rel[:3, :3].T + rel[:3, 3]
            return data

        scan = {round(1000 * dt): moved(dt).score(1.0, 0.0, 0.0) for dt in np.arange(-0.020, 0.0605, 0.005)}
        best_dt = max(scan, key=scan.get) / 1000
        stamp_dt = t_rgb - t_depth
        at_stamps = moved(stamp_dt).score(1.0, 0.0, 0.0)
        data.points = points
        found = search(data)
        found_moved = search(moved(best_dt))
        rows.append({"frame": i, "stamp_dt_ms": 1000 * stamp_dt, "scan": scan, "best_dt_ms": 1000 * best_dt,
                     "as_stored": scan[0], "moved_by_stamp_dt": at_stamps, "moved_by_best_dt": scan[round(1000 * best_dt)],
                     "search_as_stored": found, "search_after_moving": found_moved})
        data.points = points
        rows[-1]["search_as_stored_score"] = data.score(*found)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="7scenes_redkitchen_300")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--also", default="sun3d_3dmatch_fragment1,tum_fr1_xyz_pair")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--motion", default=None, metavar="SEQ", help="only section 4 on this TUM-layout sequence")
    args = ap.parse_args(argv)
    if args.motion:
        rows = motion_check(DATA / args.motion)
        if args.json:
            print(json.dumps(rows, indent=2))
            return 0
        for r in rows:
            (r0, x0, y0), (r1, x1, y1) = r["search_as_stored"], r["search_after_moving"]
            print(f"frame {r['frame']}: colour stamp {r['stamp_dt_ms']:.1f} ms after depth; edge agreement as stored "
                  f"{r['as_stored']:.2f}, depth moved by the reference motion over the stamps' dt {r['moved_by_stamp_dt']:.2f}, "
                  f"over the best dt ({r['best_dt_ms']:.0f} ms) {r['moved_by_best_dt']:.2f}; the search finds "
                  f"x{r0:.3f} tx {100 * x0:+.2f} ty {100 * y0:+.2f} cm ({r['search_as_stored_score']:.2f}) as stored, "
                  f"x{r1:.3f} tx {100 * x1:+.2f} ty {100 * y1:+.2f} cm after moving")
            print("   scan (ms: agreement) " + " ".join(f"{k}:{v:.2f}" for k, v in r["scan"].items()))
        return 0
    from splat_core.io import open_capture
    from splat_core.registration_estimate import edge_agreement

    path = DATA / args.sequence
    source = open_capture(path)
    w, h = source.raw_pair(0)[1].shape[::-1]
    result = {"registration": time_registration(source, literature_cameras(w, h), args.frames, args.repeat),
              "estimates": [estimate_anyway(path)] + [estimate_anyway(DATA / s) for s in args.also.split(",") if s]}
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
              + (f" (searched anyway: registered by its writer, {e['registered_by']}; not estimated by splatam info)"
                 if e["registered_by"] else "")
              + f"; edge agreement as stored {e['edge_agreement_as_stored']:.2f}"
              + (f", with the estimate {e['edge_agreement_estimate']:.2f}" if "edge_agreement_estimate" in e else ""))
    print(f"{args.sequence} with the literature calibration (525, {LITERATURE['translation']}): edge agreement "
          f"{result['edge_agreement_literature']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
