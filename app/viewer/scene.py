"""The 3D scene's map: the splat chunks per keyframe (cameras.py: keyframe frustums, trajectories
and the current camera). Only these modules and the panels call viser's scene API.

Map layout (docs/viewer-notes.md §1.2): viser has no splat append and every change costs O(N_total) in
the browser, so the map is split by birth keyframe. Node `/map/kf_<frame>` holds the Gaussians
born in (previous keyframe, keyframe]; `/map/tail` those born after the last keyframe. A new
keyframe sends only its own chunk; the tail is small. Because SLAM keeps refining old Gaussians
(and prunes some), every node is refreshed from the latest snapshot in one atomic
"consolidation" every few keyframes / seconds and whenever the run pauses or ends. Scrubbing to
keyframe k hides the chunks after k for that page only (scrub.py: client-scoped shadows, no re-upload). A consolidation
re-sends only the chunks whose Gaussians changed (a fingerprint of their arrays): mapping moves
only what the window sees, so on a capture that keeps exploring the chunks left behind are not
sent again and an update costs what changed, not the whole map.

Covariances travel as float16, so positions and covariances are uploaded multiplied by
WORLD_SCALE and each node gets `scale=1/WORLD_SCALE` (the notes' nerfstudio trick), keeping
millimetre-sized Gaussians representable.

While SLAM runs, `policy` says when the browser's 3D scene follows it (`follows`): "keyframes"
(the default) sends a keyframe's chunk, the tail and any due consolidation when a keyframe
arrives, and nothing between keyframes; "continuous" also re-sends the tail with every new
snapshot (at most the viewer's update rate); "off" sends nothing until the run pauses or ends.
The viewer holds the camera layer (current camera, trajectories, keyframe frustums) to the same policy: each
scene message makes viser's page draw frames for 250 ms, which a browser that draws WebGL in
software pays for on the cores SLAM uses (docs/viewer-notes.md §3; figures: docs/benchmarks.md, Viewer).

`budget` (`splatam-viewer --browser-splats N`) caps what the browser draws while SLAM runs: past
N Gaussians it gets every stride-th Gaussian of each chunk (stride a power of two), each with
its footprint grown stride times so the preview still covers the surfaces; pausing or finishing
sends the whole map. A browser that draws WebGL in software spends CPU in proportion to the
splats it draws, at least once a second even when nothing changes.

`running_style` (`splatam-viewer --draw-while-running points`) draws each chunk as a point cloud
while SLAM runs (a point per Gaussian, its colour, a size from the chunk's Gaussians): in
software WebGL a point costs a tenth of a splat (docs/benchmarks.md, Viewer). "auto" (the
default) does that while a page that draws WebGL in software is connected (its page script says
so: page_shim.py) and sends splats otherwise; the style is chosen again at each update, so a
page arriving or leaving changes it at the next keyframe. Pausing or finishing sends splats again.
"""

from __future__ import annotations

import hashlib
import threading
import time

import numpy as np
import viser

from ..snapshot import MAP_UPDATE_POLICIES, RUNNING_STYLES, MapSnapshot, keyframe_buckets
from .page_shim import software_pages

WORLD_SCALE = 10.0


def splat_payload(arrays: dict, index: np.ndarray | None = None, area: float = 1.0):
    """(centers, covariances, rgbs, opacities (N,1)) for viser from raw Gaussian arrays,
    in the uploaded (WORLD_SCALE-multiplied) units; `area` scales each splat's footprint (its
    variances), so that one of every `area` Gaussians still covers the surface they cover."""
    sel = (lambda a: a) if index is None else (lambda a: a[index])  # noqa: E731
    means = np.asarray(sel(arrays["means"]), np.float32)
    n = len(means)
    log_scales = np.asarray(sel(arrays["log_scales"]), np.float32).reshape(n, -1)
    var = np.exp(2.0 * log_scales.astype(np.float64)) * (WORLD_SCALE ** 2 * area)
    if log_scales.shape[1] == 1:
        cov = np.zeros((n, 3, 3), np.float32)
        cov[:, 0, 0] = cov[:, 1, 1] = cov[:, 2, 2] = var[:, 0]
    else:
        q = np.asarray(sel(arrays["rotations"]), np.float64)
        q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
        w, x, y, z = q.T
        R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                     axis=1).reshape(n, 3, 3)
        cov = np.einsum("nij,nj,nkj->nik", R, var, R).astype(np.float32)
    rgbs = np.clip(np.asarray(sel(arrays["colors"]), np.float32), 0.0, 1.0)
    logits = np.asarray(sel(arrays["logit_opacities"]), np.float64).reshape(n, 1)
    opacities = (1.0 / (1.0 + np.exp(-logits))).astype(np.float32)
    return means * np.float32(WORLD_SCALE), cov, rgbs, opacities


POINT_MIN_OPACITY = 0.1   # a point cannot be faint, so the faintest Gaussians are left out


def point_payload(arrays: dict, index: np.ndarray | None = None, area: float = 1.0):
    """(points, rgbs uint8, point size) for viser from raw Gaussian arrays, in the uploaded units:
    a point per Gaussian at least POINT_MIN_OPACITY opaque, all of one size, the median Gaussian
    radius of the chunk (its footprint grown `area` times, as for `splat_payload`)."""
    idx = np.arange(len(arrays["means"])) if index is None else np.asarray(index)
    logits = np.asarray(arrays["logit_opacities"])[idx].reshape(len(idx))
    idx = idx[logits >= np.log(POINT_MIN_OPACITY / (1.0 - POINT_MIN_OPACITY))]
    if not len(idx):
        return None
    means = np.asarray(arrays["means"], np.float32)[idx] * np.float32(WORLD_SCALE)
    rgbs = (np.clip(np.asarray(arrays["colors"], np.float32)[idx], 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    radius = float(np.exp(np.median(np.asarray(arrays["log_scales"], np.float64)[idx])))
    return means, rgbs, radius * np.sqrt(area) * WORLD_SCALE


def chunk_fingerprint(arrays: dict, index: np.ndarray) -> bytes:
    """A digest of the Gaussians `index` of raw arrays (equal digests: nothing to re-send)."""
    h = hashlib.blake2b(digest_size=16)
    for name in ("means", "colors", "rotations", "logit_opacities", "log_scales"):
        h.update(np.ascontiguousarray(np.asarray(arrays[name])[index]).tobytes())
    return h.digest()


class MapLayer:
    """Splat chunks per keyframe under `/map` (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, consolidate_every: int = 5,
                 consolidate_interval_s: float = 10.0, policy: str = "keyframes", budget: int | None = None,
                 running_style: str = "auto"):
        if running_style not in RUNNING_STYLES:
            raise ValueError(f"map style while running must be one of {RUNNING_STYLES}, not {running_style!r}")
        self.server = server
        self.policy = policy
        self.budget = budget          # most Gaussians sent while SLAM runs (None: all)
        self.running_style = running_style   # how chunks are drawn while SLAM runs
        self.stride = 1               # every stride-th Gaussian of each chunk is sent
        self.style = "splats"         # how the chunks sent are drawn
        self.consolidate_every = consolidate_every
        self.consolidate_interval_s = consolidate_interval_s
        self._lock = threading.RLock()
        self._nodes: dict[str, viser.SceneNodeHandle] = {}       # name -> splats / points (non-empty only)
        self._order: list[str] = []                               # chunk names, keyframe order
        self._map_version = -1
        self._keyframes_followed = -1                             # keyframes of the last snapshot followed
        self._loops_drawn = 0                                     # loops closed in the map drawn
        self._keyframes_at_consolidation = 0
        self._consolidated_at = time.monotonic()
        self._fingerprints: dict[str, bytes] = {}                  # name -> digest of what was sent
        self.last_update_seconds = 0.0
        self.consolidations = 0
        self.chunks_sent = 0

    @staticmethod
    def chunk_name(frame_index: int) -> str:
        return f"/map/kf_{frame_index:06d}"

    @property
    def node_names(self) -> list[str]:
        return list(self._nodes)

    def chunk_names(self) -> list[str]:
        """Every chunk's node name in keyframe order, the tail last (scrub.py shadows those after a keyframe)."""
        with self._lock:
            return list(self._order)

    def update(self, snap: MapSnapshot, force_consolidate: bool = False) -> bool:
        """Bring the chunks up to date with `snap`; returns True if anything was sent."""
        with self._lock:
            if not force_consolidate and not self.follows(snap):
                return False
            kf_frames = snap.keyframe_frames
            K = self._keyframes_followed = len(kf_frames)
            stride, style = self.stride_for(snap), self.style_for(snap)
            drawn = (stride, style)
            if snap.map_version == self._map_version and drawn == (self.stride, self.style) and not force_consolidate:
                return False
            t0 = time.perf_counter()
            payload_of = splat_payload if style == "splats" else point_payload
            loops = len(snap.loops or ())            # a loop correction moved old chunks: refresh all
            consolidate = force_consolidate or drawn != (self.stride, self.style) or loops != self._loops_drawn or (
                K - self._keyframes_at_consolidation >= self.consolidate_every
                or time.monotonic() - self._consolidated_at >= self.consolidate_interval_s)
            bucket = keyframe_buckets(snap.gaussians["birth_frame"], kf_frames)
            counts = np.bincount(bucket, minlength=K + 1)
            order = np.argsort(bucket, kind="stable")
            starts = np.concatenate([[0], np.cumsum(counts)])
            names = [self.chunk_name(int(f)) for f in kf_frames] + ["/map/tail"]
            # Compute every payload before touching viser (atomic() stalls all traffic).
            payloads = {}
            for k, name in enumerate(names):
                is_new = name not in self._order
                if consolidate or is_new or name == "/map/tail":
                    idx = order[starts[k]:starts[k + 1]:stride]
                    digest = chunk_fingerprint(snap.gaussians, idx) + repr(drawn).encode()
                    if self._fingerprints.get(name) == digest:
                        continue
                    self._fingerprints[name] = digest
                    payloads[name] = payload_of(snap.gaussians, idx, stride) if len(idx) else None
            with self.server.atomic():
                for name, payload in payloads.items():
                    self._send(name, payload)
                    self.chunks_sent += payload is not None
                for stale in [n for n in self._order if n not in names]:  # keyframes never vanish,
                    self._drop(stale)                                      # but be safe
            self._order = names
            self._map_version, self._loops_drawn = snap.map_version, loops
            self.stride, self.style = drawn
            if consolidate:
                self._keyframes_at_consolidation = K
                self._consolidated_at = time.monotonic()
                self.consolidations += 1
            self.last_update_seconds = time.perf_counter() - t0
            return True

    def stride_for(self, snap: MapSnapshot) -> int:
        """1 (the whole map) unless SLAM is running with more Gaussians than `budget`; then the
        smallest power of two that brings the map within it (powers of two: the stride, and so
        every chunk, changes only when the map has doubled)."""
        n = snap.num_gaussians
        if self.budget is None or snap.state != "running" or n <= self.budget:
            return 1
        return 1 << int(np.ceil(np.log2(n / max(self.budget, 1))))

    def style_for(self, snap: MapSnapshot) -> str:
        """`running_style` while SLAM runs ("auto": points while a page that draws WebGL in software
        is connected), splats once it pauses or ends."""
        if snap.state != "running":
            return "splats"
        if self.running_style == "auto":
            return "points" if software_pages(self.server) else "splats"
        return self.running_style

    def set_policy(self, policy: str) -> None:
        """Change when map changes reach the browser (MAP_UPDATE_POLICIES); the next update consolidates."""
        if policy not in MAP_UPDATE_POLICIES:
            raise ValueError(f"map update policy must be one of {MAP_UPDATE_POLICIES}, not {policy!r}")
        with self._lock:
            self.policy = policy
            self._keyframes_at_consolidation = -self.consolidate_every   # refresh all next time

    def follows(self, snap: MapSnapshot) -> bool:
        """Whether `policy` lets the browser's 3D scene follow this snapshot: always once SLAM
        stops running; while it runs, "continuous" always, "keyframes" when a keyframe arrived
        since the last snapshot followed, "off" never."""
        if snap.state != "running" or self.policy == "continuous":
            return True
        return self.policy == "keyframes" and len(snap.keyframe_frames) > self._keyframes_followed

    def _send(self, name: str, payload, visible: bool = True) -> None:
        handle = self._nodes.get(name)
        if payload is None:
            self._drop(name)
            return
        points = len(payload) == 3
        if handle is not None and isinstance(handle, viser.PointCloudHandle) != points:
            self._nodes.pop(name).remove()                            # the style changed: a new node
            handle = None
        if handle is None:
            scene = self.server.scene
            self._nodes[name] = (
                scene.add_point_cloud(name, payload[0], payload[1], point_size=payload[2], point_shape="circle",
                                      precision="float32", point_shading="flat", scale=1.0 / WORLD_SCALE,
                                      visible=visible) if points else
                scene.add_gaussian_splats(name, *payload, scale=1.0 / WORLD_SCALE, visible=visible))
        else:
            if points:
                handle.points, handle.colors, handle.point_size = payload
            else:
                handle.set_gaussians(*payload)
            if handle.visible != visible:
                handle.visible = visible

    def _drop(self, name: str) -> None:
        handle = self._nodes.pop(name, None)
        self._fingerprints.pop(name, None)
        if handle is not None:
            handle.remove()
