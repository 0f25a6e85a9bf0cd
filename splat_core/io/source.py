"""FrameSource: what every capture reader (and the synthetic scene) provides."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Iterator

import numpy as np

from ..camera import Intrinsics
from ..frame import Frame, resize_frame


class FrameSource(ABC):
    """A sequence of RGB-D frames read lazily (captures can hold thousands of frames).

    Frames come at the source's own resolution (colour and depth already brought to one size);
    the engine resizes them to its working resolution. Reference poses, when present, are
    camera-to-world in OpenCV camera axes, in the capture's own world frame.
    """

    format_name: str = "unknown"
    path: Path | None = None
    registered: bool = True     # colour and depth pixels correspond (False: the camera file says not)
    live: bool = False          # frames arrive over time: pulled with next_frame(), len() grows (nerfcapture_stream.py)

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
