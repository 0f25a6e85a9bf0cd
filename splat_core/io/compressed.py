"""Compact Gaussian map files, encoded by gsply (MIT): Niantic's SPZ and the PlayCanvas /
SuperSplat compressed PLY. Arrays follow `GaussianMap.to_numpy()` as in ply.py.

Axes. Our map lives in OpenCV-style world axes: x right, y down, z forward (RDF). SPZ's
coordinate system is right-up-back (RUB), so `write_spz` converts on write: positions become
(x, -y, -z) and rotations (w, x, y, z) -> (w, x, -y, -z), i.e. R -> F R F with F = diag(1, -1, -1).
`read_spz` converts back. The compressed PLY has no declared axes and, like a 3DGS .ply (and our
map.ply), keeps ours.

Order. Both writers store the Gaussians in k-d tree order (`spatial_order`): the compressed PLY
quantises positions relative to the box of each chunk of 256 consecutive Gaussians, so chunks
must be compact (PlayCanvas's compressor sorts along a Morton curve for the same reason; on our
synthetic map that left chunks metres tall and errors of 1.4 mm, the k-d order 0.8 mm), and
SPZ's gzip gains from neighbours sharing their high position bytes. Readers return file order.

gsply writes the coordinates it is given (no axis conversion of its own). Its kernels use
Numba's parallel runtime, so every call runs inside splat_core.parallel.numba_lock().

Precision. SPZ: positions 24-bit fixed point with 10 fractional bits (1/1024 m steps: at most
0.49 mm off per coordinate, 0.85 mm in 3D; |coordinate| < 8192 m). Niantic's default is 12, but
positions are most of an SPZ file and those two bits per axis cost 1.35 B per Gaussian after
gzip (our 7-Scenes map: 9.6 -> 8.3 B, against 68 B in a 3DGS PLY). Colour and opacity 8 bits,
log-scales in 1/16 steps, clamped to [-10, 5.9] (scales 45 um .. 380 m). Compressed PLY: positions 11/10/11 bits of each chunk's box,
colour 8 bits of each chunk's range, opacity 8 bits, rotations 2 + 3 x 10 bits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..parallel import numba_lock
from .atomic import atomic_path, write_bytes_atomic
from .ply import SH_C0, checked_arrays, collapse_isotropic, normalised_quaternions

SPZ_FRACTIONAL_BITS = 10
SPZ_MAX_COORDINATE = (1 << 23) / (1 << SPZ_FRACTIONAL_BITS)   # 8192 m
RDF_TO_RUB = np.array([1.0, -1.0, -1.0], np.float32)           # its own inverse
CHUNK = 256                                                    # Gaussians per compressed-PLY chunk


def spatial_order(means: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """Indices that put `means` (N x 3) in k-d tree order: split recursively along the longest
    axis at a multiple of `chunk`, so each run of `chunk` consecutive Gaussians (and the one
    shorter run, last) is a compact box."""
    p = np.asarray(means, np.float64).reshape(-1, 3)
    runs, stack = [], [np.arange(len(p))]
    while stack:
        idx = stack.pop()
        if len(idx) <= chunk:
            runs.append(idx)
            continue
        pts = p[idx]
        axis = int(np.ptp(pts, axis=0).argmax())
        half = ((len(idx) // chunk + 1) // 2) * chunk     # 0 < half < len(idx)
        part = np.argpartition(pts[:, axis], half)
        stack += [idx[part[half:]], idx[part[:half]]]     # left half first
    return np.concatenate(runs) if runs else np.zeros(0, np.int64)


def _gsdata(arrays: dict, axes: np.ndarray | None = None):
    """gsply's GSData (PLY conventions: log-scales, logit opacities, SH DC) in spatial order."""
    import gsply

    a = checked_arrays(arrays)
    order = spatial_order(a["means"])
    means = a["means"][order]
    quats = normalised_quaternions(a["rotations"][order]).astype(np.float32)
    if axes is not None:
        means = means * axes
        quats[:, 1:] *= axes
    sh0 = ((a["colors"][order] - 0.5) / SH_C0).astype(np.float32)
    return gsply.GSData.from_arrays(
        means=np.ascontiguousarray(means), scales=np.ascontiguousarray(a["log_scales"][order]),
        quats=quats, opacities=np.ascontiguousarray(a["logit_opacities"][order]), sh0=sh0,
        format="ply")


def _arrays(data, axes: np.ndarray | None = None) -> dict[str, np.ndarray]:
    means = np.asarray(data.means, np.float32).copy()
    quats = np.asarray(data.quats, np.float32).copy()
    if axes is not None:
        means *= axes
        quats[:, 1:] *= axes
    n = len(means)
    return dict(
        means=means,
        colors=(0.5 + SH_C0 * np.asarray(data.sh0, np.float32)).astype(np.float32),
        rotations=quats,
        logit_opacities=np.asarray(data.opacities, np.float32).reshape(n).copy(),
        log_scales=collapse_isotropic(np.asarray(data.scales, np.float32).reshape(n, 3)),
        birth_frame=np.zeros(n, np.int64),
    )


# ----------------------------------------------------------------------------- SPZ

def write_spz(path, arrays: dict) -> Path:
    """Write Niantic SPZ (v3, gzip) atomically, converting our RDF axes to SPZ's RUB."""
    import gsply

    means = np.asarray(arrays["means"], np.float64).reshape(-1, 3)
    if len(means) and np.abs(means).max() >= SPZ_MAX_COORDINATE:
        raise InputError(f"{path}: the map reaches {np.abs(means).max():.0f} m from the origin; SPZ "
                         f"({SPZ_FRACTIONAL_BITS} fractional bits) holds |x| < {SPZ_MAX_COORDINATE:.0f} m")
    data = _gsdata(arrays, RDF_TO_RUB)
    with atomic_path(path) as tmp, numba_lock():
        gsply.write_spz(tmp, data, version=3, fractional_bits=SPZ_FRACTIONAL_BITS)
    return Path(path)


def read_spz(path) -> dict[str, np.ndarray]:
    """Read an SPZ file into Gaussian arrays in our RDF axes (undoing SPZ's RUB)."""
    import gsply

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such SPZ file")
    try:
        with numba_lock():
            data = gsply.read_spz(path)
    except ValueError as e:
        raise InputError(f"{path}: not a readable SPZ file ({str(e).removesuffix(f': {path}')})") from None
    return _arrays(data, RDF_TO_RUB)


# ----------------------------------------------------------------------------- compressed PLY

def compressed_ply_bytes(arrays: dict) -> bytes:
    import gsply

    data = _gsdata(arrays)
    with numba_lock():
        return gsply.compress_to_bytes(data)


def write_compressed_ply(path, arrays: dict) -> Path:
    """Write the PlayCanvas / SuperSplat compressed PLY (chunked, ~16 B per Gaussian) atomically."""
    return write_bytes_atomic(path, compressed_ply_bytes(arrays))


def is_compressed_ply(path) -> bool:
    """True when `path` is a PLY whose header declares the compressed layout's `chunk` element."""
    with open(path, "rb") as f:
        head = f.read(4096)
    end = head.find(b"end_header")
    return head.startswith(b"ply") and b"\nelement chunk " in head[: end if end >= 0 else None]


def read_compressed_ply(path) -> dict[str, np.ndarray]:
    import gsply

    path = Path(path)
    raw = path.read_bytes()
    try:
        with numba_lock():
            data = gsply.decompress_from_bytes(raw)
    except (ValueError, KeyError, IndexError) as e:
        raise InputError(f"{path}: not a readable compressed PLY ({e})") from None
    return _arrays(data)
