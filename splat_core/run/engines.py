"""The engines that drive SplaTAM, behind one interface, so the pipeline never asks which it has.

    engine = make_engine("live" | "sequential", slam, config)
    result = engine.process(frame, w2c_given)   # one frame: tracked now, mapped now or later
    version = engine.map_version()              # the newest map, safe to read from any thread
    engine.drain()                              # every frame handed over is in the map
    engine.close()
    engine.stats()                              # the engine's own figures for metrics.json

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
from ..slam import FrameResult, MapVersion, SplaTAM

ENGINES = ("sequential", "live")


class Engine(Protocol):
    def process(self, frame: Frame, w2c_given: np.ndarray | None = None) -> FrameResult: ...
    def map_version(self) -> MapVersion: ...
    def drain(self) -> None: ...
    def close(self) -> None: ...
    def stats(self) -> dict: ...


class SequentialEngine:
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


def make_engine(name: str, slam: SplaTAM, config: Config) -> Engine:
    if name == "sequential":
        return SequentialEngine(slam)
    if name == "live":
        from .live import LiveEngine
        return LiveEngine(slam, config.live)
    raise InputError(f"--engine {name}: expected one of {', '.join(ENGINES)}")
