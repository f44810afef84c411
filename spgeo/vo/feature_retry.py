"""Feature-based pose of a frame against a keyframe: the tracker's retry after a
photometric failure under large inter-frame motion, and its check of a
photometric pose the cost alone would refuse.

Photometric tracking converges only from a pose within its basin (a few
pixels at the coarsest level).  When the motion model's guess is outside it
(fast forward motion, a jolt), SIFT/ORB features of the keyframe image,
lifted to 3-D with the keyframe's primitive depth, are matched with the
frame's, and a RANSAC PnP gives a pose in the map's scale that the
photometric tracker then refines (docs/design.md §5).

The same matches judge a photometric pose (:meth:`FeaturePose.support`): under
fast forward motion past high-contrast texture at grazing angles (a street's
facades) the photometric cost of the right pose exceeds the tracker's
``max_relative_cost`` one or two frames after a keyframe, while the pose still
reprojects the matched features as well as the PnP pose does (issue 38).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from ..configs import config_class
from ..camera import PinholeCamera
from ..geometry import invert_pose, transform_points
from ..primitives import PrimitiveSet
from ..twoview import FeatureOptions, to_gray_uint8
from ..twoview.backends import opencv_features, ratio_matches

__all__ = ["FeatureRetryConfig", "FeaturePose", "FeatureRetry", "pnp_pose"]

log = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class FeatureRetryConfig:
    """Parameters of :class:`FeatureRetry`.

    Attributes:
        enabled: try the feature-based pose when photometric tracking fails
            (default True).
        features: feature type, count and matching
            (:class:`~spgeo.twoview.FeatureOptions`; default 1500 SIFT features).
        min_inliers: PnP inliers needed to accept a pose (default 25).
        reprojection_px: RANSAC inlier threshold (pixels of the frame's
            image, default 2.0).
        ransac_iterations: RANSAC iteration cap (default 500).
        min_agreement: a photometric pose refused only for its cost
            (``"high_cost"``) is kept when it reprojects at least this share of
            the PnP pose's inlier count within ``reprojection_px`` (and at
            least ``min_inliers``); >= 0, default 0.8 (docs/results.md, issue
            38); None: never kept at the photometric pose (the PnP pose of most
            inliers is kept instead, :class:`~spgeo.vo.frame_tracker.FrameTracker`).
    """

    enabled: bool = True
    features: FeatureOptions = field(default_factory=lambda: FeatureOptions(max_features=1500))
    min_inliers: int = 25
    reprojection_px: float = 2.0
    ransac_iterations: int = 500
    min_agreement: Optional[float] = 0.8

    def __post_init__(self) -> None:
        if (self.min_inliers < 4 or not self.reprojection_px > 0 or self.ransac_iterations < 1
                or not (self.min_agreement is None or self.min_agreement >= 0)):
            raise ValueError("FeatureRetryConfig: need min_inliers >= 4, reprojection_px > 0, "
                             f"ransac_iterations >= 1 and min_agreement >= 0, got {self}")


@dataclass
class FeaturePose:
    """A frame's PnP pose against a keyframe and the matches it came from.

    Attributes:
        T_world_frame: the PnP camera-to-world pose (4, 4).
        inliers: its RANSAC inlier count.
        points_world: (M, 3) world points of the matched keyframe features
            (lifted with the keyframe's primitive depth; map units).
        pixels: (M, 2) the matched frame features (pixels of the frame).
    """

    T_world_frame: np.ndarray
    inliers: int
    points_world: np.ndarray
    pixels: np.ndarray

    def support(self, T_world_frame: np.ndarray, camera: PinholeCamera, tol_px: float) -> int:
        """How many matches the pose ``T_world_frame`` reprojects within
        ``tol_px`` pixels (points behind the camera count as misses)."""
        uv, z = camera.project(transform_points(
            invert_pose(np.asarray(T_world_frame, dtype=np.float64)), self.points_world))
        return int(np.count_nonzero((z > 0) & (np.linalg.norm(uv - self.pixels, axis=1)
                                                <= tol_px)))

    def agrees(self, T_world_frame: np.ndarray, camera: PinholeCamera,
               config: "FeatureRetryConfig") -> bool:
        """Whether ``T_world_frame`` reprojects at least ``config.min_agreement``
        of :attr:`inliers` (and ``config.min_inliers``) within ``reprojection_px``
        (never with ``min_agreement`` None)."""
        if config.min_agreement is None:
            return False
        n = self.support(T_world_frame, camera, config.reprojection_px)
        return n >= config.min_inliers and n >= config.min_agreement * self.inliers


@dataclass
class _KeyframeFeatures:
    primitives: PrimitiveSet  # the shapes the points were lifted with
    points: np.ndarray  # (N, 3) keyframe-camera points of the features (NaN: no depth)
    descriptors: Optional[np.ndarray]


class FeatureRetry:
    """Feature-based ``T_world_frame`` guesses against keyframes (features of
    each keyframe computed once and cached by its key).

    Args:
        camera: camera of the images passed to :meth:`guess`.
        config: :class:`FeatureRetryConfig`.
        capacity: the most keyframes whose features are cached (those of the
            highest keys are kept; default None: every one).
    """

    def __init__(self, camera: PinholeCamera, config: FeatureRetryConfig = FeatureRetryConfig(),
                 capacity: Optional[int] = None) -> None:
        self.camera = camera
        self.config = config
        self.capacity = capacity
        self._cache: Dict[int, _KeyframeFeatures] = {}

    def _features(self, image: np.ndarray) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        return opencv_features(to_gray_uint8(image), self.config.features)

    def _keyframe_features(self, key: int, image: np.ndarray, primitives: PrimitiveSet
                           ) -> _KeyframeFeatures:
        cached = self._cache.get(key)
        if cached is not None and cached.primitives is primitives:
            return cached
        pts, desc = self._features(image)
        depth, depth_camera = primitives.depth_map(), primitives.camera
        # feature pixel (image camera) -> depth-camera pixel (pixel centres at integers)
        sx = depth_camera.width / self.camera.width
        sy = depth_camera.height / self.camera.height
        u = (pts[:, 0] + 0.5) * sx - 0.5
        v = (pts[:, 1] + 0.5) * sy - 0.5
        ui = np.clip(np.round(u).astype(np.int64), 0, depth_camera.width - 1)
        vi = np.clip(np.round(v).astype(np.int64), 0, depth_camera.height - 1)
        z = depth[vi, ui] if len(pts) else np.zeros(0)
        ok = np.isfinite(z) & (z > 0)
        X = np.stack([(u - depth_camera.cx) / depth_camera.fx * z,
                      (v - depth_camera.cy) / depth_camera.fy * z, z], 1)
        points = np.where(ok[:, None], X, np.nan)
        feats = _KeyframeFeatures(primitives, points, desc)
        self._cache[key] = feats
        if self.capacity is not None and len(self._cache) > self.capacity:
            self.forget(set(sorted(self._cache)[-self.capacity:]))
        return feats

    def forget(self, keep: set) -> None:
        """Drop the cached features of keyframes whose key is not in ``keep``."""
        for k in [k for k in self._cache if k not in keep]:
            del self._cache[k]

    def guess(self, key: int, kf_image: np.ndarray, primitives: PrimitiveSet,
              T_world_kf: np.ndarray, image: np.ndarray) -> Optional[np.ndarray]:
        """``T_world_frame`` of :meth:`pose` (arguments there), or None."""
        found = self.pose(key, kf_image, primitives, T_world_kf, image)
        return None if found is None else found.T_world_frame

    def frame_features(self, image: np.ndarray) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        """``(pixels (N, 2), descriptors)`` of a frame (size of ``camera``) with
        this retry's feature options."""
        return self._features(image)

    def pose(self, key: int, kf_image: np.ndarray, primitives: PrimitiveSet,
             T_world_kf: np.ndarray, image: np.ndarray,
             frame_features: Optional[Tuple[np.ndarray, Optional[np.ndarray]]] = None
             ) -> Optional[FeaturePose]:
        """The PnP pose of ``image`` on the keyframe's features.

        Args:
            key: the keyframe's cache key (its features are recomputed when
                ``primitives`` is another object than at the last call).
            kf_image: the keyframe's image (size of ``camera``).
            primitives: the keyframe's scaled primitives (their depth map lifts
                the features to 3-D; any resolution of the same view).
            T_world_kf: the keyframe's camera-to-world pose.
            image: the frame (size of ``camera``).
            frame_features: the frame's :meth:`frame_features`, when already
                computed (default None: computed here).
        Returns:
            :class:`FeaturePose`, or None with too few PnP inliers.
        """
        cfg = self.config
        kf = self._keyframe_features(key, kf_image, primitives)
        pts, desc = frame_features if frame_features is not None else self._features(image)
        pairs = ratio_matches(kf.descriptors, desc, cfg.features)
        if len(pairs):
            pairs = pairs[np.isfinite(kf.points[pairs[:, 0], 0])]
        T_world_kf = np.asarray(T_world_kf, dtype=np.float64)
        return pnp_pose(transform_points(T_world_kf, kf.points[pairs[:, 0]]),
                        pts[pairs[:, 1]], self.camera, cfg)


def pnp_pose(points_world: np.ndarray, pixels: np.ndarray, camera: PinholeCamera,
             config: FeatureRetryConfig) -> Optional[FeaturePose]:
    """The RANSAC PnP (EPnP minimal solver, ``config.reprojection_px`` inlier
    threshold, ``config.ransac_iterations``) camera-to-world pose of a frame whose
    pixels ``pixels`` (M, 2) see the world points ``points_world`` (M, 3): a
    :class:`FeaturePose` over the M matches, or None with fewer than
    ``config.min_inliers`` matches or inliers (the one PnP of the VO's feature
    poses: keyframe features and map landmarks)."""
    import cv2

    n = len(points_world)
    if n < config.min_inliers:
        log.debug("feature pose: %d matches with a 3-D point", n)
        return None
    X = np.ascontiguousarray(points_world, dtype=np.float64)
    uv = np.ascontiguousarray(pixels, dtype=np.float64)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        X, uv, camera.K.astype(np.float64), None,
        iterationsCount=int(config.ransac_iterations),
        reprojectionError=float(config.reprojection_px), confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP)
    n_in = 0 if inliers is None else len(inliers)
    if not ok or n_in < config.min_inliers:
        log.debug("feature pose: %d PnP inliers of %d matches", n_in, n)
        return None
    T_frame_world = np.eye(4)
    T_frame_world[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_frame_world[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(T_frame_world)):
        return None
    return FeaturePose(invert_pose(T_frame_world), n_in, X, uv)
