"""Options of loop closure (:mod:`spgeo.loop`): place recognition, geometric
verification, the Sim(3) pose graph, and :class:`LoopClosureConfig` that nests them."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Tuple

from ..configs import config_class
from ..twoview.config import FeatureOptions

__all__ = ["PlaceRecognitionConfig", "VerificationConfig", "PoseGraphConfig",
           "LoopClosureConfig"]


@config_class
@dataclass(frozen=True)
class PlaceRecognitionConfig:
    """Keyframe database and candidate retrieval (:class:`spgeo.loop.KeyframeDatabase`).

    Attributes:
        features: feature type, count and matching
            (:class:`~spgeo.twoview.FeatureOptions`; default 1000 SIFT features).
        min_keyframe_gap: a keyframe is a candidate for a query only when its id is
            at most ``query id - min_keyframe_gap`` (recent keyframes are the
            odometry's business, not a loop).
        min_matches: descriptor matches (ratio test, mutual) a keyframe needs to be
            a candidate.
        max_candidates: candidates returned per query, most matches first.
    """

    features: FeatureOptions = field(default_factory=lambda: FeatureOptions(max_features=1000))
    min_keyframe_gap: int = 10
    min_matches: int = 30
    max_candidates: int = 3

    def __post_init__(self) -> None:
        if self.min_keyframe_gap < 1 or self.min_matches < 3 or self.max_candidates < 1:
            raise ValueError("PlaceRecognitionConfig: need min_keyframe_gap >= 1, "
                             f"min_matches >= 3, max_candidates >= 1, got {self}")


@config_class
@dataclass(frozen=True)
class VerificationConfig:
    """Geometric verification of a candidate (:func:`spgeo.loop.verify_sim3`) and its
    consistency check (:meth:`spgeo.loop.LoopCloser.add_keyframe`).

    Attributes:
        reprojection_px: a match is an inlier of ``S_cand_query`` when the query
            point, mapped into the candidate, reprojects within this many pixels of
            the candidate's keypoint, and the candidate point, mapped back, within
            this many pixels of the query's keypoint (also the PnP RANSAC threshold).
        depth_tolerance: ... and the mapped query point's depth agrees with the
            candidate point's depth to ``|log ratio| <=`` this.
        ransac_iterations: PnP RANSAC iterations (OpenCV's, deterministic).
        min_inliers: inliers needed to accept.
        min_inlier_ratio: inliers over the matches that have depth in both keyframes
            needed to accept.
        neighbour_radius: keyframes with ids within this distance of the candidate
            (older than the query's gap too) are its neighbours.
        min_neighbour_support: neighbours that must agree with the loop: the
            candidate's ``S_cand_query``, carried to the neighbour by the odometry's
            poses, must explain at least ``min_neighbour_inliers`` of the query's
            matches with that neighbour. 0 switches the check off.
        min_neighbour_inliers: see ``min_neighbour_support``.
        consistent_detections: a loop is accepted when this many consecutive query
            keyframes each verified a loop to candidates within ``neighbour_radius``
            of each other (all their edges enter the pose graph); 1 accepts at once.
    """

    reprojection_px: float = 3.0
    depth_tolerance: float = 0.05
    ransac_iterations: int = 300
    min_inliers: int = 30
    min_inlier_ratio: float = 0.5
    neighbour_radius: int = 2
    min_neighbour_support: int = 1
    min_neighbour_inliers: int = 15
    consistent_detections: int = 2

    def __post_init__(self) -> None:
        if (not self.reprojection_px > 0 or not self.depth_tolerance > 0
                or self.ransac_iterations < 1 or self.min_inliers < 3
                or not 0 <= self.min_inlier_ratio <= 1 or self.neighbour_radius < 0
                or self.min_neighbour_support < 0 or self.min_neighbour_inliers < 3
                or self.consistent_detections < 1):
            raise ValueError(f"VerificationConfig: invalid values in {self}")


@config_class
@dataclass(frozen=True)
class PoseGraphConfig:
    """Sim(3) pose-graph optimisation (:func:`spgeo.loop.optimise_sim3_pose_graph`).

    Sigmas are ``(rotation rad, translation in the map's units, log-scale)`` of an
    edge's error in GTSAM's Similarity3 tangent space, used for edges that carry none.

    Attributes:
        odometry_sigmas: sigmas of the odometry edges between consecutive keyframes.
        loop_sigmas: sigmas of loop edges that carry no information (the loop
            closer's edges carry their refinement's, :class:`~spgeo.loop.Sim3Edge`).
        loop_huber: Huber threshold (whitened units) on loop edges; 0 means none.
        gauge_sigma: sigma of the prior holding the first keyframe at its input pose
            and scale 1 (the gauge).
        max_iterations: Levenberg-Marquardt iteration cap.
        relative_error_tol: Levenberg-Marquardt relative error decrease to stop.
    """

    odometry_sigmas: Tuple[float, float, float] = (0.01, 0.01, 0.01)
    loop_sigmas: Tuple[float, float, float] = (0.01, 0.01, 0.01)
    loop_huber: float = 0.0
    gauge_sigma: float = 1e-6
    max_iterations: int = 100
    relative_error_tol: float = 1e-12

    def __post_init__(self) -> None:
        sig = tuple(self.odometry_sigmas) + tuple(self.loop_sigmas)
        if len(sig) != 6 or not all(s > 0 for s in sig) or not self.gauge_sigma > 0 \
                or self.loop_huber < 0 or self.max_iterations < 1:
            raise ValueError(f"PoseGraphConfig: invalid values in {self}")


@config_class
@dataclass(frozen=True)
class LoopClosureConfig:
    """Loop closure (:class:`spgeo.loop.LoopCloser`), docs/design.md §5.2.

    Attributes:
        enabled: whether the odometry runs loop closure (off by default).
        recognition: :class:`PlaceRecognitionConfig`.
        verification: :class:`VerificationConfig`.
        pose_graph: :class:`PoseGraphConfig`.
    """

    enabled: bool = False
    recognition: PlaceRecognitionConfig = field(default_factory=PlaceRecognitionConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
