"""A lighter copy of a mesh for display: vertex clustering on a grid (numpy only).

    decimate(mesh, max_faces) -> trimesh.Trimesh with at most max_faces faces

Vertices are merged per grid cell (position and colour averaged), faces that collapse or repeat
are dropped. The cell starts at sqrt(2 * area / max_faces) (a grid mesh of that spacing has about
max_faces triangles) and grows until the face count fits. trimesh's quadric decimation needs the
fast_simplification package, which is not a dependency.
"""

from __future__ import annotations

import numpy as np


def cluster_vertices(mesh, cell: float):
    """(vertices, faces, colours) of `mesh` with its vertices merged per cell of side `cell`."""
    v = np.asarray(mesh.vertices, np.float64)
    _, inverse = np.unique(np.floor(v / cell).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    n = int(inverse.max()) + 1
    count = np.bincount(inverse, minlength=n).astype(np.float64)[:, None]
    verts = np.stack([np.bincount(inverse, v[:, i], n) for i in range(3)], 1) / count
    colors = None
    if getattr(mesh.visual, "kind", None) == "vertex":
        c = np.asarray(mesh.visual.vertex_colors, np.float64)
        colors = np.stack([np.bincount(inverse, c[:, i], n) for i in range(c.shape[1])], 1) / count
        colors = np.clip(np.round(colors), 0, 255).astype(np.uint8)
    f = inverse[np.asarray(mesh.faces)]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(np.sort(f, 1), axis=0, return_index=True)
    return verts, f[np.sort(first)], colors


def decimate(mesh, max_faces: int):
    """`mesh` itself when it has at most max_faces faces, else a vertex-clustered copy that has."""
    import trimesh

    if len(mesh.faces) <= max_faces:
        return mesh
    cell = float(np.sqrt(2.0 * mesh.area / max_faces))
    for _ in range(20):
        verts, faces, colors = cluster_vertices(mesh, cell)
        if len(faces) <= max_faces:
            break
        cell *= 1.05 * np.sqrt(len(faces) / max_faces)
    out = trimesh.Trimesh(verts, faces, vertex_colors=colors, process=False)
    out.remove_unreferenced_vertices()
    out.metadata.update(mesh.metadata, decimated_from=len(mesh.faces), cluster_cell=cell)
    return out
