"""Capture readers (one module per format), format detection, PLY, checkpoints, TUM trajectories.

The names below are imported on first use, so the torch-free modules (atomic.py, checkpoint.py,
source.py) import without the readers and the engine behind them.
"""

from typing import TYPE_CHECKING

from ..lazy_names import lazy_names

if TYPE_CHECKING:       # what the names are (for readers and type checkers); imported on first use below
    from .detect import FORMATS, detect_format, open_capture
    from .source import FrameSource

_HOMES = {"FrameSource": "source", "FORMATS": "detect", "detect_format": "detect", "open_capture": "detect"}

__all__ = sorted(_HOMES)


__getattr__, __dir__ = lazy_names(__name__, _HOMES)
