"""A copy of a capture under ../shared/data whose camera file gives the depth camera other focal
lengths (issue 44: "is the depth focal length the error?"): the images and references are symbolic
links, `camera.yaml` / `camera.json` are rewritten with FX and FY, nothing else changes.

    python benchmarks/capture_with_focal.py --sequence 7scenes_redkitchen_600 --fx 560 --fy 585 --out SCRATCH/cap600_560
    splatam run --input SCRATCH/cap600_560 --out RUN --config cpu
    python benchmarks/three_lenses.py --run RUN --sequence cap600_560 --data SCRATCH --pairs 0
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import DATA  # noqa: E402


def copy_with_focal(src: Path, out: Path, fx: float, fy: float) -> Path:
    out.mkdir(parents=True, exist_ok=False)
    for item in src.iterdir():
        if item.name not in ("camera.yaml", "camera.json"):
            (out / item.name).symlink_to(item.resolve())
    if (src / "camera.yaml").exists():
        text = (src / "camera.yaml").read_text()
        for key, value in (("fx", fx), ("fy", fy)):
            text, n = re.subn(rf"(?m)^{key}:.*$", f"{key}: {value!r}", text)
            if n != 1:
                raise SystemExit(f"{src / 'camera.yaml'}: expected one top-level '{key}:' line, found {n}")
        (out / "camera.yaml").write_text(text)
    if (src / "camera.json").exists():
        cam = json.loads((src / "camera.json").read_text())
        cam["fx"], cam["fy"] = fx, fy
        (out / "camera.json").write_text(json.dumps(cam, indent=1))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sequence", required=True)
    p.add_argument("--fx", type=float, required=True)
    p.add_argument("--fy", type=float, required=True)
    p.add_argument("--out", required=True, type=Path)
    args = p.parse_args(argv)
    print(copy_with_focal(DATA / args.sequence, args.out, args.fx, args.fy))
    return 0


if __name__ == "__main__":
    sys.exit(main())
