"""TUM trajectory text: one pose per line, `t tx ty tz qx qy qz qw`, camera-to-world.

This is what evo and the TUM benchmark tools read. Quaternions in files are (qx, qy, qz, qw);
in code they are (w, x, y, z) (docs/design.md, Conventions).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import write_text_atomic


def parse_tum_lines(path: Path, min_columns: int = 8) -> list[tuple[int, list[str]]]:
    """(line number, fields) of a whitespace/comma separated text file, skipping '#' and blank lines."""
    try:
        text = Path(path).read_text(errors="replace")
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e})") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) < min_columns:
            raise InputError(f"{path}:{n}: expected at least {min_columns} columns, got {len(fields)}: {line[:60]!r}")
        rows.append((n, fields))
    return rows


def read_tum_trajectory(path) -> tuple[np.ndarray, np.ndarray]:
    """-> (timestamps (N,), c2w (N, 4, 4)). Lines that are not 8 numbers raise InputError with the line."""
    stamps, quats, trans = [], [], []
    for n, fields in parse_tum_lines(path, 8):
        try:
            t, tx, ty, tz, qx, qy, qz, qw = (float(v) for v in fields[:8])
        except ValueError:
            raise InputError(f"{path}:{n}: expected 't tx ty tz qx qy qz qw' numbers, got {' '.join(fields)[:60]!r}") from None
        q = np.array([qw, qx, qy, qz])
        norm = np.linalg.norm(q)
        if not np.all(np.isfinite([t, tx, ty, tz])) or not np.isfinite(norm) or norm < 1e-6:
            raise InputError(f"{path}:{n}: invalid pose (non-finite value or zero quaternion)")
        stamps.append(t)
        quats.append(q / norm)
        trans.append([tx, ty, tz])
    c2w = np.tile(np.eye(4), (len(stamps), 1, 1))
    if stamps:
        c2w[:, :3, :3] = quats_to_rotmats(np.asarray(quats))
        c2w[:, :3, 3] = np.asarray(trans)
    return np.asarray(stamps, dtype=np.float64), c2w


def quats_to_rotmats(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) -> (N, 3, 3), vectorised (same formula as camera.py)."""
    w, x, y, z = q.T
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape(-1, 3, 3)


def format_tum_line(t: float, c2w: np.ndarray) -> str:
    from ..camera import rotmat_to_quat     # (camera.py imports torch; reading a trajectory does not need it)
    q = rotmat_to_quat(np.asarray(c2w)[:3, :3])  # (w, x, y, z)
    tx, ty, tz = np.asarray(c2w)[:3, 3]
    return (f"{t:.6f} {tx:.9f} {ty:.9f} {tz:.9f} "
            f"{q[1]:.9f} {q[2]:.9f} {q[3]:.9f} {q[0]:.9f}")


def write_tum_trajectory(path, timestamps, c2w, header: str | None = None, comments: dict | None = None) -> int:
    """Write poses atomically (temporary file + os.replace). Non-finite poses are left out.
    `comments`: pose number -> a '#' line written just before that pose (e.g. a lost frame).
    Returns the number of poses written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = []
    if header:
        lines += [f"# {h}" for h in header.splitlines()]
    lines.append("# timestamp tx ty tz qx qy qz qw")
    n = 0
    for k, (t, T) in enumerate(zip(np.asarray(timestamps, dtype=np.float64), c2w)):
        if T is None or not np.all(np.isfinite(T)):
            continue
        if comments and k in comments:
            lines.append(f"# {comments[k]}")
        lines.append(format_tum_line(float(t), T))
        n += 1
    write_text_atomic(path, "\n".join(lines) + "\n")
    return n
