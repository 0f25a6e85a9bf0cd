"""splat_core: the SplaTAM engine (dense RGB-D SLAM with 3D Gaussian splatting).

Imports torch, numpy and numba (the outer ring, run folder and input contract, numpy only);
never the viewer toolkit. See docs/design.md for the layout.
"""

__version__ = "0.1.0"
