"""A run around the algorithm: the frames in, an engine, checkpoints, the run folder.

    pipeline.py     Pipeline: step() one frame, finish() the run folder (used by `splatam run` and the viewer)
    engines.py      one interface for the sequential engine (SplaTAM.process) and the live one (live.py)
    live.py         LiveEngine: tracking in the caller's thread, mapping in a mapper thread
    frame_feed.py   opening the input, frame indices, bad frames skipped
    run_folder.py   RunFolder: the run folder's files, written once, read strictly or tolerantly (no torch)
    report.py       ATE, render metrics and metrics.json's figures
    resolution.py   what a preset's working resolution means on a capture's shape

The names below are imported on first use, so `splat_core.run.run_folder` imports without torch.
"""

from typing import TYPE_CHECKING

from ..lazy_names import lazy_names

if TYPE_CHECKING:       # what the names are (for readers and type checkers); imported on first use below
    from .engines import ENGINES
    from .frame_feed import open_input, resolve_device
    from .pipeline import Pipeline
    from .run_folder import RunFolder

_HOMES = {"ENGINES": "engines", "Pipeline": "pipeline", "RunFolder": "run_folder",
          "open_input": "frame_feed", "resolve_device": "frame_feed"}

__all__ = sorted(_HOMES)


__getattr__, __dir__ = lazy_names(__name__, _HOMES)
