"""A run around the algorithm: the frames in, an engine, checkpoints, the run folder.

    pipeline.py     Pipeline: step() one frame, finish() the run folder (used by `splatam run` and the viewer)
    engines.py      one interface for the sequential engine (SplaTAM.process) and the live one (live.py)
    live.py         LiveEngine: tracking in the caller's thread, mapping in a mapper thread
    frame_feed.py   opening the input, frame indices, bad frames skipped
    run_folder.py   RunFolder: the run folder's files, written once, read strictly or tolerantly
    report.py       ATE, render metrics and metrics.json's figures
    resolution.py   what a preset's working resolution means on a capture's shape
"""

from .engines import ENGINES
from .frame_feed import open_input, resolve_device
from .pipeline import Pipeline
from .run_folder import RunFolder

__all__ = ["ENGINES", "Pipeline", "RunFolder", "open_input", "resolve_device"]
