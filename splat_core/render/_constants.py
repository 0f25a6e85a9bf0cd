"""The renderer's constants, shared by the dispatcher, the torch definitions and the Numba kernels
(a leaf module: it imports nothing of the package).

Compositing follows 3DGS: alpha = min(ALPHA_MAX, opacity * G), contributions below ALPHA_MIN are
skipped, and a pixel stops once its transmittance falls below T_MIN.
"""

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4

# A Gaussian's alpha is below 1/255 beyond sqrt(2 ln(255 * 0.99)) = 3.326 standard deviations, so a
# footprint of 3.33 sigma drops nothing that compositing would keep: results do not depend on tiling.
RADIUS_SIGMAS = 3.33

TILE = 16          # the CPU rasterizer's tile size in pixels; `tiles` masks are on this grid
