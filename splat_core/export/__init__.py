"""Hand-offs: a finished run as input for other tools.

    write_colmap(run, out_dir, frames="keyframes")        COLMAP text model + images (colmap.py)
    write_nerfstudio(run, out_dir, frames="keyframes")    transforms.json + images + depth + seed .ply
    build_mesh(run, voxel=None, trunc=None, ...)          TSDF fusion -> trimesh.Trimesh (mesh.py)

`run` is a `splat_core.refine.run_data.RunData` (load_run_data(RUN_DIR)). Poses in our files and
in memory follow DESIGN.md §3 (OpenCV axes, w2c in memory); each writer converts to its target's
convention in one place, and tests/export/test_handoffs.py checks the conversion by round trip.
"""

from .colmap import write_colmap
from .mesh import build_mesh, write_mesh
from .nerfstudio import write_nerfstudio

__all__ = ["write_colmap", "write_nerfstudio", "build_mesh", "write_mesh"]
