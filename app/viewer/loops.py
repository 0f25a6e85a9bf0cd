"""Closed loops in the viewer: edges between the two keyframes of each loop, and what the page says.

    layer = LoopLayer(server, colors)
    layer.update(snap)               # with the keyframe frustums: edges at the keyframes' current poses
    layer.notify(clients, prev, snap)  # a toast on every page for each loop closed since `prev`
    loop_line(record)                # "loop closed: keyframe 12 <-> 87 (frames #240 <-> #1740), correction 4.1 cm"

A loop record is a splat_core.loop.records.LoopRecord (MapSnapshot.loops: the engine's MapVersion.loops
while SLAM runs, metrics.json `loops` read back when browsing a run folder). Its `keyframes` are keyframe
positions as the CLI prints them (counted from 0), its `frames` the keyframes' frame numbers; the
edges are found by frame number, so they join the frustums whatever list the keyframes came from.
The edges live under /keyframes, so they are hidden with the frustums (a page scrubbed to a
keyframe hides /keyframes and draws its own faded outlines and edges: scrub.py).
"""

from __future__ import annotations

import threading

import numpy as np
import viser

from splat_core.loop.records import LoopRecord

LOOP_COLOR = (0, 200, 200)      # cyan: distinct from the trajectories, keyframes and current camera


def loop_line(record: LoopRecord) -> str:
    """One loop in words, from the record's own fields; says so when no correction was applied."""
    k = record.keyframes or ("?", "?")
    f = record.frames
    where = f"keyframe {k[0]} <-> {k[1]}" + (f" (frames #{f[0]} <-> #{f[1]})" if f else "")
    if record.applied:
        cm, deg = record.correction_cm, record.correction_deg
        what = f"correction {cm:.1f} cm" if cm is not None else "correction applied"
        if cm is not None and deg is not None:
            what += f", {deg:.2f}°"
    else:
        cm = record.disagreement_cm
        what = "no correction applied" + (f" (the poses already agreed within {cm:.1f} cm)" if cm is not None else "")
    return f"loop closed: {where}, {what}"


def loop_status_lines(loops) -> list[str]:
    """The status panel's lines about loops: the newest one (None or () says nothing)."""
    if not loops:
        return []
    return [f"🔁 {loop_line(loops[-1])}"]


def loop_count_text(loops) -> str:
    """' · loops: N' for the status line when the run closes loops ('' when loop closure is off)."""
    return "" if loops is None else f" · loops: {len(loops)}"


def loop_segments(loops, keyframes, upto_frame: int | None = None) -> np.ndarray:
    """(S, 2, 3) float32: for each loop whose two keyframes are both in `keyframes` (KeyframeViews),
    the segment between their camera centres (the frustums' apexes) at their current poses.
    upto_frame: only loops both of whose keyframes are at or before this frame (a scrubbed page)."""
    centre = {int(kf.frame_index): np.asarray(kf.c2w, np.float64)[:3, 3] for kf in keyframes}
    segs = []
    for record in loops or ():
        frames = [int(f) for f in record.frames]
        if len(frames) != 2 or not all(f in centre for f in frames):
            continue
        if upto_frame is not None and max(frames) > upto_frame:
            continue
        segs.append((centre[frames[0]], centre[frames[1]]))
    return np.asarray(segs, np.float32).reshape(-1, 2, 3)


class LoopLayer:
    """The loop edges under /keyframes/loops (one line-segment node, replaced when the edges change)."""

    NAME = "/keyframes/loops"

    def __init__(self, server: viser.ViserServer, colors: dict | None = None):
        self.server = server
        self.color = tuple((colors or {}).get("loop", LOOP_COLOR))
        self.segments = np.zeros((0, 2, 3), np.float32)    # what is drawn now
        self._handle = None
        self._notified = 0
        self._lock = threading.Lock()

    def update(self, snap) -> bool:
        """Draw the snapshot's loops between its keyframes' current poses; True when the edges changed."""
        seg = loop_segments(snap.loops, snap.keyframes)
        with self._lock:
            if seg.shape == self.segments.shape and np.array_equal(seg, self.segments):
                return False
            self.segments = seg
            if self._handle is not None:
                self._handle.remove()
                self._handle = None
            if len(seg):
                self._handle = self.server.scene.add_line_segments(
                    self.NAME, seg, colors=np.array(self.color, np.uint8), thickness=3.0,
                    thickness_units="screen")
            return True

    def notify(self, clients, snap) -> list[str]:
        """A notification on every page for each loop closed since the last call while SLAM runs
        (browsing a finished run says it in the status panel only); returns the lines shown."""
        loops = snap.loops or ()
        with self._lock:
            first, self._notified = self._notified, len(loops)
        if snap.state == "browse" or len(loops) <= first:
            return []
        lines = [loop_line(r) for r in loops[first:]]
        for client in list(clients):
            for line in lines:
                try:
                    client.add_notification("Loop closed", line, auto_close_seconds=10.0, color="cyan")
                except Exception:          # a page that just left: nothing to tell
                    pass
        return lines
