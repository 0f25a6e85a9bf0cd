"""A sparse, blocked TSDF volume: voxel blocks (BLOCK^3 voxels) allocated only where depth lands.

Memory grows with the observed surface (blocks within `trunc` of a depth reading), not with the
bounding box. Voxel (global integer index g) has its centre at g * voxel in the world frame.

Integration (projective TSDF, as in KinectFusion): each voxel of the blocks a frame touches is
projected into the frame; with d the depth at that pixel and z the voxel's camera depth, the
signed distance sdf = d - z (positive in front of the surface) is truncated to [-trunc, trunc],
divided by trunc and averaged over frames (weight 1 per frame); voxels further than trunc behind
the surface are left alone. Colour is averaged over the frames where |sdf| < trunc.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..camera import Intrinsics, invert_pose
from ..parallel import prefer_512_bit_vectors  # noqa: F401  (before the kernels: their vector width)

BLOCK = 8
_OFF = 1 << 20     # block coordinates packed into one int64 key (21 bits each)


def pack(coords: np.ndarray) -> np.ndarray:
    c = np.asarray(coords, np.int64) + _OFF
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def unpack(keys: np.ndarray) -> np.ndarray:
    k = np.asarray(keys, np.int64)
    mask = (1 << 21) - 1
    return np.stack([(k >> 42) & mask, (k >> 21) & mask, k & mask], 1) - _OFF


@njit(parallel=True, cache=True)
def _integrate(slots, coords, tsdf, weight, color, cweight, block, voxel, R, t, fx, fy, cx, cy,
               depth, image, trunc):
    H, W = depth.shape
    for n in prange(slots.shape[0]):
        s = slots[n]
        for i in range(block):
            x = (coords[s, 0] * block + i) * voxel
            for j in range(block):
                y = (coords[s, 1] * block + j) * voxel
                for k in range(block):
                    z = (coords[s, 2] * block + k) * voxel
                    zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
                    if zc <= 1e-3:
                        continue
                    xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
                    yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
                    u = int(np.floor(fx * xc / zc + cx + 0.5))
                    v = int(np.floor(fy * yc / zc + cy + 0.5))
                    if u < 0 or v < 0 or u >= W or v >= H:
                        continue
                    d = depth[v, u]
                    if d <= 0.0:
                        continue
                    sdf = d - zc
                    if sdf < -trunc:
                        continue
                    val = min(1.0, sdf / trunc)
                    w0 = weight[s, i, j, k]
                    tsdf[s, i, j, k] = (tsdf[s, i, j, k] * w0 + val) / (w0 + 1.0)
                    weight[s, i, j, k] = w0 + 1.0
                    if sdf < trunc:
                        c0 = cweight[s, i, j, k]
                        for ch in range(3):
                            color[s, i, j, k, ch] = (color[s, i, j, k, ch] * c0 + image[v, u, ch]) / (c0 + 1.0)
                        cweight[s, i, j, k] = c0 + 1.0


@njit(cache=True)
def _ray_block_keys(depth, R, t, fx, fy, cx, cy, voxel, block, offsets):
    """Packed keys of the blocks holding the points at depth + offset along each valid pixel's ray
    (voxel centres at g * voxel: block b holds voxels b*B .. b*B+B-1)."""
    H, W = depth.shape
    n = 0
    for v in range(H):
        for u in range(W):
            if depth[v, u] > 0:
                n += 1
    keys = np.empty(n * offsets.shape[0], np.int64)
    m = 0
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            if d <= 0:
                continue
            rx, ry = (u - cx) / fx, (v - cy) / fy
            for o in range(offsets.shape[0]):
                z = d + offsets[o]
                xc, yc = rx * z, ry * z
                key = np.int64(0)
                for a in range(3):
                    w = R[a, 0] * xc + R[a, 1] * yc + R[a, 2] * z + t[a]
                    g = np.int64(np.floor(w / voxel + 0.5))
                    b = (g // block) + _OFF
                    key = (key << 21) | b
                keys[m] = key
                m += 1
    return keys


class BlockVolume:
    """TSDF voxels in blocks, looked up by block coordinate."""

    def __init__(self, voxel: float, trunc: float, block: int = BLOCK, capacity: int = 256):
        if not (voxel > 0 and trunc >= voxel):
            raise ValueError(f"voxel {voxel} must be > 0 and trunc {trunc} >= voxel")
        self.voxel, self.trunc, self.block = float(voxel), float(trunc), int(block)
        self.index: dict[int, int] = {}
        self.n = 0
        b = self.block
        self.coords = np.zeros((capacity, 3), np.int64)
        self.tsdf = np.ones((capacity, b, b, b), np.float32)
        self.weight = np.zeros((capacity, b, b, b), np.float32)
        self.color = np.zeros((capacity, b, b, b, 3), np.float32)
        self.cweight = np.zeros((capacity, b, b, b), np.float32)

    @property
    def nbytes(self) -> int:
        return sum(a[: self.n].nbytes for a in (self.coords, self.tsdf, self.weight, self.color, self.cweight))

    def _grow(self, need: int) -> None:
        cap = len(self.coords)
        if need <= cap:
            return
        new = max(need, cap * 2)
        def grow(a, fill):
            out = np.full((new,) + a.shape[1:], fill, a.dtype)
            out[: self.n] = a[: self.n]
            return out
        self.coords = grow(self.coords, 0)
        self.tsdf, self.weight = grow(self.tsdf, 1), grow(self.weight, 0)
        self.color, self.cweight = grow(self.color, 0), grow(self.cweight, 0)

    def allocate(self, block_coords: np.ndarray) -> np.ndarray:
        """Slots of the given (unique) block coordinates, allocating the missing ones."""
        keys = pack(block_coords)
        slots = np.empty(len(keys), np.int64)
        new = []
        for n, key in enumerate(keys.tolist()):
            s = self.index.get(key)
            if s is None:
                s = self.index[key] = self.n + len(new)
                new.append(n)
            slots[n] = s
        if new:
            self._grow(self.n + len(new))
            self.coords[self.n: self.n + len(new)] = block_coords[new]
            self.n += len(new)
        return slots

    def touched_blocks(self, depth: np.ndarray, w2c: np.ndarray, intr: Intrinsics) -> np.ndarray:
        """Unique block coordinates within trunc of the frame's depth readings (along each ray)."""
        c2w = invert_pose(np.asarray(w2c, np.float64))
        step = 0.5 * min(self.voxel * self.block, self.trunc)
        offsets = np.arange(-self.trunc, self.trunc + 1e-9, step)
        keys = _ray_block_keys(np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(c2w[:3, :3]),
                               np.ascontiguousarray(c2w[:3, 3]), float(intr.fx), float(intr.fy), float(intr.cx),
                               float(intr.cy), self.voxel, self.block, offsets)
        return unpack(np.unique(keys))

    def integrate(self, depth: np.ndarray, color: np.ndarray, w2c: np.ndarray, intr: Intrinsics) -> None:
        depth = np.ascontiguousarray(depth, np.float32)
        if not (depth > 0).any():
            return
        slots = self.allocate(self.touched_blocks(depth, w2c, intr))
        w2c = np.asarray(w2c, np.float64)
        _integrate(slots, self.coords, self.tsdf, self.weight, self.color, self.cweight, self.block,
                   self.voxel, np.ascontiguousarray(w2c[:3, :3]), np.ascontiguousarray(w2c[:3, 3]),
                   float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), depth,
                   np.ascontiguousarray(color, np.float32), np.float32(self.trunc))

    def slot_of(self, coord) -> int | None:
        return self.index.get(int(pack(np.asarray([coord]))[0]))
