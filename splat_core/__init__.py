"""splat_core: the SplaTAM engine (dense RGB-D SLAM with 3D Gaussian splatting).

Imports torch, numpy and numba; never the viewer toolkit. See docs/design.md for the layout.
"""

__version__ = "0.1.0"
