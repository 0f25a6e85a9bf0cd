"""`splatam convert --input PATH --out DIR [--format NAME] [--force]`: any supported capture to the
TUM RGB-D layout (rgb/*.png, depth/*.png 16-bit with depth_scale 5000, rgb.txt, depth.txt,
associations.txt, groundtruth.txt c2w OpenCV in the capture's own world, camera.yaml).

The output is written to a temporary folder beside --out and renamed into place at the end, so
an interrupted conversion never leaves a half-written folder under the requested name.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

DEPTH_SCALE = 5000.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--input", required=True, help="capture folder or Record3D .r3d file")
    p.add_argument("--out", required=True, help="output folder (TUM layout)")
    p.add_argument("--format", default=None, help="reader to use instead of detecting")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out")
    p.add_argument("--resolution", choices=("depth", "color"), default="depth",
                   help="phone captures: shrink colour to the depth size (default) or enlarge depth")
    p.add_argument("--min-confidence", type=int, default=None,
                   help="phone captures: keep depth with confidence >= this (0 low, 1 medium, 2 high; default 2)")


def write_tum(source, out_dir: Path, progress=None) -> dict:
    """Write every frame of `source` into `out_dir` (which must exist and be empty)."""
    import yaml

    from splat_core.io.images import write_color_png, write_depth_png
    from splat_core.io.atomic import write_text_atomic
    from splat_core.io.trajectory import format_tum_line

    (out_dir / "rgb").mkdir()
    (out_dir / "depth").mkdir()
    rgb_lines, depth_lines, assoc_lines, gt_lines = [], [], [], []
    n_clipped = 0
    for i in range(len(source)):
        f = source[i]
        t = f"{f.timestamp:.6f}"
        rgb_rel, depth_rel = f"rgb/{i:06d}.png", f"depth/{i:06d}.png"
        write_color_png(out_dir / rgb_rel, f.color)
        n_clipped += write_depth_png(out_dir / depth_rel, f.depth, DEPTH_SCALE)
        rgb_lines.append(f"{t} {rgb_rel}")
        depth_lines.append(f"{t} {depth_rel}")
        assoc_lines.append(f"{t} {rgb_rel} {t} {depth_rel}")
        if f.c2w_ref is not None:
            gt_lines.append(format_tum_line(f.timestamp, f.c2w_ref))
        if progress:
            progress(i + 1, len(source))
    origin = f"converted by splatam convert from {source.format_name} capture {source.path}"
    write_text_atomic(out_dir / "rgb.txt", f"# color images\n# {origin}\n# timestamp filename\n"
                      + "\n".join(rgb_lines) + "\n")
    write_text_atomic(out_dir / "depth.txt", f"# depth maps\n# {origin}\n# timestamp filename\n"
                      + "\n".join(depth_lines) + "\n")
    write_text_atomic(out_dir / "associations.txt", "\n".join(assoc_lines) + "\n")
    if gt_lines:
        write_text_atomic(out_dir / "groundtruth.txt",
                          f"# ground truth trajectory (camera-to-world, OpenCV camera axes)\n# {origin}\n"
                          "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt_lines) + "\n")
    intr = source.intrinsics
    cam = dict(fx=float(intr.fx), fy=float(intr.fy), cx=float(intr.cx), cy=float(intr.cy),
               width=int(intr.width), height=int(intr.height), depth_scale=DEPTH_SCALE,
               depth_unit="uint16, metres*5000; 0 = invalid", source=origin,
               source_format=source.format_name)
    # What the source says about colour and depth, kept (docs/formats.md, Two cameras): frames of a
    # two-camera capture were registered when read; a source that says nothing still says nothing.
    if getattr(source, "two_cameras", None) is not None or getattr(source, "registered_by", None):
        cam["depth_registered_to_rgb"] = True
    elif not source.registered:
        cam["depth_registered_to_rgb"] = False
    write_text_atomic(out_dir / "camera.yaml", yaml.safe_dump(cam, sort_keys=False))
    return dict(frames=len(source), poses=len(gt_lines), depth_out_of_range_pixels=n_clipped)


def convert(input_path, out_dir, format=None, force=False, progress=None, **options) -> dict:
    from splat_core.errors import InputError
    from splat_core.io import open_capture

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not force:
        raise InputError(f"{out_dir}: folder exists and is not empty (use --force to replace it)")
    source = open_capture(input_path, format=format, **options)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".partial", dir=out_dir.parent))
    try:
        summary = write_tum(source, tmp, progress)
        if out_dir.exists():
            old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
            os.replace(out_dir, old)
            os.replace(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    summary["warnings"] = list(getattr(source, "warnings", []))
    summary["format"] = source.format_name
    return summary


def main(args) -> int:
    def progress(i, n):
        if sys.stderr.isatty() and (i == n or i % 25 == 0):
            print(f"\rconverting {i}/{n}", end="\n" if i == n else "", file=sys.stderr, flush=True)

    summary = convert(args.input, args.out, format=args.format, force=args.force, progress=progress,
                      resolution=args.resolution, min_confidence=args.min_confidence)
    print(f"wrote {summary['frames']} frames ({summary['poses']} with reference poses) from the "
          f"{summary['format']} capture to {args.out} (TUM layout, depth_scale {DEPTH_SCALE:g})")
    if summary["depth_out_of_range_pixels"]:
        print(f"warning: {summary['depth_out_of_range_pixels']} depth pixels beyond "
              f"{65534 / DEPTH_SCALE:.2f} m written as invalid", file=sys.stderr)
    for w in summary["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    return 0
