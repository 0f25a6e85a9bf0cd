"""Scoring a mesh: against the synthetic scene's exact surfaces, or against reference points.

accuracy    distance from the mesh to the truth (mesh surface samples -> truth), median / mean / p90
completion  fraction of the truth's observed surface points within `threshold` (2 cm) of the mesh

`scene_surface_distance(scene, points)` is the exact distance from world points to the nearest
surface of a `synthetic.SyntheticScene` (room faces, boxes, spheres).
Used by benchmarks/mesh.py and tests/export/test_mesh_export.py (benchmarks/ is on their sys.path).
"""

from __future__ import annotations

import numpy as np

from splat_core.camera import Intrinsics, backproject

COMPLETION_THRESHOLD = 0.02


def _box_surface_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
    inside = np.min(np.minimum(p - lo, hi - p), axis=1)
    return np.where(outside > 0, outside, np.maximum(inside, 0.0))


def scene_surface_distance(scene, points: np.ndarray) -> np.ndarray:
    """Distance (m) from each world point (N x 3) to the nearest surface of the synthetic scene."""
    from splat_core.synthetic import Box

    p = np.asarray(points, np.float64).reshape(-1, 3)
    best = _box_surface_distance(p, scene.lo, scene.hi)
    for obj in scene.objects:
        if isinstance(obj, Box):
            d = _box_surface_distance(p, obj.lo, obj.hi)
        else:
            d = np.abs(np.linalg.norm(p - obj.centre, axis=1) - obj.radius)
        best = np.minimum(best, d)
    return best


def surface_samples(mesh, per_face: float = 2.0, seed: int = 0) -> np.ndarray:
    """Vertices plus random points on the faces (about per_face of them per face)."""
    import trimesh

    count = int(per_face * len(mesh.faces))
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed) if count else (np.zeros((0, 3)), None)
    return np.concatenate([np.asarray(mesh.vertices), pts])


def depth_points(depth: np.ndarray, c2w: np.ndarray, intr: Intrinsics, stride: int = 1) -> np.ndarray:
    """World points of a depth image's valid pixels (every `stride`-th row and column)."""
    pts = backproject(depth, intr)[::stride, ::stride].reshape(-1, 3)
    pts = pts[pts[:, 2] > 0]
    return pts @ c2w[:3, :3].T + c2w[:3, 3]


def _stats(d: np.ndarray) -> dict:
    return dict(median_cm=float(np.median(d) * 100), mean_cm=float(np.mean(d) * 100),
                p90_cm=float(np.percentile(d, 90) * 100))


def score_against_scene(mesh, scene, truth_points: np.ndarray, threshold: float = COMPLETION_THRESHOLD) -> dict:
    """Mesh (in the scene's world frame) against the exact surfaces; completion over truth_points
    (observed surface points, e.g. exact depth back-projected at the exact poses)."""
    from scipy.spatial import cKDTree

    samples = surface_samples(mesh)
    acc = scene_surface_distance(scene, samples)
    comp, _ = cKDTree(samples).query(truth_points, k=1, workers=1)
    return dict(accuracy=_stats(acc), completion=float(np.mean(comp <= threshold)),
                vertices=len(mesh.vertices), faces=len(mesh.faces))


def score_against_points(mesh, truth_points: np.ndarray, threshold: float = COMPLETION_THRESHOLD) -> dict:
    """Mesh against reference points (captured depth reprojected with the reference poses)."""
    from scipy.spatial import cKDTree

    samples = surface_samples(mesh)
    acc, _ = cKDTree(truth_points).query(samples, k=1, workers=1)
    comp, _ = cKDTree(samples).query(truth_points, k=1, workers=1)
    return dict(accuracy=_stats(acc), completion=float(np.mean(comp <= threshold)),
                vertices=len(mesh.vertices), faces=len(mesh.faces))
