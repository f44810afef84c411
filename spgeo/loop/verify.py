"""Keyframe features lifted to 3-D, and the geometric verification of a loop candidate:
PnP (RANSAC) of the candidate's 3-D points in the query image, the scale from the
query's depths, refined as a Sim(3) on reprojection in both images, scored by
reprojection in both images and depth agreement; the edge's information comes from
that refinement (docs/design.md §5.2).

Frames: a keyframe's points are in its camera frame, in its depth units; the
verified ``S_cand_query`` (convention of :mod:`spgeo.similarity`) maps query-camera
points into the candidate's camera, so its scale is the candidate's depth unit over
the query's (1 for a map without scale drift).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..camera import PinholeCamera
from ..similarity import sim3, sim3_inverse
from ..twoview import FeatureOptions, to_gray_uint8
from ..twoview.backends import opencv_features, ratio_matches
from .config import VerificationConfig
from .refine import refine_sim3, sim3_information

__all__ = ["KeyframeFeatures", "extract_features", "match_features", "Sim3Verification",
           "count_inliers", "verify_sim3"]

log = logging.getLogger(__name__)


@dataclass
class KeyframeFeatures:
    """Features of one keyframe image.

    Attributes:
        keypoints: (N, 2) pixel coordinates in ``camera`` (pixel centres at integers).
        descriptors: (N, D) OpenCV descriptors (float32 SIFT or uint8 ORB), or None.
        points: (N, 3) camera-frame points from the keyframe's depth (its depth units);
            rows of NaN where the depth is missing.
        camera: the camera of ``keypoints``.
    """

    keypoints: np.ndarray
    descriptors: Optional[np.ndarray]
    points: np.ndarray
    camera: PinholeCamera

    def scaled(self, factor: float) -> "KeyframeFeatures":
        """The same features with depths multiplied by ``factor`` (log-scale ``+= log factor``)."""
        return KeyframeFeatures(self.keypoints, self.descriptors, self.points * float(factor),
                                self.camera)


def extract_features(image: np.ndarray, camera: PinholeCamera, depth: np.ndarray,
                     config: FeatureOptions) -> KeyframeFeatures:
    """SIFT / ORB features of ``image`` lifted to 3-D with ``depth``.

    Args:
        image: (H, W[, 3]) image of ``camera``'s size (uint8 / uint16 / float in [0, 1]).
        camera: the image's pinhole camera.
        depth: (h, w) depth map of the same view at any resolution (z along the optical
            axis; NaN or <= 0 where unknown), e.g. the keyframe's primitive depth map.
        config: feature type and count (:class:`~spgeo.twoview.FeatureOptions`).
    Returns:
        :class:`KeyframeFeatures`.
    """
    image = camera.check_image(np.asarray(image), "image")
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"extract_features: depth must be (h, w), got shape {depth.shape}")
    pts, desc = opencv_features(to_gray_uint8(image), config)
    h, w = depth.shape
    u = (pts[:, 0] + 0.5) * w / camera.width - 0.5
    v = (pts[:, 1] + 0.5) * h / camera.height - 0.5
    ui = np.clip(np.round(u).astype(np.int64), 0, w - 1)
    vi = np.clip(np.round(v).astype(np.int64), 0, h - 1)
    z = depth[vi, ui] if len(pts) else np.zeros(0)
    ok = np.isfinite(z) & (z > 0)
    X = camera.unproject(pts, z)
    return KeyframeFeatures(pts, desc, np.where(ok[:, None], X, np.nan), camera)


def match_features(a: KeyframeFeatures, b: KeyframeFeatures, config: FeatureOptions
                   ) -> np.ndarray:
    """(M, 2) index pairs ``(index in a, index in b)`` passing the ratio test (and the
    mutual check when ``config.cross_check``)."""
    return ratio_matches(a.descriptors, b.descriptors, config)


@dataclass
class Sim3Verification:
    """Outcome of :func:`verify_sim3`.

    Attributes:
        accepted: enough inliers and inlier ratio.
        S_cand_query: 4x4 similarity from the query's camera (its depth units) to the
            candidate's camera (its units), or None without a model.
        n_matches: matches with depth in both keyframes.
        n_inliers: matches consistent with ``S_cand_query``.
        inlier_ratio: ``n_inliers / n_matches`` (0 without matches).
        inliers: (n_matches,) bool over the matches with depth (order of ``pairs``).
        reason: why it was rejected ("" when accepted).
        information: (7, 7) information of ``S_cand_query`` from its refinement
            (:func:`spgeo.loop.refine.sim3_information`, pixels), when accepted.
    """

    accepted: bool
    S_cand_query: Optional[np.ndarray]
    n_matches: int
    n_inliers: int
    inlier_ratio: float
    inliers: np.ndarray
    reason: str = ""
    information: Optional[np.ndarray] = None


def _reprojection(points: np.ndarray, camera: PinholeCamera, uv: np.ndarray) -> np.ndarray:
    """Pixel distance of ``points`` projected by ``camera`` from ``uv``; inf behind it."""
    proj, z = camera.project(points)
    err = np.hypot(proj[:, 0] - uv[:, 0], proj[:, 1] - uv[:, 1])
    return np.where(z > 0, err, np.inf)


def count_inliers(S_cand_query: np.ndarray, P_query: np.ndarray, P_cand: np.ndarray,
                  uv_query: np.ndarray, uv_cand: np.ndarray, cam_query: PinholeCamera,
                  cam_cand: PinholeCamera, config: VerificationConfig) -> np.ndarray:
    """(M,) bool: matches whose query point mapped by ``S_cand_query`` reprojects near the
    candidate keypoint with the candidate's depth, and whose candidate point mapped back
    reprojects near the query keypoint (thresholds of ``config``)."""
    S = np.asarray(S_cand_query, dtype=np.float64)
    in_cand = P_query @ S[:3, :3].T + S[:3, 3]
    Si = sim3_inverse(S)
    in_query = P_cand @ Si[:3, :3].T + Si[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        dlog = np.abs(np.log(in_cand[:, 2] / P_cand[:, 2]))
    ok = (_reprojection(in_cand, cam_cand, uv_cand) <= config.reprojection_px) \
        & (_reprojection(in_query, cam_query, uv_query) <= config.reprojection_px)
    return ok & np.nan_to_num(dlog <= config.depth_tolerance, nan=False)


def _pnp_model(P_q, P_c, uv_q, cam_q, config: VerificationConfig) -> Optional[np.ndarray]:
    """``S_cand_query`` from PnP: the candidate's points (its camera, its units) against
    the query's keypoints (OpenCV's EPnP RANSAC, ``reprojection_px``, deterministic),
    the scale from the PnP inliers' depths in the query over the query's own depths
    (median).  None without a model."""
    import cv2

    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            np.ascontiguousarray(P_c, np.float64), np.ascontiguousarray(uv_q, np.float64),
            np.asarray(cam_q.K, np.float64), None, iterationsCount=int(config.ransac_iterations),
            reprojectionError=float(config.reprojection_px), confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP)
    except cv2.error:
        return None
    if not ok or inl is None or len(inl) < 4:
        return None
    R = cv2.Rodrigues(rvec)[0]
    t = np.asarray(tvec, np.float64).ravel()
    idx = inl.ravel()
    ratio = (P_c[idx] @ R.T + t)[:, 2] / P_q[idx, 2]
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    if not len(ratio):
        return None
    return sim3(R.T, -R.T @ t, float(np.median(ratio)))


def _fit(args, config: VerificationConfig):
    """PnP model (:func:`_pnp_model`), its inliers (:func:`count_inliers`), then the model
    refined on them by reprojection in both images (:func:`refine_sim3`) and its
    inliers again.  Returns ``(S or None, inliers)``."""
    P_q, P_c, uv_q, uv_c, cam_q, cam_c = args
    S = _pnp_model(P_q, P_c, uv_q, cam_q, config)
    if S is None:
        return None, np.zeros(len(P_q), bool)
    inl = count_inliers(S, *args, config)
    for _ in range(2):
        if inl.sum() < 4:
            break
        S_ref = refine_sim3(S, P_q[inl], P_c[inl], uv_q[inl], uv_c[inl], cam_q, cam_c)
        if S_ref is None:
            break
        S, inl = S_ref, count_inliers(S_ref, *args, config)
    return S, inl


def verify_sim3(query: KeyframeFeatures, cand: KeyframeFeatures, pairs: np.ndarray,
                config: VerificationConfig = VerificationConfig()) -> Sim3Verification:
    """Relative Sim(3) of a loop candidate from feature matches with depth in both keyframes.

    Args:
        query, cand: the two keyframes' :class:`KeyframeFeatures`.
        pairs: (M, 2) matches ``(index in cand, index in query)``
            (:func:`match_features` of ``cand`` and ``query``).
        config: :class:`VerificationConfig` (thresholds, RANSAC iterations and seed).
    Returns:
        :class:`Sim3Verification`; accepted when ``n_inliers >= config.min_inliers`` and
        ``inlier_ratio >= config.min_inlier_ratio``.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    keep = np.isfinite(cand.points[pairs[:, 0], 0]) & np.isfinite(query.points[pairs[:, 1], 0])
    pairs = pairs[keep]
    m = len(pairs)
    if m < max(3, config.min_inliers):
        return Sim3Verification(False, None, m, 0, 0.0, np.zeros(m, bool), "too_few_matches")
    args = (query.points[pairs[:, 1]], cand.points[pairs[:, 0]], query.keypoints[pairs[:, 1]],
            cand.keypoints[pairs[:, 0]], query.camera, cand.camera)
    S, inl = _fit(args, config)
    n_in = int(inl.sum())
    ratio = n_in / m
    reason = ""
    if S is None:
        reason = "no_model"
    elif n_in < config.min_inliers:
        reason = "too_few_inliers"
    elif ratio < config.min_inlier_ratio:
        reason = "low_inlier_ratio"
    log.debug("loop verification: %d inliers of %d matches (%s)", n_in, m, reason or "accepted")
    info = None
    if not reason:
        info = sim3_information(S, *(a[inl] for a in args[:4]), *args[4:])
    return Sim3Verification(not reason, S, m, n_in, ratio, inl, reason, info)
