"""Loop closure for the monocular VO (issue 23, docs/design.md §5.2): a keyframe
database with place recognition, Sim(3) geometric verification of candidates, a
Sim(3) pose graph over the keyframes, and :class:`LoopCloser` that drives them.

Sim(3) convention (:mod:`spgeo.similarity`): ``S_a_b`` maps ``x_b`` to
``x_a = s R x_b + t``, a 4x4 ``[[s R, t], [0, 1]]``.
"""
from .config import LoopClosureConfig, PlaceRecognitionConfig, PoseGraphConfig, VerificationConfig
from .closer import LoopCloser, LoopClosure, LoopCorrection
from .database import Candidate, DatabaseEntry, KeyframeDatabase
from .pose_graph import PoseGraphResult, Sim3Edge, odometry_edges, optimise_sim3_pose_graph
from .verify import (KeyframeFeatures, Sim3Verification, count_inliers, extract_features,
                     match_features, verify_sim3)

__all__ = [
    "LoopCloser", "LoopClosure", "LoopCorrection", "Candidate", "DatabaseEntry",
    "KeyframeDatabase", "KeyframeFeatures", "Sim3Verification", "count_inliers",
    "extract_features", "match_features", "verify_sim3",
    "LoopClosureConfig", "PlaceRecognitionConfig", "PoseGraphConfig", "VerificationConfig",
    "PoseGraphResult", "Sim3Edge", "odometry_edges", "optimise_sim3_pose_graph",
]
