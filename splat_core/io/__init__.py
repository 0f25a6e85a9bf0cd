"""Capture readers (one module per format), format detection, PLY, checkpoints, TUM trajectories.

The names below are imported on first use, so the torch-free modules (atomic.py, checkpoint.py,
source.py) import without the readers and the engine behind them.
"""

from importlib import import_module
from typing import TYPE_CHECKING

if TYPE_CHECKING:       # what the names are (for readers and type checkers); imported on first use below
    from .detect import FORMATS, detect_format, open_capture
    from .source import FrameSource

_HOMES = {"FrameSource": "source", "FORMATS": "detect", "detect_format": "detect", "open_capture": "detect"}

__all__ = sorted(_HOMES)


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f".{_HOMES[name]}", __name__), name)


def __dir__():
    return sorted(set(globals()) | set(_HOMES))
