"""Plays a synthetic sequence as the NeRFCapture app sends it (test helper).

As the app: ARKit (OpenGL) camera axes, camera-to-world as 16 float32 in column-major order, RGB8
image, depth at half the colour size as float32 metres in little-endian bytes, depth_scale 1.0,
ARKit-like timestamps. `messages()` builds the fields; `FakeReceiver` hands them to a
NeRFCaptureStream without DDS; `Publisher` writes them on DDS (the caller must have pointed
CYCLONEDDS_URI at the loopback-only configuration first).
"""

from __future__ import annotations

import queue
import threading
import time
from types import SimpleNamespace

import numpy as np

from splat_core.camera import OPENGL_TO_OPENCV
from splat_core.synthetic import SyntheticSource

COLOR_SIZE = (128, 96)
DEPTH_SIZE = (64, 48)


def messages(n: int, speed: float = 0.5, t0: float = 5000.0) -> tuple[list[dict], np.ndarray]:
    """(n message field dicts, the n exact c2w poses in OpenCV axes they were rendered from)."""
    src = SyntheticSource(n_frames=n, width=COLOR_SIZE[0], height=COLOR_SIZE[1], speed=speed)
    k, kd = src.intrinsics, src.intrinsics.scaled(*DEPTH_SIZE)
    out = []
    for i in range(n):
        color, _ = src.render_view(src.c2w[i], k)
        _, depth = src.render_view(src.c2w[i], kd)
        rgb = np.clip(np.round(color * 255), 0, 255).astype(np.uint8)
        c2w_arkit = (src.c2w[i] @ OPENGL_TO_OPENCV).astype(np.float32)
        out.append(dict(id=i + 1, timestamp=t0 + i / 30.0, fl_x=k.fx, fl_y=k.fy, cx=k.cx, cy=k.cy,
                        transform_matrix=[float(v) for v in c2w_arkit.T.reshape(-1)],   # column-major
                        width=COLOR_SIZE[0], height=COLOR_SIZE[1], image=list(rgb.tobytes()), has_depth=True,
                        depth_width=DEPTH_SIZE[0], depth_height=DEPTH_SIZE[1], depth_scale=1.0,
                        depth_image=list(depth.astype("<f4").tobytes())))
    return out, src.c2w


def sent_c2w(fields: dict) -> np.ndarray:
    """The pose a message carries, in OpenCV axes (float32 values, as a reader must return it)."""
    c2w_arkit = np.asarray(fields["transform_matrix"], dtype=np.float32).reshape(4, 4).T
    return c2w_arkit.astype(np.float64) @ OPENGL_TO_OPENCV


class FakeReceiver:
    """What DDSReceiver looks like to the stream: poll(timeout) -> messages; fed with put()."""

    def __init__(self, preload=()):
        self.queue: queue.Queue = queue.Queue()
        self.closed = False
        for fields in preload:
            self.put(fields)

    def put(self, fields: dict) -> None:
        self.queue.put(SimpleNamespace(**fields))

    def poll(self, timeout: float) -> list:
        try:
            return [self.queue.get(timeout=timeout)]
        except queue.Empty:
            return []

    def close(self) -> None:
        self.closed = True


class Publisher:
    """A DDS writer on topic "Frames" under one of the app's type names."""

    def __init__(self, typename: str):
        from cyclonedds.core import Policy, Qos
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        from splat_core.io.nerfcapture_dds import TOPIC, frame_type

        self.type = frame_type(typename)
        self.participant = DomainParticipant(0)
        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(seconds=2)), Policy.History.KeepAll)
        self.writer = DataWriter(self.participant, Topic(self.participant, TOPIC, self.type), qos=qos)

    def wait_for_reader(self, timeout: float = 30.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.writer.get_publication_matched_status().current_count > 0:
                time.sleep(0.3)          # let the subscriber's other reader match too
                return True
            time.sleep(0.05)
        return False

    def send(self, fields: dict) -> None:
        self.writer.write(self.type(**fields))


def play(fields_list, typenames, interval: float = 0.0, gate: threading.Event | None = None) -> threading.Thread:
    """Publish in a thread once a reader is there; message i under typenames[i % len]. With `gate`,
    each message after the first waits until the gate is set (then clears it).

    The writers are made here, before the caller starts its reader: Cyclone DDS can fail to create
    a topic ("Non specific error") when two threads of one process create the same topic name
    under different types at the same moment, which made this helper flaky."""
    pubs = [Publisher(name) for name in typenames]

    def run():
        if not all(p.wait_for_reader() for p in pubs):
            return
        for i, fields in enumerate(fields_list):
            if gate is not None and i > 0:
                if not gate.wait(120):
                    return
                gate.clear()
            pubs[i % len(pubs)].send(fields)
            time.sleep(interval)
        time.sleep(1.0)                  # reliable delivery of the last fragments before the writer goes
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread
