"""The keyframe pose graph, optimised by gtsam (BSD; Levenberg-Marquardt on SE(3) with robust kernels).

Nodes are the keyframes' camera-to-world poses (gtsam.Pose3). Edges:
    odometry   keyframe k-1 -> k: their relative pose when k was made (what tracking measured), with
               noise growing with the step's length (odometry_sigma + odometry_sigma_rel x metres);
    loop       old keyframe -> current keyframe: the verified relative pose (verify.py), with noise
               from the verification's residual; a loop that the solved graph contradicts gets a
               Cauchy kernel and the graph is solved again (`optimise`), so it pulls with
               bounded force;
    prior      keyframe 0 held where it is (it is the world's origin).
gtsam was chosen over a hand-written solver because it is made for this (sparse, on-manifold
Pose3, robust noise models, maintained, wheels on PyPI); see docs/loop-closure.md.
Tangent order in gtsam's Pose3 noise models is (rotation, translation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

try:
    import gtsam
except ImportError:          # pragma: no cover - declared in pyproject's loop extra
    gtsam = None


@dataclass
class Edge:
    a: int                     # keyframe positions
    b: int
    measured: np.ndarray       # 4x4 relative pose: c2w_a^-1 c2w_b
    sigma_m: float             # translation standard deviation (metres)
    sigma_deg: float           # rotation standard deviation (degrees)
    robust: bool = False

    def to_dict(self) -> dict:
        return dict(a=self.a, b=self.b, measured=np.asarray(self.measured).tolist(), sigma_m=self.sigma_m,
                    sigma_deg=self.sigma_deg, robust=self.robust)

    @classmethod
    def from_dict(cls, d: dict) -> "Edge":
        return cls(int(d["a"]), int(d["b"]), np.array(d["measured"], np.float64), float(d["sigma_m"]),
                   float(d["sigma_deg"]), bool(d["robust"]))


def _noise(sigma_m: float, sigma_deg: float, robust: bool):
    sigmas = np.array([np.radians(sigma_deg)] * 3 + [sigma_m] * 3)
    model = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    if robust:
        model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0), model)
    return model


def _pose3(T: np.ndarray):
    T = np.asarray(T, np.float64)
    U, _, Vt = np.linalg.svd(T[:3, :3])          # exactly orthonormal for gtsam
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return gtsam.Pose3(gtsam.Rot3(R), T[:3, 3].copy())


def _solve(c2ws, edges, robust: set, max_iterations):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k, T in enumerate(c2ws):
        values.insert(k, _pose3(T))
    graph.add(gtsam.PriorFactorPose3(0, _pose3(c2ws[0]), _noise(1e-6, 1e-6, False)))
    for n, e in enumerate(edges):
        graph.add(gtsam.BetweenFactorPose3(e.a, e.b, _pose3(e.measured), _noise(e.sigma_m, e.sigma_deg, n in robust)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def edge_chi2(result, e: Edge) -> float:
    """Squared error of edge e in its own sigmas at the optimised poses."""
    measured = _pose3(e.measured)
    err = measured.localCoordinates(result.atPose3(e.a).between(result.atPose3(e.b)))
    sig = np.array([np.radians(e.sigma_deg)] * 3 + [e.sigma_m] * 3)
    return float(np.sum((np.asarray(err) / sig) ** 2))


CHI2_6DOF_99 = 16.8       # 99% of a chi-squared with 6 degrees of freedom


def optimise(c2ws: list[np.ndarray], edges: list[Edge], max_iterations: int = 100) -> tuple[list[np.ndarray], list[int]]:
    """(keyframe c2w poses after optimising the graph, the loop edges found inconsistent).

    A verified loop is first trusted with its Gaussian noise (a robust kernel from the start would
    refuse the large correction a real loop after long drift asks for). If the result then
    contradicts any edge (error beyond the 99% chi-squared bound in its own sigmas: loops that
    disagree with each other bend the odometry), every loop edge gets a Cauchy kernel and the
    graph is solved again from that result, so a wrong loop pulls with bounded force; the loops
    the robust solution still contradicts are returned as inconsistent."""
    if gtsam is None:
        raise RuntimeError("loop closure needs gtsam: pip install gtsam")
    result = _solve(c2ws, edges, set(), max_iterations)
    loops = {n for n, e in enumerate(edges) if e.robust}
    if loops and max(edge_chi2(result, e) for e in edges) > CHI2_6DOF_99:
        start = [np.asarray(result.atPose3(k).matrix(), np.float64) for k in range(len(c2ws))]
        result = _solve(start, edges, loops, max_iterations)
        inconsistent = sorted(n for n in loops if edge_chi2(result, edges[n]) > CHI2_6DOF_99)
    else:
        inconsistent = []
    return [np.asarray(result.atPose3(k).matrix(), np.float64) for k in range(len(c2ws))], inconsistent


def odometry_edge(a: int, b: int, c2w_a: np.ndarray, c2w_b: np.ndarray, sigma_m: float, sigma_rel: float,
                  sigma_deg: float) -> Edge:
    rel = np.linalg.inv(c2w_a) @ c2w_b
    return Edge(a, b, rel, sigma_m + sigma_rel * float(np.linalg.norm(rel[:3, 3])), sigma_deg)
