"""The NeRFCapture app's DDS message, its decoding, and a receiver (optional `cyclonedds` package).

The app (App Store build) publishes on DDS domain 0, topic "Frames", one message per tap on
"Send" in Online mode. Struct `NeRFCaptureData::NeRFCaptureFrame` (`@final`, key `id`); SplaTAM's
scripts subscribe to the same fields under the name `SplatCaptureData::SplatCaptureFrame`, so
both names are subscribed. Fields, in wire order:

    id uint32 (key) · timestamp double (ARKit seconds) · fl_x fl_y cx cy float (pixels, colour
    resolution) · transform_matrix float[16] (camera-to-world, ARKit = OpenGL camera axes,
    column-major) · width height uint32 · image sequence<octet> (RGB8, row-major) · has_depth
    boolean · depth_width depth_height uint32 · depth_scale float (the app sends 1.0) ·
    depth_image sequence<octet> (float32 metres, little-endian, depth_height x depth_width)

The app's later, unpublished source adds an `ImageFormat format` field after `height`; SplaTAM's
and instant-ngp's scripts read the layout above, as here. depth_scale is ignored, as they do.

DDS configuration: Cyclone DDS reads CYCLONEDDS_URI (a file:// URI or inline XML) when the
first participant is created; without it, Cyclone's defaults (all interfaces, multicast
discovery) are what a phone on the same network needs.
"""

# No `from __future__ import annotations` here: cyclonedds reads the message's field types from
# live annotations, and the types module is imported inside frame_type().
import functools
import os
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

DOMAIN_ID = 0
TOPIC = "Frames"
TYPE_NAMES = ("NeRFCaptureData.NeRFCaptureFrame", "SplatCaptureData.SplatCaptureFrame")
INSTALL_HINT = 'pip install "splatam-viewer[stream]"'


def require_cyclonedds() -> None:
    try:
        import cyclonedds  # noqa: F401
        import cyclonedds.domain  # noqa: F401
        import cyclonedds.idl  # noqa: F401
    except ImportError:
        raise InputError(f"nerfcapture://: the live stream needs the cyclonedds package: {INSTALL_HINT}") from None


def dds_config_label() -> str:
    uri = os.environ.get("CYCLONEDDS_URI")
    return f"CYCLONEDDS_URI={uri}" if uri else "CYCLONEDDS_URI unset: Cyclone DDS defaults"


@functools.cache
def frame_type(typename: str):
    """The message as a cyclonedds IdlStruct registered under `typename` (one of TYPE_NAMES)."""
    require_cyclonedds()
    import cyclonedds.idl as idl
    import cyclonedds.idl.annotations as annotate
    import cyclonedds.idl.types as t

    @dataclass
    @annotate.final
    @annotate.autoid("sequential")
    class Message(idl.IdlStruct, typename=typename):
        id: t.uint32
        annotate.key("id")
        timestamp: t.float64
        fl_x: t.float32
        fl_y: t.float32
        cx: t.float32
        cy: t.float32
        transform_matrix: t.array[t.float32, 16]
        width: t.uint32
        height: t.uint32
        image: t.sequence[t.uint8]
        has_depth: bool
        depth_width: t.uint32
        depth_height: t.uint32
        depth_scale: t.float32
        depth_image: t.sequence[t.uint8]

    return Message


@dataclass
class PhoneFrame:
    """One decoded message: RGB8 colour, float32 depth (metres, the sensor's smaller size), c2w in
    ARKit axes as sent (float32 values), intrinsics at the colour resolution."""

    id: int
    timestamp: float
    fl_x: float
    fl_y: float
    cx: float
    cy: float
    c2w_arkit: np.ndarray  # 4x4
    rgb: np.ndarray        # HxWx3 uint8
    depth: np.ndarray      # hxw float32 metres

    @property
    def size(self) -> tuple[int, int]:
        return self.rgb.shape[1], self.rgb.shape[0]


def decode(msg) -> PhoneFrame:
    """Any object with the message's fields -> PhoneFrame; ValueError says what is wrong."""
    w, h, dw, dh = int(msg.width), int(msg.height), int(msg.depth_width), int(msg.depth_height)
    if w <= 0 or h <= 0:
        raise ValueError(f"frame {msg.id}: image size {w}x{h}")
    rgb = np.frombuffer(bytes(msg.image), np.uint8)   # cyclonedds gives a list of ints; bytes() is the fast way
    if rgb.size != w * h * 3:
        raise ValueError(f"frame {msg.id}: image has {rgb.size} bytes, expected {w}x{h} RGB8 ({w * h * 3})")
    if not msg.has_depth:
        raise ValueError(f"frame {msg.id}: no depth (a phone without LiDAR: the app does not show 'Depth Supported')")
    raw = np.frombuffer(bytes(msg.depth_image), "<f4") if len(msg.depth_image) % 4 == 0 else None
    if dw <= 0 or dh <= 0 or raw is None or raw.size != dw * dh:
        raise ValueError(f"frame {msg.id}: depth has {len(msg.depth_image)} bytes, "
                         f"expected {dw}x{dh} float32 ({dw * dh * 4})")
    if not np.any(np.isfinite(raw) & (raw > 0)):
        raise ValueError(f"frame {msg.id}: no valid depth pixel")
    c2w = np.asarray(msg.transform_matrix, dtype=np.float32).reshape(4, 4).T.astype(np.float64)
    return PhoneFrame(int(msg.id), float(msg.timestamp), float(msg.fl_x), float(msg.fl_y), float(msg.cx),
                      float(msg.cy), c2w, rgb.reshape(h, w, 3), raw.reshape(dh, dw).astype(np.float32))


class DDSReceiver:
    """Subscribes to "Frames" under both type names; `poll(timeout)` returns new messages.

    A message can reach both readers (Cyclone matches structurally equal types across names),
    so each (id, timestamp) is returned once. Reliable, keep-all readers: the app's writer is
    reliable and a frame is several megabytes of fragments.
    """

    def __init__(self, domain_id: int = DOMAIN_ID):
        require_cyclonedds()
        from cyclonedds.core import (DDSException, InstanceState, Policy, Qos, ReadCondition, SampleState,
                                     ViewState, WaitSet)
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.internal import InvalidSample
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        self._duration, self._invalid = duration, InvalidSample   # InvalidSample: a writer left, no data
        try:
            self._participant = dp = DomainParticipant(domain_id)
            qos = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)), Policy.History.KeepAll)
            self._readers = [DataReader(dp, Topic(dp, TOPIC, frame_type(name), qos=qos), qos=qos)
                             for name in TYPE_NAMES]
            self._waitset = WaitSet(dp)
            self._conditions = [ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any)
                                for r in self._readers]  # kept: a collected condition leaves the waitset
            for condition in self._conditions:
                self._waitset.attach(condition)
        except DDSException as e:
            raise InputError(f"nerfcapture://: cannot start DDS ({dds_config_label()}): {e}") from None
        self._seen: deque = deque(maxlen=512)

    def poll(self, timeout: float) -> list:
        self._waitset.wait(self._duration(seconds=timeout))
        out = []
        for reader in self._readers:
            for msg in reader.take(N=64):
                if isinstance(msg, self._invalid):
                    continue
                key = (int(msg.id), float(msg.timestamp))
                if key not in self._seen:
                    self._seen.append(key)
                    out.append(msg)
        return sorted(out, key=lambda m: m.timestamp)

    def close(self) -> None:
        self._waitset = self._conditions = self._readers = self._participant = None
