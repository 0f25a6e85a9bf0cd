"""Capture readers (one module per format), format detection, PLY, checkpoints, TUM trajectories."""

from .detect import FORMATS, detect_format, open_capture
from .source import FrameSource

__all__ = ["FrameSource", "FORMATS", "detect_format", "open_capture"]
