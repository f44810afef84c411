"""Sparse landmarks of the VO: long-range geometric constraints (issue 30).

Each keyframe's SIFT / ORB features (:func:`spgeo.twoview.backends.opencv_features`,
at the processing size) are associated, in order:

1. with the remembered landmarks that project into the new keyframe (its tracked
   pose): descriptor ratio matches (:func:`~spgeo.twoview.backends.ratio_matches`)
   whose pixel lies within ``search_px`` of the landmark's projection;
2. with the features of the last ``match_keyframes`` live keyframes: a match whose
   older feature already observes a landmark adds an observation (same gate); two
   unassigned features are triangulated (:func:`spgeo.triangulation.triangulate`,
   linear DLT) into a new landmark when the rays' parallax is at least
   ``min_parallax_deg``, the point is in front of both cameras and reprojects
   within ``max_reprojection_px``.

Landmarks are world points (the VO map's frame and arbitrary monocular units)
with an id, a descriptor (the latest observation's), their observations in the
live keyframes (keyframe index -> pixel) and the last keyframe that saw them.
Memory is bounded: a landmark not seen for ``memory_keyframes`` keyframes is
forgotten, and at most ``max_landmarks`` (the most recently seen) are kept; the
features of a keyframe are dropped when it leaves the window.

The window smoother (:class:`spgeo.vo.smoother.WindowMapper`) turns them into
GTSAM ``GenericProjectionFactorCal3_S2`` factors (Huber kernel, pixels) on the
live keyframes' poses, and gives a remembered landmark that re-enters the window
a prior at its position (sigma ``prior_sigma`` x the keyframe's median depth):
the landmark ties the present keyframe to the map it was built in.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..geometry import invert_pose, transform_points
from ..similarity import moved_frame
from ..triangulation import triangulate
from ..twoview import FeatureOptions, to_gray_uint8
from ..twoview.backends import opencv_features, ratio_matches

__all__ = ["LandmarkConfig", "Landmark", "LandmarkMap"]

log = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class LandmarkConfig:
    """Parameters of the sparse landmarks (:class:`LandmarkMap`) and their factors.

    Attributes:
        enabled: track landmarks and add their factors to the window (default True:
            docs/results.md, issue 30).
        features: feature type, count and matching (default 1000 SIFT features).
        match_keyframes: live keyframes the new one is matched with for new
            landmarks (default 3: with 2 the KITTI clip loses 9 frames).
        min_parallax_deg: least angle between the two rays of a new landmark (1.0).
        max_reprojection_px: reprojection bound of a new landmark in both views (2.0).
        search_px: re-observation gate: pixel distance of a match from the
            landmark's projection with the tracked pose (default 15).
        pixel_sigma: sigma of a projection factor, pixels (default 1.0).
        huber_px: Huber threshold of a projection factor, pixels (default 2.0).
        max_factors: the most landmarks of a keyframe given factors in the window
            (the longest-known first; default 1000).
        prior_sigma: sigma of the prior of a remembered landmark re-entering the
            window, as a fraction of the observing keyframe's median depth (0.02).
        memory_keyframes: keyframes a landmark is kept without being seen (100).
        max_landmarks: the most landmarks kept (default 20000).
        snapshot_landmarks: the most landmarks (the most recently seen) each
            mapping update carries to the tracker for its feature poses and
            relocalisation (:class:`~spgeo.vo.landmark_snapshot.LandmarkSnapshot`;
            default 3000: a few keyframes' worth, docs/results.md issue 51).
    """

    enabled: bool = True
    features: FeatureOptions = field(default_factory=lambda: FeatureOptions(max_features=1000))
    match_keyframes: int = 3
    min_parallax_deg: float = 1.0
    max_reprojection_px: float = 2.0
    search_px: float = 15.0
    pixel_sigma: float = 1.0
    huber_px: float = 2.0
    max_factors: int = 1000
    prior_sigma: float = 0.02
    memory_keyframes: int = 100
    max_landmarks: int = 20000
    snapshot_landmarks: int = 3000

    def __post_init__(self) -> None:
        if (self.match_keyframes < 1 or not self.pixel_sigma > 0 or not self.huber_px > 0
                or not self.prior_sigma > 0 or self.memory_keyframes < 1
                or self.max_landmarks < 1 or self.max_factors < 1 or self.snapshot_landmarks < 0
                or not self.max_reprojection_px > 0):
            raise ValueError(f"LandmarkConfig: invalid values {self}")


@dataclass
class Landmark:
    """A world point with its live observations (keyframe index -> (2,) pixel)."""

    id: int
    point: np.ndarray
    descriptor: np.ndarray
    observations: Dict[int, np.ndarray]
    last_seen: int
    first_seen: int


@dataclass
class _KeyframeFeatures:
    pixels: np.ndarray          # (N, 2)
    descriptors: Optional[np.ndarray]
    landmark: np.ndarray        # (N,) landmark id or -1
    T_world_kf: np.ndarray


class LandmarkMap:
    """The landmarks of one :class:`~spgeo.vo.Odometry` (module docstring).

    Args:
        camera: the processing camera (images passed to :meth:`add_keyframe`).
        config: :class:`LandmarkConfig`.
    """

    def __init__(self, camera: PinholeCamera, config: LandmarkConfig) -> None:
        self.camera = camera
        self.config = config
        self.K = np.asarray(camera.K, dtype=np.float64)
        self.landmarks: Dict[int, Landmark] = {}
        self._features: Dict[int, _KeyframeFeatures] = {}
        self._next_id = 0
        self.created: List[int] = []      # ids created by the last add_keyframe
        self.stats: List[dict] = []

    def clear(self) -> None:
        """Forget every landmark and keyframe feature (a new map segment)."""
        self.landmarks.clear()
        self._features.clear()
        self.created = []

    # ------------------------------------------------------------ association
    def add_keyframe(self, k: int, image: np.ndarray, T_world_kf: np.ndarray,
                     live: Sequence[int]) -> None:
        """Detect keyframe ``k``'s features (``image`` at the processing size, pose
        ``T_world_kf`` camera-to-world), associate them with remembered landmarks
        and the last ``match_keyframes`` of ``live`` (keyframe indices of the
        window, older than ``k``), triangulate new landmarks; then forget the
        features of keyframes not in ``live`` and landmarks out of memory."""
        t0 = time.perf_counter()
        pts, desc = opencv_features(to_gray_uint8(image), self.config.features)
        T = np.asarray(T_world_kf, dtype=np.float64)
        feats = _KeyframeFeatures(pts, desc, np.full(len(pts), -1, np.int64), T)
        self._features[k] = feats
        n_old = self._reobserve(k, feats)
        self.created = []
        n_link = 0
        for j in [j for j in live if j in self._features and j != k][-self.config.match_keyframes:][::-1]:
            n_link += self._match_pair(k, feats, j, self._features[j])
        self._forget(k, set(live) | {k})
        self.stats.append({"keyframe": k, "features": len(pts), "reobserved": n_old,
                           "linked": n_link, "created": len(self.created),
                           "landmarks": len(self.landmarks),
                           "seconds": time.perf_counter() - t0})

    def _observe(self, lm: Landmark, k: int, feats: _KeyframeFeatures, i: int) -> None:
        lm.observations[k] = feats.pixels[i].copy()
        lm.descriptor = feats.descriptors[i].copy()
        lm.last_seen = k
        feats.landmark[i] = lm.id

    def _project(self, T_world_kf: np.ndarray, X: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths (N,) of world points ``X`` (N, 3) in the camera at
        ``T_world_kf`` (NaN pixels behind it)."""
        return self.camera.project(transform_points(invert_pose(T_world_kf), X))

    def _gate(self, T: np.ndarray, X: np.ndarray, px: np.ndarray, tol: float) -> np.ndarray:
        uv, z = self._project(T, X)
        return (z > 0) & (np.linalg.norm(uv - px, axis=1) <= tol)

    def _reobserve(self, k: int, feats: _KeyframeFeatures) -> int:
        """Matches of remembered landmarks that project into keyframe ``k``."""
        if not self.landmarks or feats.descriptors is None or not len(feats.pixels):
            return 0
        lms = list(self.landmarks.values())
        X = np.array([lm.point for lm in lms])
        uv, z = self._project(feats.T_world_kf, X)
        m = self.config.search_px
        vis = (z > 0) & (uv[:, 0] > -m) & (uv[:, 1] > -m) & \
            (uv[:, 0] < self.camera.width + m) & (uv[:, 1] < self.camera.height + m)
        if np.any(feats.landmark >= 0):     # a second pass (:meth:`reobserve`)
            vis &= np.array([k not in lm.observations for lm in lms])
        idx = np.flatnonzero(vis)
        if len(idx) < 2:
            return 0
        D = np.array([lms[i].descriptor for i in idx])
        pairs = ratio_matches(D, feats.descriptors, self.config.features)
        if len(pairs):     # features already associated stay so
            pairs = pairs[feats.landmark[pairs[:, 1]] < 0]
        if not len(pairs):
            return 0
        near = np.linalg.norm(uv[idx[pairs[:, 0]]] - feats.pixels[pairs[:, 1]], axis=1) <= m
        for a, b in pairs[near]:
            self._observe(lms[idx[a]], k, feats, int(b))
        return int(np.count_nonzero(near))

    def _match_pair(self, k: int, fk: _KeyframeFeatures, j: int, fj: _KeyframeFeatures) -> int:
        """Observations and new landmarks from the matches of keyframes ``k`` and ``j``."""
        cfg = self.config
        pairs = ratio_matches(fj.descriptors, fk.descriptors, cfg.features)
        pairs = pairs[fk.landmark[pairs[:, 1]] < 0] if len(pairs) else pairs
        n_link = 0
        known = pairs[fj.landmark[pairs[:, 0]] >= 0] if len(pairs) else pairs
        for a, b in known:
            lm = self.landmarks.get(int(fj.landmark[a]))
            if lm is not None and k not in lm.observations and self._gate(
                    fk.T_world_kf, lm.point[None], fk.pixels[b][None], cfg.search_px)[0]:
                self._observe(lm, k, fk, int(b))
                n_link += 1
        new = pairs[fj.landmark[pairs[:, 0]] < 0] if len(pairs) else pairs
        if not len(new):
            return n_link
        X = triangulate(self.camera, [fj.T_world_kf, fk.T_world_kf],
                        np.stack([fj.pixels[new[:, 0]], fk.pixels[new[:, 1]]], 1),
                        cfg.max_reprojection_px, cfg.min_parallax_deg)
        ok = np.all(np.isfinite(X), 1)
        for (a, b), P in zip(new[ok], X[ok]):
            lm = Landmark(self._next_id, P, fk.descriptors[b].copy(),
                          {j: fj.pixels[a].copy()}, j, j)
            self._next_id += 1
            self.landmarks[lm.id] = lm
            fj.landmark[a] = lm.id
            self._observe(lm, k, fk, int(b))
            self.created.append(lm.id)
        return n_link

    def _forget(self, k: int, live: set) -> None:
        """Drop features of keyframes not in ``live``, observations in them, and
        landmarks out of memory.  (Every observation of a landmark in keyframe ``j``
        is marked in ``j``'s features, and only live keyframes keep features.)"""
        for j in [j for j in self._features if j not in live]:
            ids = self._features.pop(j).landmark
            for lid in ids[ids >= 0].tolist():
                lm = self.landmarks.get(lid)
                if lm is not None:
                    lm.observations.pop(j, None)
        horizon = k - self.config.memory_keyframes
        for lid in [lid for lid, lm in self.landmarks.items() if lm.last_seen < horizon]:
            del self.landmarks[lid]
        extra = len(self.landmarks) - self.config.max_landmarks
        if extra > 0:
            order = sorted(self.landmarks.values(), key=lambda lm: (lm.last_seen, lm.id))
            for lm in order[:extra]:
                del self.landmarks[lm.id]

    def reobserve(self, k: int) -> int:
        """Associate live keyframe ``k``'s features that observe no landmark with the
        remembered landmarks it does not observe yet, at its current pose (after a
        loop correction moved it and the map); returns how many."""
        f = self._features.get(k)
        return 0 if f is None else self._reobserve(k, f)

    def apply_similarity(self, W_new_old: Dict[int, np.ndarray]) -> None:
        """Move the map by a loop correction: each landmark by the world similarity
        (4x4, ``S_world_kf(new) @ inv(T_world_kf(old))``) of the last keyframe that saw
        it, each live keyframe's pose by its own (:func:`spgeo.similarity.moved_frame`);
        landmarks and keyframes without one stay."""
        for lm in self.landmarks.values():
            W = W_new_old.get(lm.last_seen)
            if W is not None:
                lm.point = W[:3, :3] @ lm.point + W[:3, 3]
        for j, f in self._features.items():
            if j in W_new_old:
                f.T_world_kf = moved_frame(W_new_old[j], f.T_world_kf)

    # ------------------------------------------------------------ queries
    def observed_in(self, k: int) -> List[Landmark]:
        """Landmarks observed in keyframe ``k`` (live)."""
        f = self._features.get(k)
        if f is None:
            return []
        ids = f.landmark[f.landmark >= 0]
        return [self.landmarks[int(i)] for i in ids if int(i) in self.landmarks]

    def set_pose(self, k: int, T_world_kf: np.ndarray) -> None:
        """The smoothed pose of live keyframe ``k`` (for the next triangulations)."""
        f = self._features.get(k)
        if f is not None:
            f.T_world_kf = np.asarray(T_world_kf, dtype=np.float64)

    def report(self) -> dict:
        """Counts (JSON-ready): landmarks kept, and the per-keyframe statistics' totals."""
        tot = {key: int(sum(s[key] for s in self.stats))
               for key in ("reobserved", "linked", "created")}
        secs = [s["seconds"] for s in self.stats]
        return {"landmarks": len(self.landmarks), **tot, "keyframes": len(self.stats),
                "seconds_per_keyframe": float(np.mean(secs)) if secs else None}


def add_landmark_factors(batch, lmap: LandmarkMap, k: int, poses_in: set, lms_in: set,
                         median_depth: float) -> int:
    """Projection factors of keyframe ``k``'s landmarks into a smoother update.

    Args:
        batch: the update's :class:`~spgeo.graph.builders.FactorBatch` (its values,
            factors and timestamps receive the landmarks, each stamped with its
            first live observer, so that it leaves the window with it).
        lmap: the :class:`LandmarkMap` (``k`` just added).
        k: the new keyframe (its pose key in the smoother or in ``batch``).
        poses_in: keyframe indices whose pose is in the smoother or in ``batch``.
        lms_in: ids of the landmarks in the smoother (updated in place).
        median_depth: the new keyframe's median depth (prior sigma unit).
    Returns:
        The number of projection factors added.
    """
    import gtsam

    from ..graph.builders import projection_model
    from ..graph.keys import landmark_key, pose_key

    cfg = lmap.config
    cal, noise = projection_model(lmap.K, cfg.pixel_sigma, cfg.huber_px)
    created = set(lmap.created)
    n = 0
    seen = sorted(lmap.observed_in(k), key=lambda lm: (lm.first_seen, lm.id))
    for lm in seen[:cfg.max_factors]:
        key = landmark_key(lm.id)
        if lm.id in lms_in:
            obs = {k: lm.observations[k]}
        else:
            old = lm.id not in created
            obs = {k: lm.observations[k]} if old else lm.observations
            if not old and sum(j in poses_in for j in obs) < 2:
                continue   # one view of a new point: no depth, an indeterminate variable
            t = min([j for j in obs if j in poses_in] + [k])
            batch.insert(key, gtsam.Point3(*lm.point), t)
            if old:    # remembered: anchored where the old map put it
                sigma = cfg.prior_sigma * float(median_depth)
                batch.graph.add(gtsam.PriorFactorPoint3(
                    key, gtsam.Point3(*lm.point), gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
            lms_in.add(lm.id)
        for j, px in sorted(obs.items()):
            if j in poses_in:       # px: a (2,) float64 array, gtsam's Point2
                batch.graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    px, noise, pose_key(j), key, cal))
                n += 1
    return n


def read_landmarks(lmap: LandmarkMap, est, lms_in: set) -> None:
    """Landmark points from a smoother estimate ``est``; ``lms_in`` becomes the ids
    still in it."""
    from ..graph.keys import landmark_key

    keys = {lid: landmark_key(lid) for lid in lms_in}
    keep = [lid for lid, key in keys.items() if est.exists(key)]
    lms_in.intersection_update(keep)
    lms = [(lmap.landmarks.get(lid), keys[lid]) for lid in keep]
    lms = [(lm, key) for lm, key in lms if lm is not None]
    if not lms:
        return
    P = np.array([est.atPoint3(key) for _, key in lms], dtype=np.float64).reshape(-1, 3)
    for (lm, _), p, ok in zip(lms, P, np.all(np.isfinite(P), axis=1)):
        if ok:
            lm.point = p
