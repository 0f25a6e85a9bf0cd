"""The colour and depth cameras' focal lengths in x and y, relative to each other, from a capture's
own edges: no tracking, no reference poses (issue 44's third lens on a depth focal length).

    python benchmarks/focal_anisotropy.py --sequence 7scenes_redkitchen_600 --frames 12 --seeds 0,1,2 \
        --hypothesis 560/585

The colour-depth edge search of `splatam info --estimate-registration` (splat_core/
registration_estimate.py) with the focal ratio free per axis: the colour pixel of a depth pixel is
u_c - c = rx (u_d - c) (+ the offset's parallax), so rx = colour fx / depth fx and ry = colour fy /
depth fy, the cameras' true focal lengths whatever the camera file says. Their quotient rx / ry =
(colour fx / fy) / (depth fx / fy): with square colour pixels it is the depth camera's fy / fx. A
depth camera with fx 560 and fy 585 (issue 44's candidate) would give rx / ry = 1.045.

`--radial`: also a radial distortion k of the colour camera relative to the depth camera's (a colour
pixel at k (x^2 + y^2) further out, in normalised coordinates), searched with a shared focal ratio:
the edges see the difference of the two cameras' distortions, not what they share.

`--hypothesis FX/FY`: also the best edge agreement with rx / ry held at FY / FX (square colour
pixels, that depth camera), against the free best: how much worse the capture's edges say it is.
Every sample is `--frames` frames: the first evenly spread over the capture (or `--range A-B`), the
others drawn at random with that seed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import DATA, machine  # noqa: E402
from splat_core.io.detect import open_capture  # noqa: E402
from splat_core.registration_estimate import _grid, gather_edges, sample_frames, search  # noqa: E402

# (ratio half-range, step), (offset half-range, step), metres: around the shared-ratio search's best
STAGES = (((0.03, 0.005), (0.006, 0.002)), ((0.006, 0.001), (0.002, 0.0005)), ((0.0015, 0.00025), (0.0005, 0.00025)))


def refine(data, start: tuple[float, float, float], quotient: float | None = None) -> tuple[float, ...]:
    """(rx, ry, tx, ty) with the highest edge agreement, coarse to fine from the shared-ratio best;
    `quotient`: rx held at quotient * ry."""
    rx, tx, ty = start
    best = (rx, rx if quotient is None else rx / quotient, tx, ty)
    for (rh, rs), (th, ts) in STAGES:
        rys = _grid(best[1], rh, rs)
        rxs = _grid(best[0], rh, rs) if quotient is None else [None]
        cands = [(quotient * b if a is None else a, b, x, y) for a in rxs for b in rys
                 for x in _grid(best[2], th, ts) for y in _grid(best[3], th, ts)]
        scores = [data.score(a, x, y, ry=b) for a, b, x, y in cands]
        best = cands[int(np.argmax(scores))]
    return tuple(float(v) for v in best)


def refine_radial(data, start: tuple[float, float, float]) -> tuple[float, ...]:
    """(r, tx, ty, k) with the highest edge agreement, coarse to fine from the shared-ratio best."""
    best = (*start, 0.0)
    for ((rh, rs), (th, ts)), (kh, ks) in zip(STAGES, ((0.3, 0.05), (0.05, 0.01), (0.01, 0.0025))):
        cands = [(a, x, y, c) for a in _grid(best[0], rh, rs) for x in _grid(best[1], th, ts)
                 for y in _grid(best[2], th, ts) for c in _grid(best[3], kh, ks)]
        scores = [data.score(a, x, y, k=c) for a, x, y, c in cands]
        best = cands[int(np.argmax(scores))]
    return tuple(float(v) for v in best)


def sample(source, n: int, seed: int, lo: int, hi: int) -> list[int]:
    if seed == 0:
        return [lo + i for i in sample_frames(hi - lo, n)]
    return sorted(np.random.default_rng(seed).choice(np.arange(lo, hi), n, replace=False).tolist())


def measure(source, ids: list[int], quotient: float | None, radial: bool = False) -> dict:
    pairs = [source.raw_pair(i) for i in ids]
    depth_intr = source.intrinsics.scaled(pairs[0][1].shape[1], pairs[0][1].shape[0])
    data = gather_edges(pairs, depth_intr)
    shared = search(data)
    rx, ry, tx, ty = refine(data, shared)
    out = {"frames": ids, "shared_ratio": shared[0], "shared_score": data.score(*shared),
           "rx": rx, "ry": ry, "tx_cm": 100 * tx, "ty_cm": 100 * ty, "free_score": data.score(rx, tx, ty, ry=ry),
           "rx_over_ry": rx / ry, "depth_fx_over_fy_if_colour_square": ry / rx}
    if quotient is not None:
        hx, hy, htx, hty = refine(data, shared, quotient)
        out["hypothesis"] = {"rx": hx, "ry": hy, "score": data.score(hx, htx, hty, ry=hy)}
    if radial:
        r, tx, ty, k = refine_radial(data, shared)
        out["radial"] = {"k": k, "score": data.score(r, tx, ty, k=k),
                         "profile": {f"{c:+.1f}": data.score(r, tx, ty, k=c) for c in (-0.2, -0.1, 0.0, 0.1, 0.2)}}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sequence", required=True, help="a folder under ../shared/data, or a capture path")
    p.add_argument("--frames", type=int, default=12, help="frames per sample")
    p.add_argument("--seeds", default="0", help="samples: 0 = evenly spread, others random with that seed")
    p.add_argument("--range", default=None, help="A-B: frames A..B-1 only")
    p.add_argument("--radial", action="store_true", help="also the colour camera's radial distortion relative to depth's")
    p.add_argument("--hypothesis", default=None, help="FX/FY: a depth camera to test (square colour pixels)")
    args = p.parse_args(argv)
    source = open_capture(args.sequence if Path(args.sequence).exists() else DATA / args.sequence)
    lo, hi = (int(v) for v in args.range.split("-")) if args.range else (0, len(source))
    quotient = None
    if args.hypothesis:
        fx, fy = (float(v) for v in args.hypothesis.split("/"))
        quotient = fy / fx
    samples = [measure(source, sample(source, args.frames, int(s), lo, hi), quotient, args.radial) for s in args.seeds.split(",")]
    q = [s["rx_over_ry"] for s in samples]
    print(json.dumps({"machine": machine(), "sequence": args.sequence, "range": [lo, hi],
                      "hypothesis_rx_over_ry": quotient, "rx_over_ry_mean": float(np.mean(q)),
                      "rx_over_ry_range": [float(min(q)), float(max(q))], "samples": samples}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
