"""Live NeRFCapture: the stream's newest-frame policy and recording (without DDS), and over DDS on
the loopback-only configuration: `splatam capture nerfcapture`, `splatam run --input nerfcapture://`.

Every DDS participant in this process and its children uses ../shared/reference/cyclonedds-loopback.xml
(127.0.0.1 only, no multicast): CYCLONEDDS_URI is set below, at import, before any participant. It
adds one setting to that file: a port base of this test process's own (Discovery/Ports/Base), so
that two test runs on one machine do not discover each other's participants. Both listen on domain
0, topic "Frames", where the app publishes; with the file alone, a run received the other run's
frames and failed (two concurrent runs of this module, 2026-12-07: "received 10, frames 2").
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
LOOPBACK = REPO.parent / "shared" / "reference" / "cyclonedds-loopback.xml"
# Cyclone DDS's ports for domain 0 lie within ~50 of the base: bases 100 apart, 7500-27400
PORT_BASE = 7500 + 100 * (os.getpid() % 200)
os.environ["CYCLONEDDS_URI"] = f"file://{LOOPBACK},<Discovery><Ports><Base>{PORT_BASE}</Base></Ports></Discovery>"

from app.cli import splatam_main  # noqa: E402
from splat_core.errors import InputError  # noqa: E402
from splat_core.io import nerfcapture_dds  # noqa: E402
from splat_core.io.nerfcapture import NeRFCaptureCapture  # noqa: E402
from splat_core.io.nerfcapture_stream import NeRFCaptureStream  # noqa: E402
from splat_core.io.trajectory import read_tum_trajectory  # noqa: E402
from helpers import nerfcapture_publisher as pub  # noqa: E402

dds = pytest.mark.skipif(importlib.util.find_spec("cyclonedds") is None or not LOOPBACK.is_file(),
                         reason='needs cyclonedds (pip install "splatam-viewer[stream]") and '
                                f"the loopback DDS configuration {LOOPBACK}")

TINY = "base: cpu\nresolution: [64, 48]\n"


def wait_until(predicate, timeout=60.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def assert_reads_back(folder: Path, fields_list, poses):
    cap = NeRFCaptureCapture(folder)
    assert len(cap) == len(fields_list)
    for i, fields in enumerate(fields_list):
        f = cap[i]
        np.testing.assert_array_equal(f.c2w_ref, pub.sent_c2w(fields))          # the float32 pose sent
        np.testing.assert_allclose(f.c2w_ref, poses[i], atol=1e-6)              # the pose rendered
        assert f.timestamp == fields["timestamp"] and f.color.shape == (96, 128, 3)
    return cap


# ----------------------------------------------------------------------------- without DDS

def test_live_frames_equal_the_recorded_capture_read_offline(tmp_path):
    fields_list, poses = pub.messages(4)
    receiver = pub.FakeReceiver()
    stream = NeRFCaptureStream(tmp_path / "cap", receiver=receiver, idle_timeout=None)
    live = []
    for fields in fields_list:
        receiver.put(fields)
        live.append(stream.next_frame(timeout=60))
    stream.close()
    assert receiver.closed and stream.stats()["dropped"] == 0
    cap = assert_reads_back(tmp_path / "cap", fields_list, poses)
    assert stream.intrinsics == cap.intrinsics and stream.intrinsics.width == 128
    for i, f in enumerate(live):
        offline = cap[i]
        assert f.index == i and f.timestamp == offline.timestamp
        for a, b in ((f.color, offline.color), (f.depth, offline.depth), (f.c2w_ref, offline.c2w_ref)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(stream[i].depth, f.depth)
    # depth went from 64x48 to the colour size by nearest neighbour, quantised to 1/6553.5 m
    sent = np.frombuffer(bytes(fields_list[0]["depth_image"]), "<f4").reshape(48, 64)
    np.testing.assert_allclose(live[0].depth[::2, ::2], sent, atol=1 / 6553.5)
    np.testing.assert_array_equal(live[0].depth[1::2, 1::2], live[0].depth[::2, ::2])


def test_slam_gets_the_newest_frame_and_the_skipped_ones_are_counted(tmp_path):
    fields_list, _ = pub.messages(5)
    receiver = pub.FakeReceiver(fields_list[:3])
    stream = NeRFCaptureStream(tmp_path / "cap", receiver=receiver, idle_timeout=None)
    wait_until(lambda: len(stream) == 3)
    assert len(NeRFCaptureCapture(tmp_path / "cap")) == 3    # readable while the stream goes on
    assert stream.next_frame(timeout=60).index == 2 and stream.dropped == 2
    assert stream.next_frame(timeout=0.3) is None          # nothing new yet; the stream goes on
    receiver.put(fields_list[3])
    assert stream.next_frame(timeout=60).index == 3
    receiver.put(fields_list[4])
    wait_until(lambda: len(stream) == 5)
    stream.stop()                                          # Ctrl-C: the frame waiting is not handed out
    assert stream.next_frame() is None
    stream.close()
    stats = stream.stats()
    assert (stats["received"], stats["dropped"], stats["rejected"], stats["stream_end"]) == (5, 3, 0, "stopped")
    assert len(NeRFCaptureCapture(tmp_path / "cap")) == 5    # every frame recorded, taken or not


def test_bad_frames_are_rejected_and_named_when_nothing_usable_arrives(tmp_path):
    fields_list, _ = pub.messages(1)
    no_depth = dict(fields_list[0], has_depth=False, depth_image=[])
    short = dict(fields_list[0], id=9, image=fields_list[0]["image"][:-3])
    stream = NeRFCaptureStream(tmp_path / "cap", receiver=pub.FakeReceiver([no_depth, short]), idle_timeout=3.0)
    with pytest.raises(InputError) as e:
        stream.intrinsics
    message = str(e.value)
    assert "\n" not in message and "2 frames rejected" in message and "expected 128x96 RGB8" in message
    assert "same Wi-Fi" in message and "Online mode" in message and "CYCLONEDDS_URI" in message
    assert stream.end_reason == "no frame for 3 s" and not (tmp_path / "cap").exists()


def test_recording_refuses_a_folder_that_holds_files(tmp_path):
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "transforms.json").write_text("{}")
    with pytest.raises(InputError, match="not empty"):
        NeRFCaptureStream(tmp_path / "cap", receiver=pub.FakeReceiver())


def test_idle_timeout_ends_a_live_run_cleanly(tmp_path, monkeypatch, capsys):
    fields_list, _ = pub.messages(3)
    monkeypatch.setattr(nerfcapture_dds, "DDSReceiver", lambda: pub.FakeReceiver(fields_list))
    (tmp_path / "tiny.yaml").write_text(TINY + "tracking: {iterations: 2}\nmapping: {iterations: 2, "
                                        "first_frame_iterations: 4}\n")
    out = tmp_path / "run"
    code = splatam_main(["run", "--input", "nerfcapture://", "--out", str(out), "--config",
                         str(tmp_path / "tiny.yaml"), "--idle-timeout", "1"])
    assert code == 0, capsys.readouterr().err
    assert "stream ended (no frame for 1 s): 3 frames received" in capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["received"] == 3 and metrics["frames"] + metrics["dropped"] == 3 and metrics["frames"] >= 1
    assert len(read_tum_trajectory(out / "trajectory.txt")[0]) == metrics["frames"]
    assert len(NeRFCaptureCapture(out / "capture")) == 3


def test_missing_cyclonedds_is_one_line_saying_how_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cyclonedds", None)
    for argv in (["capture", "nerfcapture", "--out", str(tmp_path / "cap")],
                 ["run", "--input", "nerfcapture://", "--out", str(tmp_path / "run")]):
        assert splatam_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and 'pip install "splatam-viewer[stream]"' in err and "cyclonedds" in err
    assert not (tmp_path / "cap").exists()


# ----------------------------------------------------------------------------- over DDS (loopback only)

@dds
def test_capture_records_every_frame_under_both_type_names(tmp_path):
    fields_list, poses = pub.messages(6)
    publisher = pub.play(fields_list, nerfcapture_dds.TYPE_NAMES, interval=0.05)
    code = splatam_main(["capture", "nerfcapture", "--out", str(tmp_path / "cap"), "--frames", "6", "--quiet"])
    publisher.join(10)
    assert code == 0
    assert_reads_back(tmp_path / "cap", fields_list, poses)


@dds
def test_ctrl_c_ends_a_capture_and_keeps_what_arrived(tmp_path):
    fields_list, poses = pub.messages(3)
    out = tmp_path / "cap"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "capture", "nerfcapture", "--out", str(out), "--quiet"],
                            env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pub.play(fields_list, nerfcapture_dds.TYPE_NAMES[:1], interval=0.05)
        listed = lambda: (out / "transforms.json").is_file() and len(  # noqa: E731
            json.loads((out / "transforms.json").read_text())["frames"]) == 3
        wait_until(listed, timeout=60)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "3 frames recorded" in stdout and "Ctrl-C" in stderr
    assert_reads_back(out, fields_list, poses)


@dds
def test_live_run_on_the_stream_tracks_it(tmp_path, monkeypatch, capsys):
    # The publisher sends the next frame once SLAM has taken the one before, as a phone that SLAM
    # keeps up with (falling behind is tested without DDS above). Gated on the frame taken, not on
    # SLAM asking: a message still in transit when SLAM asked again was replaced by the next one
    # under load (a dropped frame).
    taken, next_frame = threading.Event(), NeRFCaptureStream.next_frame

    def counted(self, timeout=None):
        frame = next_frame(self, timeout)
        taken.set()
        return frame
    monkeypatch.setattr(NeRFCaptureStream, "next_frame", counted)
    fields_list, _ = pub.messages(10)
    (tmp_path / "small.yaml").write_text(TINY)
    out = tmp_path / "run"
    publisher = pub.play(fields_list, nerfcapture_dds.TYPE_NAMES[:1], gate=taken)
    code = splatam_main(["run", "--input", "nerfcapture://", "--out", str(out), "--config",
                         str(tmp_path / "small.yaml"), "--max-frames", "8", "--idle-timeout", "120", "--quiet"])
    taken.set()
    publisher.join(30)
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 8 and metrics["received"] - 8 == metrics["dropped"] <= 1
    assert metrics["ate_rmse_cm"] <= 1.0
    stamps, _ = read_tum_trajectory(out / "trajectory.txt")
    np.testing.assert_allclose(stamps, [f["timestamp"] for f in fields_list[:8]], atol=1e-6)
    assert len(NeRFCaptureCapture(out / "capture")) == metrics["received"]
    # Redone offline on the recorded capture, the run is the same bit for bit.
    assert splatam_main(["run", "--input", str(out / "capture"), "--out", str(tmp_path / "offline"), "--config",
                         str(tmp_path / "small.yaml"), "--max-frames", "8", "--quiet"]) == 0
    for name in ("trajectory.txt", "map.ply"):
        assert (out / name).read_bytes() == (tmp_path / "offline" / name).read_bytes(), name


@dds
def test_no_frame_within_the_idle_timeout_says_what_to_check(tmp_path, capsys):
    code = splatam_main(["run", "--input", "nerfcapture://", "--out", str(tmp_path / "run"), "--idle-timeout", "1",
                         "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert "no usable frame" in err and "same Wi-Fi" in err and f"CYCLONEDDS_URI=file://{LOOPBACK}" in err
