"""3D Gaussian maps as files other tools read: the 3DGS `.ply` and the antimatter15 `.splat`.

Arrays follow `GaussianMap.to_numpy()` (raw, pre-activation parameters):
    means N x 3, colors N x 3 (RGB), rotations N x 4 (w, x, y, z, unnormalised),
    logit_opacities N, log_scales N x 1 (isotropic) or N x 3, birth_frame N (optional).

3DGS PLY (docs/formats.md, "Files written"): one `vertex` element, float32, binary little
endian, properties `x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0
rot_1 rot_2 rot_3`, with f_dc = (rgb - 0.5) / C0 so that a viewer's 0.5 + C0 * f_dc gives the
colour back, `opacity` the logit and `scale_*` natural-log scales (isotropic tiled x3).

.splat: 32 bytes per Gaussian, no header: position 3 x f32, linear scale 3 x f32, RGBA 4 x u8
(alpha = sigmoid(opacity) * 255), rotation 4 x u8 = normalised (w, x, y, z) * 128 + 128, sorted
by descending scale-volume x opacity (what web viewers expect to stream front-loaded).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import write_bytes_atomic

SH_C0 = 0.28209479177387814  # degree-0 spherical-harmonic basis constant

PLY_PROPERTIES = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
)

SPLAT_DTYPE = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)),
                        ("rgba", "u1", (4,)), ("rotation", "u1", (4,))])
assert SPLAT_DTYPE.itemsize == 32

# PLY scalar type names (both spellings) -> numpy little-endian type codes.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}


# ----------------------------------------------------------------------------- helpers

def checked_arrays(arrays: dict) -> dict[str, np.ndarray]:
    """The five parameter arrays as float32 with consistent N, log_scales as N x 3."""
    try:
        means = np.asarray(arrays["means"], dtype=np.float32).reshape(-1, 3)
        n = means.shape[0]
        colors = np.asarray(arrays["colors"], dtype=np.float32).reshape(n, 3)
        rotations = np.asarray(arrays["rotations"], dtype=np.float32).reshape(n, 4)
        logits = np.asarray(arrays["logit_opacities"], dtype=np.float32).reshape(n)
        log_scales = np.asarray(arrays["log_scales"], dtype=np.float32).reshape(n, -1)
    except KeyError as e:
        raise ValueError(f"Gaussian arrays lack {e.args[0]!r}") from None
    if log_scales.shape[1] == 1:
        log_scales = np.repeat(log_scales, 3, axis=1)
    elif log_scales.shape[1] != 3:
        raise ValueError(f"log_scales must be N x 1 or N x 3, got {log_scales.shape}")
    return dict(means=means, colors=colors, rotations=rotations, logit_opacities=logits,
                log_scales=log_scales)


def collapse_isotropic(log_scales: np.ndarray) -> np.ndarray:
    """N x 3 log-scales as N x 1 when all three columns are equal (isotropic), else unchanged."""
    if np.array_equal(log_scales[:, 0], log_scales[:, 1]) and np.array_equal(log_scales[:, 0],
                                                                              log_scales[:, 2]):
        return log_scales[:, :1].copy()
    return log_scales


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, dtype=np.float64)))


def normalised_quaternions(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    out = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    return out


# ----------------------------------------------------------------------------- PLY

def ply_bytes(arrays: dict) -> bytes:
    """The 3DGS binary PLY of `arrays` as bytes (for downloads); `write_ply` writes the same."""
    header, body = _ply_parts(arrays)
    return header + body


def _ply_parts(arrays: dict) -> tuple[bytes, bytes]:
    a = checked_arrays(arrays)
    n = a["means"].shape[0]
    table = np.zeros(n, dtype=np.dtype([(name, "<f4") for name in PLY_PROPERTIES]))
    for i, axis in enumerate("xyz"):
        table[axis] = a["means"][:, i]
    f_dc = (a["colors"] - 0.5) / SH_C0
    for i in range(3):
        table[f"f_dc_{i}"] = f_dc[:, i]
        table[f"scale_{i}"] = a["log_scales"][:, i]
    table["opacity"] = a["logit_opacities"]
    for i in range(4):
        table[f"rot_{i}"] = a["rotations"][:, i]
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
        + [f"property float {name}" for name in PLY_PROPERTIES] + ["end_header"]
    ) + "\n"
    return header.encode("ascii"), table.tobytes()


def write_ply(path, arrays: dict) -> Path:
    """Write a Gaussian map as a standard 3DGS PLY (SH degree 0) atomically; returns the path."""
    header, body = _ply_parts(arrays)
    return write_bytes_atomic(path, [header, body])


def _parse_header(f, path: Path):
    first = f.readline()
    if first.strip() != b"ply":
        raise InputError(f"{path}: not a PLY file (expected the magic line 'ply')")
    fmt = None
    elements: list[tuple[str, int, list]] = []  # (name, count, [(prop, type or ('list', ...))])
    while True:
        line = f.readline()
        if not line:
            raise InputError(f"{path}: PLY header has no 'end_header' line")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else None
        elif words[0] == "element" and len(words) == 3:
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[-1], ("list", words[2], words[3])))
            else:
                if words[1] not in _PLY_TYPES:
                    raise InputError(f"{path}: unknown PLY property type {words[1]!r}")
                elements[-1][2].append((words[2], words[1]))
        else:
            raise InputError(f"{path}: unreadable PLY header line {line.strip()!r}")
    if fmt not in ("binary_little_endian", "ascii"):
        raise InputError(f"{path}: PLY format {fmt!r} is not supported "
                         "(expected binary_little_endian or ascii)")
    return fmt, elements


def _element_dtype(props, path: Path, name: str) -> np.dtype:
    for prop, kind in props:
        if isinstance(kind, tuple):
            raise InputError(f"{path}: element {name!r} has a list property {prop!r}; "
                             "a Gaussian PLY has only scalar vertex properties before the vertices")
    return np.dtype([(prop, _PLY_TYPES[kind]) for prop, kind in props])


def read_ply(path) -> dict[str, np.ndarray]:
    """Read any 3DGS PLY (with or without f_rest_* and extra properties; ascii or binary
    little endian) into Gaussian arrays like `GaussianMap.to_numpy()`.

    log_scales come back N x 1 when the three scales are equal (isotropic), else N x 3;
    colors = 0.5 + C0 * f_dc (higher-order SH are dropped); birth_frame is all zeros.
    Raises InputError naming the file for anything else.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such PLY file")
    with open(path, "rb") as f:
        fmt, elements = _parse_header(f, path)
        vertex = None
        for name, count, props in elements:
            if name == "vertex":
                dtype = _element_dtype(props, path, name)
                if fmt == "binary_little_endian":
                    raw = f.read(dtype.itemsize * count)
                    if len(raw) != dtype.itemsize * count:
                        raise InputError(f"{path}: truncated PLY, expected {count} vertices "
                                         f"of {dtype.itemsize} bytes")
                    vertex = np.frombuffer(raw, dtype=dtype, count=count)
                else:
                    vertex = _read_ascii_rows(f, dtype, count, path)
                break
            # An element before the vertices: skip it.
            dtype = _element_dtype(props, path, name)
            if fmt == "binary_little_endian":
                f.seek(dtype.itemsize * count, os.SEEK_CUR)
            else:
                for _ in range(count):
                    f.readline()
    if vertex is None:
        raise InputError(f"{path}: PLY has no 'vertex' element")
    names = set(vertex.dtype.names)
    needed = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
              "rot_0", "rot_1", "rot_2", "rot_3"]
    missing = [p for p in needed if p not in names]
    if missing:
        raise InputError(f"{path}: not a 3D Gaussian splatting PLY; vertex properties "
                         f"{', '.join(missing)} are missing")
    col = lambda p: np.asarray(vertex[p], dtype=np.float32)  # noqa: E731
    scales = [col("scale_0")] + [col(f"scale_{i}") if f"scale_{i}" in names else col("scale_0")
                                 for i in (1, 2)]
    log_scales = collapse_isotropic(np.stack(scales, axis=1))
    means = np.stack([col("x"), col("y"), col("z")], axis=1)
    colors = (0.5 + SH_C0 * np.stack([col(f"f_dc_{i}") for i in range(3)], axis=1)).astype(np.float32)
    return dict(
        means=means, colors=colors,
        rotations=np.stack([col(f"rot_{i}") for i in range(4)], axis=1),
        logit_opacities=col("opacity").copy(), log_scales=log_scales,
        birth_frame=np.zeros(len(means), dtype=np.int64),
    )


def _read_ascii_rows(f, dtype: np.dtype, count: int, path: Path) -> np.ndarray:
    rows = []
    for i in range(count):
        line = f.readline()
        if not line:
            raise InputError(f"{path}: truncated ASCII PLY, expected {count} vertices, got {i}")
        rows.append(line.split()[: len(dtype.names)])
    try:
        values = np.asarray(rows, dtype=np.float64).reshape(count, len(dtype.names))
    except ValueError:
        raise InputError(f"{path}: malformed ASCII PLY vertex rows") from None
    out = np.zeros(count, dtype=dtype)
    for i, name in enumerate(dtype.names):
        out[name] = values[:, i]
    return out


# ----------------------------------------------------------------------------- .splat

def splat_bytes(arrays: dict) -> bytes:
    a = checked_arrays(arrays)
    scales = np.exp(a["log_scales"].astype(np.float64))
    opacity = sigmoid(a["logit_opacities"])
    order = np.argsort(-(scales.prod(axis=1) * opacity), kind="stable")
    table = np.zeros(len(order), dtype=SPLAT_DTYPE)
    table["position"] = a["means"][order]
    table["scale"] = scales[order]
    rgba = np.concatenate([a["colors"][order], opacity[order, None]], axis=1)
    table["rgba"] = np.clip(np.round(rgba * 255.0), 0, 255).astype(np.uint8)
    q = normalised_quaternions(a["rotations"][order])
    table["rotation"] = np.clip(np.round(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    return table.tobytes()


def write_splat(path, arrays: dict) -> Path:
    """Write the antimatter15 `.splat` layout (32 B per Gaussian, sorted) atomically."""
    return write_bytes_atomic(path, splat_bytes(arrays))


def read_splat(path) -> dict[str, np.ndarray]:
    """Read a `.splat` file back into Gaussian arrays (8-bit colour/opacity/rotation)."""
    path = Path(path)
    raw = path.read_bytes()
    if len(raw) % SPLAT_DTYPE.itemsize:
        raise InputError(f"{path}: size {len(raw)} is not a multiple of 32 bytes (.splat layout)")
    t = np.frombuffer(raw, dtype=SPLAT_DTYPE)
    rgba = t["rgba"].astype(np.float32) / 255.0
    alpha = np.clip(rgba[:, 3], 1e-4, 1 - 1e-4)
    return dict(
        means=t["position"].astype(np.float32),
        colors=rgba[:, :3].copy(),
        rotations=(t["rotation"].astype(np.float32) - 128.0) / 128.0,
        logit_opacities=np.log(alpha / (1 - alpha)).astype(np.float32),
        log_scales=np.log(np.maximum(t["scale"], 1e-12)).astype(np.float32),
        birth_frame=np.zeros(len(t), dtype=np.int64),
    )
