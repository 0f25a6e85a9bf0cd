"""The input contract: FrameSource (what every capture reader and the synthetic scene provides)
and LiveSource (frames that arrive over time, the newest handed to SLAM, the others counted).

Imports no torch: the outer ring (run folder, batch, a later `--realtime` player) uses it."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Iterator

import numpy as np

from ..frame import Frame, resize_frame
from ..intrinsics import Intrinsics


class FrameSource(ABC):
    """A sequence of RGB-D frames read lazily (captures can hold thousands of frames).

    Frames come at the source's own resolution (colour and depth already brought to one size);
    the engine resizes them to its working resolution. Reference poses, when present, are
    camera-to-world in OpenCV camera axes, in the capture's own world frame.
    """

    format_name: str = "unknown"
    path: Path | None = None
    registered: bool = True     # colour and depth pixels correspond (False: the camera file says not)
    # Who registered them, when the capture's writer is known to (shown by `splatam info`; such a
    # capture is not estimated: registration_estimate.registered_by_writer). None: nothing says so.
    registered_by: str | None = None
    live: bool = False          # True for a LiveSource: pulled with next_frame(), len() grows

    @abstractmethod
    def __len__(self) -> int: ...

    @abstractmethod
    def __getitem__(self, i: int) -> Frame:
        """Frame i (0-based, in capture order); raises InputError naming the file on bad data."""

    @property
    @abstractmethod
    def intrinsics(self) -> Intrinsics: ...

    @property
    @abstractmethod
    def timestamps(self) -> np.ndarray:
        """Seconds, one per frame."""

    @property
    def has_reference_poses(self) -> bool:
        return False

    def reference_c2w(self) -> np.ndarray | None:
        """T x 4 x 4 reference poses (NaN rows where a frame has none), or None."""
        return None

    def frame_at_size(self, i: int, width: int, height: int) -> Frame:
        """Frame i at width x height: colour by area averaging, depth by nearest neighbour.
        Readers whose colour and depth grids differ resample each from its own grid."""
        return resize_frame(self[i], width, height)

    def raw_pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame i's colour and depth as stored, each on its own grid (readers of captures whose
        colour is registered when read override this; here: the frame's)."""
        f = self[i]
        return f.color, f.depth

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def close(self) -> None:
        """Release what the source holds (a live stream stops receiving); frames stay readable."""

    def describe(self) -> str:
        return f"{self.format_name} capture at {self.path} ({len(self)} frames)"


class LiveSource(FrameSource):
    """Frames that arrive over time: a phone's stream (nerfcapture_stream.py), or a capture
    played back at its own pace.

    The consumer pulls with `next_frame()`, which hands over the newest frame not yet handed
    out, never a queue: a frame replaced by a newer one before it was pulled is never handed
    out, so a slow consumer always gets the freshest frame instead of falling further behind.

    `received` counts the frames that arrived; each is kept, `len(self)` of them, and readable
    as `source[i]` in arrival order (frame.index is that i). `delivered` counts those handed
    out (a subclass's next_frame() adds to it); `dropped` = received - delivered: the frames
    not handed out so far (the newest one, until it is pulled, included).
    """

    live = True
    delivered: int = 0

    @abstractmethod
    def next_frame(self, timeout: float | None = None) -> Frame | None:
        """The newest frame not yet handed out; None once the source has ended (or after
        `timeout` seconds without a new one: the source goes on)."""

    @abstractmethod
    def stop(self) -> None:
        """Ask the source to end (safe from a signal handler: sets a flag, never blocks)."""

    @property
    def received(self) -> int:
        return len(self)

    @property
    def dropped(self) -> int:
        return self.received - self.delivered

    def stats(self) -> dict:
        """metrics.json's figures: frames received, dropped, and the share of them processed."""
        received = self.received
        return dict(received=received, dropped=self.dropped,
                    processed_share=self.delivered / received if received else None)
