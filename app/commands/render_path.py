"""`splatam render`: images of a map along a camera trajectory (TUM, c2w), for figures and videos."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from splat_core.errors import InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("map", metavar="RUN_DIR|MAP.ply", help="run folder (map.ply inside) or a 3DGS .ply")
    p.add_argument("--trajectory", required=True, help="TUM trajectory (t tx ty tz qx qy qz qw, camera-to-world)")
    p.add_argument("--out", required=True, help="folder for the images (000000.png, ...)")
    p.add_argument("--mode", choices=["color", "depth", "silhouette"], default="color")
    p.add_argument("--width", type=int, default=None, help="image width (default: the run's, else 640)")
    p.add_argument("--height", type=int, default=None, help="image height (default: the run's, else 480)")
    p.add_argument("--fx", type=float, default=None, help="focal length in pixels (default: the run's, else 60 deg hfov)")
    p.add_argument("--fy", type=float, default=None)
    p.add_argument("--cx", type=float, default=None)
    p.add_argument("--cy", type=float, default=None)
    p.add_argument("--depth-max", type=float, default=None, help="depth colouring range in metres (default: auto)")
    p.add_argument("--background", type=float, default=0.0, help="background grey level in [0, 1]")
    p.add_argument("--backend", default="auto", choices=["auto", "cpu", "cuda", "reference"])


def resolve_intrinsics(args, run: Path):
    """Flags override the run's recorded intrinsics; without either, 640x480 with a 60 deg hfov."""
    from app.browse import intrinsics_from_run
    from splat_core.camera import Intrinsics

    base = intrinsics_from_run(run) if run.is_dir() else None
    width = args.width or (base.width if base else 640)
    height = args.height or (base.height if base else 480)
    if base and (width, height) != (base.width, base.height):
        base = base.scaled(width, height)
    fx = args.fx or (base.fx if base else 0.5 * width / np.tan(np.deg2rad(30.0)))
    fy = args.fy or (base.fy if base and not args.fx else fx)
    cx = args.cx if args.cx is not None else (base.cx if base else (width - 1) / 2.0)
    cy = args.cy if args.cy is not None else (base.cy if base else (height - 1) / 2.0)
    return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height))


def main(args) -> int:
    import cv2
    import torch

    from app.browse import near_plane_of, read_map
    from app.images import colorize_depth, colorize_silhouette, to_uint8
    from splat_core.camera import invert_pose
    from splat_core.gaussians import Gaussians
    from splat_core.io.map_files import map_path_of
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.render import Renderer

    run = Path(args.map)
    arrays = read_map(map_path_of(run))
    _, c2ws = read_tum_trajectory(args.trajectory)
    if len(c2ws) == 0:
        raise InputError(f"{args.trajectory}: no poses")
    intr = resolve_intrinsics(args, run)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: expected a folder")
    out.mkdir(parents=True, exist_ok=True)
    device = "cuda" if args.backend in ("auto", "cuda") and torch.cuda.is_available() else "cpu"
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    g = Gaussians(t(arrays["means"]), t(arrays["colors"]), t(arrays["rotations"]),
                  t(arrays["logit_opacities"]), t(arrays["log_scales"]))
    depth_max = args.depth_max
    renderer = Renderer(near_plane_of(run), args.backend)
    for i, c2w in enumerate(c2ws):
        with torch.no_grad():
            r = renderer.render(g, intr, t(invert_pose(c2w)), background=args.background)
        if args.mode == "color":
            img = to_uint8(r.color.cpu().numpy())
        elif args.mode == "depth":
            depth = r.depth.cpu().numpy()
            if depth_max is None:   # one range for the whole path, so a video does not flicker
                valid = depth[depth > 0]
                depth_max = float(np.percentile(valid, 99)) if valid.size else 1.0
            img = colorize_depth(depth, depth_max)
        else:
            img = colorize_silhouette(r.alpha.cpu().numpy())
        path = out / f"{i:06d}.png"
        if not cv2.imwrite(str(path), img[..., ::-1]):
            raise InputError(f"{path}: could not write the image")
    print(f"rendered {len(c2ws)} {args.mode} images of {intr.width}x{intr.height} into {out}")
    return 0
