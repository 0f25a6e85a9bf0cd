"""The engines that drive SplaTAM, behind one interface, so the pipeline never asks which it has.

    engine = make_engine("live" | "sequential", slam, config)
    result = engine.process(frame, w2c_given)   # one frame: tracked now, mapped now or later
    version = engine.map_version()              # the newest map, safe to read from any thread
    engine.drain()                              # every frame handed over is in the map
    engine.close()
    engine.finish_map()                         # SplaTAM.finish: hole fill and colour fit, the map published
    engine.stats()                              # the engine's own figures for metrics.json
    engine.keyframes(), engine.trajectory(), engine.loops(), engine.loop_figures(), engine.num_gaussians(),
    engine.map_arrays(), engine.render(w2c)
    engine.state_arrays() / engine.load_state(arrays, keyframe_file)   # checkpoints (SplaTAM's own)

The pipeline and the app talk to an engine only; the engine owns the SplaTAM it drives (`slam`).
The sequential engine runs SplaTAM.process (track, then map) in the caller's thread: deterministic
and resumable bit for bit. The live engine (live.py) tracks in the caller's thread while a mapper
thread maps.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..config import Config
from ..errors import InputError
from ..frame import Frame
from ..keyframes import Keyframe
from ..slam import FrameResult, MapVersion, SplaTAM
from .slam_reads import SlamReads

ENGINES = ("sequential", "live")


class Engine(Protocol):
    def process(self, frame: Frame, w2c_given: np.ndarray | None = None) -> FrameResult: ...
    def map_version(self) -> MapVersion: ...
    def drain(self) -> None: ...
    def close(self) -> None: ...
    def finish_map(self) -> dict: ...
    def stats(self) -> dict: ...
    def keyframes(self) -> list[Keyframe]: ...
    def trajectory(self) -> list[np.ndarray]: ...
    def loop_figures(self) -> dict | None: ...
    def loops(self) -> tuple | None: ...
    def num_gaussians(self) -> int: ...
    def map_arrays(self) -> dict: ...
    def render(self, w2c: np.ndarray): ...
    def attach_keyframes(self, path) -> None: ...
    def state_arrays(self) -> dict: ...
    def load_state(self, arrays: dict, keyframe_file) -> None: ...


class SequentialEngine(SlamReads):
    def __init__(self, slam: SplaTAM):
        self.slam = slam

    def process(self, frame: Frame, w2c_given: np.ndarray | None = None) -> FrameResult:
        return self.slam.process(frame, w2c_given)

    def map_version(self) -> MapVersion:
        """A copy of the map after the last frame, made once by the stepping thread."""
        version = self.slam.latest_version()
        newest = self.slam.frames_tracked - 1
        if version is None or version.frame_index != newest:
            version = self.slam.publish(newest)
        return version

    def drain(self) -> None:
        pass

    def close(self) -> None:
        pass

    def stats(self) -> dict:
        return {}


def make_engine(name: str, slam: SplaTAM, config: Config, live_source: bool = False) -> Engine:
    """`live_source`: the frames come from a stream or a real-time playback (live.pace_sources)."""
    if name == "sequential":
        return SequentialEngine(slam)
    if name == "live":
        from .live import LiveEngine
        return LiveEngine(slam, config.live, live_source=live_source)
    raise InputError(f"--engine {name}: expected one of {', '.join(ENGINES)}")
