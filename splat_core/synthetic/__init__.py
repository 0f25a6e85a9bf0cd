"""Procedural RGB-D captures with exact poses: the demo scene, test fixtures and benchmark input.

    scene.py      the room: analytic ray casting of textured walls, boxes and spheres (SyntheticScene)
    paths.py      camera paths (the orbit), look_at_c2w, the default camera
    source.py     SyntheticSource: the room along the orbit as a FrameSource, with sensor effects
    hard.py       HardCapture: the same with one disturbance (jump, covered lens, fast turn)
    corridor.py   CorridorSource: a 40 m corridor walk that keeps exploring (long runs)
    phone.py      SyntheticPhoneCapture: the room as a phone records it (large colour, small depth)
    loop.py       LoopSource: one lap of the room and back (loop closure), DriftingOdometry
    two_cameras.py write_two_camera_tum: the room seen by a depth camera and a colour camera beside it
"""

from .corridor import PERIOD, CorridorSource
from .hard import HARD_KINDS, HardCapture, turn_away
from .loop import DriftingOdometry, LoopSource
from .paths import ORBIT_CENTRE, camera_path, default_intrinsics, look_at_c2w
from .phone import SyntheticPhoneCapture
from .scene import FPS, ROOM_MAX, ROOM_MIN, Box, Sphere, SyntheticScene
from .source import SyntheticSource, add_depth_noise, hole_mask, render_view

__all__ = ["PERIOD", "CorridorSource", "DriftingOdometry", "LoopSource", "HARD_KINDS", "HardCapture", "turn_away", "ORBIT_CENTRE", "camera_path",
           "default_intrinsics", "look_at_c2w", "SyntheticPhoneCapture", "FPS", "ROOM_MAX", "ROOM_MIN", "Box",
           "Sphere", "SyntheticScene", "SyntheticSource", "add_depth_noise", "hole_mask", "render_view"]
