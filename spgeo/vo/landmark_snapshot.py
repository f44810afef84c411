"""The map's landmarks as the tracker sees them (issue 51): a compact copy of the
back end's :class:`~spgeo.vo.landmarks.LandmarkMap` that every mapping update
carries to the tracker (:attr:`spgeo.vo.backend.MappingUpdate.snapshot`), so that a
frame the photometric tracker cannot place finds its pose in the map it came from:
its features matched with the landmarks' descriptors (the whole snapshot, not one
keyframe's features), a RANSAC PnP pose in the map's frame and scale
(:func:`~spgeo.vo.feature_retry.pnp_pose`), which the tracking decision refines
(:class:`~spgeo.vo.frame_tracker.FrameTracker`).

World points in the map's frame and units (the smoothed positions after the
update), the descriptor of each landmark's latest observation (the landmark
map's feature type), and the keyframe that last saw it.  At most ``max_points``
landmarks, the most recently seen: a bounded copy per update (about 0.6 kB a
SIFT landmark).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..twoview import FeatureOptions
from ..twoview.backends import ratio_matches
from .feature_retry import FeaturePose, FeatureRetryConfig, pnp_pose

__all__ = ["LandmarkSnapshot"]


@dataclass
class LandmarkSnapshot:
    """The landmarks of a map segment (module docstring).

    Attributes:
        segment: the map segment they belong to.
        points: (N, 3) world points (map frame and units).
        descriptors: (N, D) descriptors (SIFT: uint8 of their whole-number values;
            ORB: uint8 bytes).
        keyframes: (N,) index of the keyframe that last saw each.
        features: the descriptors' :class:`~spgeo.twoview.FeatureOptions`
            (their type; frames must be described alike to match).
    """

    segment: int
    points: np.ndarray
    descriptors: np.ndarray
    keyframes: np.ndarray
    features: FeatureOptions

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def of(cls, lmap, segment: int, max_points: int) -> "LandmarkSnapshot":
        """The snapshot of the :class:`~spgeo.vo.landmarks.LandmarkMap` ``lmap``
        of map segment ``segment``: its ``max_points`` most recently seen
        landmarks (ties: the newest first)."""
        lms = sorted(lmap.landmarks.values(), key=lambda lm: (-lm.last_seen, -lm.id))
        lms = lms[:max_points]
        dim = 128 if lmap.config.features.features == "sift" else 32
        desc = (np.array([lm.descriptor for lm in lms]) if lms
                else np.zeros((0, dim), np.float32))
        return cls(int(segment), np.array([lm.point for lm in lms], np.float64).reshape(-1, 3),
                   np.round(desc).astype(np.uint8), np.array([lm.last_seen for lm in lms],
                                                             np.int64),
                   lmap.config.features)

    def matches(self, descriptors: Optional[np.ndarray], features: FeatureOptions) -> np.ndarray:
        """(M, 2) pairs ``(landmark, frame feature)`` of the ratio test
        (:func:`~spgeo.twoview.backends.ratio_matches` with the snapshot's
        options) against a frame's ``descriptors`` of type ``features``; none
        when the feature types differ."""
        if descriptors is None or features.features != self.features.features:
            return np.zeros((0, 2), np.int64)
        return ratio_matches(self.descriptors, descriptors, self.features)

    def pose(self, frame_features: Tuple[np.ndarray, Optional[np.ndarray]],
             features: FeatureOptions, camera: PinholeCamera, config: FeatureRetryConfig
             ) -> Optional[FeaturePose]:
        """A frame's pose in the map from its ``frame_features`` ``(pixels (M, 2),
        descriptors)`` of type ``features`` in ``camera``: :meth:`matches`, then
        :func:`~spgeo.vo.feature_retry.pnp_pose` with ``config``; None with too
        few inliers."""
        pixels, desc = frame_features
        pairs = self.matches(desc, features)
        return pnp_pose(self.points[pairs[:, 0]], np.asarray(pixels)[pairs[:, 1]], camera,
                        config)
