"""The synthetic two-camera TUM capture (splat_core/synthetic/two_cameras.py), under the names the tests use."""

from splat_core.synthetic.two_cameras import (  # noqa: F401
    COLOR_FOCAL_RATIO, DEPTH_TO_COLOR, TwoCameraCapture, write_two_camera_tum,
)
