"""Online loop closure: detection from our own data (detect.py), strict geometric verification
(verify.py), a gtsam pose graph (pose_graph.py), Gaussians that follow their birth keyframe's
correction (anchors.py); closer.py runs them after each keyframe. docs/loop-closure.md."""

from .closer import LoopClosure

__all__ = ["LoopClosure"]
