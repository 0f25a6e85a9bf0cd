"""The working resolution: what a preset's `resolution` means on a capture of a given shape.

    resolution: null          the capture's own size
    resolution: 320           a long side: 320x240 on a 4:3 landscape capture, 240x320 on portrait
    resolution: [320, 240]    a pixel budget of 320 x 240 pixels in the capture's aspect ratio:
                              exactly 320x240 on 4:3 landscape, 240x320 on 3:4 portrait,
                              368x209 on Replica's 1200x680

The aspect ratio is always the capture's (never stretched) and the working size is never larger
than the capture. "The capture's size" is its colour size, but at most `depth_upsampling` times
its depth grid where depth is smaller than colour (phones: LiDAR depth 256x192 beside colour
1920x1440; ScanNet: 640x480 beside 1296x968): 1 keeps the map at the depth grid.
"""

from __future__ import annotations

import math
import re

from ..errors import InputError


def parse_resolution(text: str, where: str = "--resolution"):
    """The CLI's `native`, `L` (a long side) or `WxH` (a pixel budget) as a config value."""
    text = str(text).strip().lower()
    if text == "native":
        return None
    if re.fullmatch(r"\d+", text) and int(text) > 0:
        return int(text)
    m = re.fullmatch(r"(\d+)x(\d+)", text)
    if m and int(m[1]) > 0 and int(m[2]) > 0:
        return [int(m[1]), int(m[2])]
    raise InputError(f"{where} {text}: expected native, a long side L (e.g. 320) or a size WxH (e.g. 320x240)")


def describe_resolution(spec) -> str:
    if spec is None:
        return "native"
    if isinstance(spec, int):
        return f"long side {spec}"
    return f"{spec[0]}x{spec[1]} pixels"


def capture_size(color_size, depth_size=None, depth_upsampling: float | None = 1.0) -> tuple[int, int]:
    """The largest working size worth having: the colour size, at most `depth_upsampling` x the
    depth grid (None: no limit)."""
    cw, ch = color_size
    dw, dh = depth_size or color_size
    if depth_upsampling is None or dw * depth_upsampling >= cw:
        return int(cw), int(ch)
    s = depth_upsampling * dw / cw
    return max(1, round(cw * s)), max(1, round(ch * s))


def working_size(spec, width: int, height: int) -> tuple[int, int]:
    """(width, height) for `resolution: spec` on a width x height capture (see the module doc)."""
    if spec is None:
        return int(width), int(height)
    if isinstance(spec, int):
        s = spec / max(width, height)
    else:
        bw, bh = (int(v) for v in spec)
        if width * bh == height * bw:              # same aspect: exactly the preset's size
            return (bw, bh) if bw * bh < width * height else (int(width), int(height))
        if width * bw == height * bh:              # the same aspect turned (portrait)
            return (bh, bw) if bw * bh < width * height else (int(width), int(height))
        s = math.sqrt(bw * bh / (width * height))
    if s >= 1:
        return int(width), int(height)
    return max(1, round(width * s)), max(1, round(height * s))


def source_sizes(source) -> tuple[tuple[int, int], tuple[int, int]]:
    """(colour size, depth grid size) of a FrameSource: readers with colour and depth of different
    sizes say so (`color_size`, `depth_size`); others give frames on one grid."""
    intr = source.intrinsics
    color = tuple(getattr(source, "color_size", None) or (intr.width, intr.height))
    return color, tuple(getattr(source, "depth_size", None) or color)


def source_working_size(source, config) -> tuple[int, int]:
    """The working size of `config` on `source`."""
    color, depth = source_sizes(source)
    return working_size(config.resolution, *capture_size(color, depth, config.depth_upsampling))
