"""Which reader opens a capture: detection from the folder's (or archive's) contents.

`open_capture(path)` looks at what is there; `open_capture(path, format="tum")` skips the guess.
`FORMATS` lists every format with what it needs and how to get one (docs/formats.md quotes it).
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..errors import InputError
from .source import FrameSource


@dataclass(frozen=True)
class FormatInfo:
    name: str
    module: str
    cls: str
    needs: str  # one line: the files that identify the format
    how: str  # one line: how to capture or export it
    markers: Callable[[Path], list[tuple[str, bool]]]  # (requirement, present) for a folder

    def reader(self):
        return getattr(importlib.import_module(self.module), self.cls)


def _record3d_markers(p: Path):
    return [("metadata", (p / "metadata").is_file() or (p / "metadata.json").is_file()),
            ("rgbd/", (p / "rgbd").is_dir())]


def _stray_markers(p: Path):
    return [("rgb.mp4", (p / "rgb.mp4").is_file()), ("odometry.csv", (p / "odometry.csv").is_file()),
            ("depth/", (p / "depth").is_dir()), ("camera_matrix.csv", (p / "camera_matrix.csv").is_file())]


def _nerfcapture_markers(p: Path):
    return [("transforms.json", (p / "transforms.json").is_file()),
            ("depth/ or images/", (p / "depth").is_dir() or (p / "images").is_dir())]


def _scannetpp_markers(p: Path):
    j = Path("nerfstudio") / "transforms_undistorted.json"
    return [("dslr/nerfstudio/transforms_undistorted.json", (p / "dslr" / j).is_file() or (p / j).is_file())]


def _scannet_markers(p: Path):
    return [("color/", (p / "color").is_dir()), ("depth/", (p / "depth").is_dir()), ("pose/", (p / "pose").is_dir())]


def _replica_markers(p: Path):
    return [("results/", (p / "results").is_dir()), ("traj.txt", (p / "traj.txt").is_file())]


def _tum_markers(p: Path):
    if (p / "associations.txt").is_file():
        return [("associations.txt", True)]
    return [("rgb.txt", (p / "rgb.txt").is_file()), ("depth.txt", (p / "depth.txt").is_file())]


# Order matters: more specific layouts first (a ScanNet folder also has depth/, a Stray folder too).
FORMATS: dict[str, FormatInfo] = {f.name: f for f in [
    FormatInfo("record3d", "splat_core.io.record3d", "Record3DCapture",
               "a .r3d file, or its unzipped folder with metadata and rgbd/<i>.jpg/.depth/.conf",
               "Record3D iPhone app (LiDAR): export the recording in the app's own .r3d format (not the EXR+JPG "
               "sequence) and copy the file over",
               _record3d_markers),
    FormatInfo("strayscanner", "splat_core.io.strayscanner", "StrayScannerCapture",
               "rgb.mp4, depth/<i:06>.png (or older .npy), odometry.csv, camera_matrix.csv (confidence/ optional)",
               "Stray Scanner iPhone app (LiDAR): record, then copy the scan folder off the phone (Files app / Finder)",
               _stray_markers),
    FormatInfo("nerfcapture", "splat_core.io.nerfcapture", "NeRFCaptureCapture",
               "transforms.json with rgb/<i>.png + depth/<i>.png, or images/<i>.png + images/<i>.depth.png "
               "(uint16 depth, integer_depth_scale metres per unit); a folder or a zip",
               "NeRFCapture iPhone app in online (streaming) mode, saved by `splatam capture nerfcapture`, SplaTAM's "
               "scripts/nerfcapture2dataset.py or instant-ngp's scripts/nerfcapture2nerf.py; the app's offline "
               "export has unusable depth and is refused",
               _nerfcapture_markers),
    FormatInfo("scannetpp", "splat_core.io.scannetpp", "ScanNetPPCapture",
               "dslr/nerfstudio/transforms_undistorted.json, dslr/undistorted_images/, and dslr/undistorted_depths/ "
               "or dslr/render_depth/ with dslr/nerfstudio/transforms.json",
               "ScanNet++ DSLR download, then either SplaTAM's toolkit fork Nik-V9/scannetpp (render depth, then its "
               "dslr.undistort writes undistorted_depths/) or the official toolkit (dslr.undistort, then "
               "common.render with render_dslr: True writes fisheye render_depth/, undistorted by this reader)",
               _scannetpp_markers),
    FormatInfo("scannet", "splat_core.io.scannet", "ScanNetCapture",
               "color/<n>.jpg, depth/<n>.png (mm), pose/<n>.txt, optional intrinsic/intrinsic_color.txt",
               "ScanNet .sens file exported with ScanNet's SensReader (color, depth, pose, intrinsic); colour "
               "exported resized is fine (the sensor-size intrinsics are scaled to it)",
               _scannet_markers),
    FormatInfo("replica", "splat_core.io.replica", "ReplicaCapture",
               "results/frame*.jpg, results/depth*.png (x6553.5), traj.txt (row-major 4x4 c2w per line)",
               "Replica sequences as rendered by NICE-SLAM / iMAP (the Replica.zip used by SplaTAM)",
               _replica_markers),
    FormatInfo("tum", "splat_core.io.tum", "TUMCapture",
               "rgb.txt and depth.txt (or associations.txt), optional groundtruth.txt and camera.yaml",
               "TUM RGB-D benchmark download, or `splatam convert` output from any other format",
               _tum_markers),
]}


def format_help() -> str:
    """One compact line per format: name: what it needs."""
    return "; ".join(f"{f.name}: {f.needs}" for f in FORMATS.values())


PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".heic", ".heif")


def photos_without_depth(path: Path) -> int:
    """How many photos a folder (and its direct subfolders) holds when nothing in it is named for depth
    (0 when something is, or there are no photos)."""
    entries = list(path.iterdir())
    entries += [e for d in entries if d.is_dir() for e in d.iterdir()]
    if any("depth" in e.name.lower() for e in entries):
        return 0
    return sum(e.is_file() and e.suffix.lower() in PHOTO_SUFFIXES for e in entries)


def detect_format(path) -> str:
    """Name of the format of the capture at `path`; InputError saying what is missing otherwise."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    if path.is_file():
        if path.suffix.lower() in (".r3d", ".zip"):
            from .stores import ZipStore

            store = ZipStore(path)  # raises on a damaged archive
            if store.exists("metadata") or store.exists("metadata.json"):
                return "record3d"
            if store.exists("transforms.json"):
                return "nerfcapture"
            raise InputError(f"{path}: archive has neither Record3D's 'metadata' nor NeRFCapture's transforms.json; "
                             f"unzip other captures and pass the folder")
        raise InputError(f"{path}: a file; pass a capture folder or a Record3D .r3d file ({format_help()})")
    if not any(path.iterdir()):
        raise InputError(f"{path}: folder is empty")
    near = []
    for f in FORMATS.values():
        marks = f.markers(path)
        if all(ok for _, ok in marks):
            return f.name
        # A near miss needs one of the format's own files (a bare depth/ folder says little).
        weight = {m: (0.5 if m.endswith("/") else 1.0) for m, _ in marks}
        present = [m for m, ok in marks if ok]
        if any(not m.endswith("/") for m in present):
            score = sum(weight[m] for m in present) / sum(weight.values())
            near.append((score, f.name, [m for m, ok in marks if not ok]))
    photos = photos_without_depth(path)
    if photos:
        raise InputError(f"{path}: {photos} photo(s) but no depth found: this needs RGB-D (a depth image per frame, "
                         "e.g. from a LiDAR phone app or a depth camera)")
    if near:
        near.sort(key=lambda x: -x[0])
        _, name, missing = near[0]
        raise InputError(f"{path}: looks like a {name} capture but {', '.join(missing)} "
                         f"{'is' if len(missing) == 1 else 'are'} missing (use --format NAME to force a reader). "
                         f"Formats: {format_help()}")
    raise InputError(f"{path}: unrecognised capture. Formats: {format_help()}")


def open_capture(path, format: str | None = None, **options) -> FrameSource:
    """Open a capture folder or file as a FrameSource, detecting its format unless `format` names it.

    Options go to the reader (e.g. resolution="depth"|"color", min_confidence=1, max_dt=0.08);
    an option the reader does not take is an InputError.
    """
    path = Path(path).expanduser()
    if format is None:
        format = detect_format(path)
    else:
        format = format.lower()
        if format not in FORMATS:
            raise InputError(f"unknown format {format!r}; choose one of {', '.join(FORMATS)}")
        if not path.exists():
            raise InputError(f"{path}: no such file or folder")
    cls = FORMATS[format].reader()
    accepted = set(inspect.signature(cls.__init__).parameters) | {"resolution", "min_confidence"}
    bad = [k for k in options if k not in accepted]
    if bad:
        raise InputError(f"option(s) {', '.join(bad)} do not apply to the {format} reader")
    return cls(path, **options)
