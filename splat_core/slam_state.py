"""What SplaTAM hands out of its state: a result per frame, immutable map versions, and the
read-only view its collaborators (loop closure) look through. SplaTAM (slam.py) is the only
writer of its state; everything here is a copy or a view taken between its steps.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import torch

from .camera import Intrinsics, invert_pose
from .config import Config
from .frame import Frame
from .gaussians import GaussianMap, Gaussians


@dataclass
class FrameResult:
    index: int                    # processed-frame number (0 = first frame, the world origin)
    timestamp: float
    w2c: np.ndarray               # estimated pose, 4 x 4
    is_keyframe: bool
    num_gaussians: int
    num_added: int
    num_pruned: int
    tracking_seconds: float
    mapping_seconds: float
    tracking_loss: float | None
    tracking_iterations: int = 0
    tracking_coverage: float | None = None   # share of the loss's valid-depth pixels the map covered (lost_tracking.min_coverage)
    tracking_start: str | None = None  # the pose the polish kept or began from: "aligned", "prediction", ... (tracking.py)
    source_index: int = 0         # frame number in the capture
    frame: Frame | None = field(default=None, repr=False)   # the frame at working resolution
    map_version: int = 0          # the map version the frame was tracked against
    lost: str | None = None       # why tracking was lost on this frame (its pose is the last tracked one); None: tracked
    loops: list = field(default_factory=list)   # LoopRecords of the loops closed at this frame (loop/records.py)

    @property
    def c2w(self) -> np.ndarray:
        return invert_pose(self.w2c)


@dataclass(frozen=True)
class MapVersion:
    """An immutable copy of the map as the mapper published it (renderers may read it from any thread)."""

    number: int
    frame_index: int              # the newest frame mapped into it (-1: empty map)
    gaussians: Gaussians          # detached tensors, never modified after publishing
    birth_frame: torch.Tensor
    ready: object = None          # CUDA: an event recorded after the copy on the publishing stream
    loops: tuple = ()             # every LoopRecord so far (loop/records.py)

    def __len__(self) -> int:
        return len(self.gaussians)

    def wait_ready(self) -> "MapVersion":
        """Make the calling thread's current CUDA stream wait for the copy (no host wait), and tell
        torch's allocator that stream uses these tensors (their memory, from the mapper's stream,
        is not reused before the reader's queued work is done). Nothing to do on the CPU."""
        if self.ready is not None:
            stream = torch.cuda.current_stream(self.gaussians.means.device)
            stream.wait_event(self.ready)
            for x in (*self.gaussians.fields(), self.birth_frame):
                if x.is_cuda:
                    x.record_stream(stream)
        return self

    @functools.cached_property
    def arrays(self) -> dict[str, np.ndarray]:
        """Read-only numpy arrays of the version (GaussianMap.to_numpy() layout), made on the first
        call, by whichever thread reads first, and kept: on the CPU they share the tensors' memory."""
        out = self.wait_ready().gaussians.to_arrays()
        out["birth_frame"] = self.birth_frame.cpu().numpy()
        for a in out.values():
            a.setflags(write=False)
        return out


def snapshot_version(gmap: GaussianMap, number: int, frame_index: int, loops: tuple = ()) -> MapVersion:
    """A MapVersion of `gmap` as it is now (copies: later steps never touch it). On CUDA the copy
    carries an event recorded on the publishing stream (the live engine's mapper has its own)."""
    g = gmap.tensors(detach=True)
    copy = Gaussians(*(x.clone() for x in g.fields()))
    ready = None
    if g.means.is_cuda:
        ready = torch.cuda.Event()
        ready.record(torch.cuda.current_stream(g.means.device))
    return MapVersion(number, frame_index, copy, gmap.birth_frame.clone(), ready, loops)


@dataclass
class MapStats:
    added: int = 0
    pruned: int = 0
    seconds: float = 0.0


@dataclass(frozen=True)
class SlamView:
    """What a collaborator may read of SplaTAM's state now (loop closure after a keyframe): never
    written through. The tensors are the map's own, detached (valid until SplaTAM's next step)."""

    config: Config
    intrinsics: Intrinsics
    near: float
    keyframes: tuple              # Keyframe objects, oldest first (read only)
    gaussians: Gaussians
    birth_frame: torch.Tensor
