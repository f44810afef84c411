"""Feature matching and relative-pose back-ends of :mod:`spgeo.twoview`.

* OpenCV: SIFT / ORB features, ratio-test matching, essential-matrix and
  homography candidates scored by MSAC on the Sampson error.
* pycolmap: COLMAP's SIFT extractor / matcher and its calibrated two-view
  geometry.

Correspondences are in spgeo pixel coordinates (pixel centres at integers);
the COLMAP half-pixel shift is applied at this module's boundary.  Geometry
functions return ``(R_tgt_ref, t, inlier mask, message)`` with
``x_tgt = R_tgt_ref x_ref + t``.
"""
from __future__ import annotations

import contextlib
import time
from typing import List, Optional

import numpy as np

from ..camera import PinholeCamera
from ..geometry import nearest_rotation
from .config import FeatureOptions, TwoViewConfig
from .geometry import positive_depth, refine_sampson, sampson_px

__all__ = [
    "colmap_camera", "quiet_colmap", "opencv_features", "ratio_matches",
    "pycolmap_features_and_matches", "opencv_geometry", "pycolmap_geometry", "is_panoramic",
]


def colmap_camera(camera: PinholeCamera):
    """``pycolmap.Camera`` (PINHOLE) of an undistorted spgeo camera.

    COLMAP's pixel centres are at half-integers, so the principal point is
    shifted by +0.5 (spgeo: pixel centres at integers)."""
    import pycolmap

    return pycolmap.Camera(model="PINHOLE", width=int(camera.width), height=int(camera.height),
                           params=[camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5])


def opencv_features(grey: np.ndarray, options: FeatureOptions):
    """SIFT / ORB keypoints of a uint8 grey image with ``options``
    (:class:`~spgeo.twoview.config.FeatureOptions`): ``((N, 2) pixels, descriptors or None)``."""
    import cv2

    if options.features == "sift":
        det = cv2.SIFT_create(nfeatures=int(options.max_features),
                              contrastThreshold=float(options.sift_contrast_threshold))
    else:
        det = cv2.ORB_create(nfeatures=int(options.max_features))
    kps, desc = det.detectAndCompute(grey, None)
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return pts, desc


def ratio_matches(d1: Optional[np.ndarray], d2: Optional[np.ndarray],
                  options: FeatureOptions) -> np.ndarray:
    """(M, 2) index pairs of descriptors ``d1`` -> ``d2`` (of :func:`opencv_features`
    with ``options``) passing the ratio test (and, with ``options.cross_check``, the
    mutual check); L2 distances for SIFT, Hamming for ORB.  Sorted by the ``d1``
    index.

    The pairs are those of ``cv2.BFMatcher.knnMatch(k=2)`` in both directions (the
    same ``cv2.batchDistance`` distances and ties: the lowest index is the nearest),
    but the reverse direction is computed only for the ``d2`` descriptors that are
    a forward match.  SIFT descriptors may come as float32 or as the uint8 of their
    whole-number values (:class:`spgeo.loop.KeyframeDatabase` keeps them so)."""
    import cv2

    if d1 is None or d2 is None or len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), np.int64)
    sift = options.features == "sift"
    norm, dtype = (cv2.NORM_L2, cv2.CV_32F) if sift else (cv2.NORM_HAMMING, cv2.CV_32S)
    if sift:    # SIFT descriptors stored as uint8 (whole numbers) match as their float32
        d1, d2 = (np.asarray(d, np.float32) for d in (d1, d2))
    i, j = _nearest_passing(d1, d2, norm, dtype, options.ratio)
    if options.cross_check and len(i):
        targets, inv = np.unique(j, return_inverse=True)
        back_i, back_ok = _nearest_passing(np.ascontiguousarray(d2[targets]), d1, norm, dtype,
                                           options.ratio, every=True)
        keep = back_ok[inv] & (back_i[inv] == i)
        i, j = i[keep], j[keep]
    return np.stack([i, j], 1).astype(np.int64).reshape(-1, 2)


def _nearest_passing(a: np.ndarray, b: np.ndarray, norm: int, dtype: int, ratio: float,
                     every: bool = False):
    """Nearest neighbour in ``b`` of each row of ``a`` and the ratio test (best <
    ``ratio`` x second-best distance, compared in float64 as ``DMatch.distance``):
    ``(rows passing, their nearest)``, or with ``every`` ``(nearest of every row,
    passes)``."""
    import cv2

    dist, idx = cv2.batchDistance(a, b, dtype, normType=norm, K=2)
    ok = dist[:, 0].astype(np.float64) < ratio * dist[:, 1].astype(np.float64)
    nearest = idx[:, 0].astype(np.int64)
    if every:
        return nearest, ok
    rows = np.flatnonzero(ok)
    return rows, nearest[rows]


@contextlib.contextmanager
def quiet_colmap(level: int = 1):
    """Temporarily raise glog's minimum level (COLMAP logs every step at INFO)."""
    import pycolmap

    old = None
    try:
        old = pycolmap.logging.minloglevel
        pycolmap.logging.minloglevel = max(int(old), int(level))
    except Exception:  # pragma: no cover - logging API differs
        old = None
    try:
        yield
    finally:
        if old is not None:
            pycolmap.logging.minloglevel = old


def pycolmap_features_and_matches(g1: np.ndarray, g2: np.ndarray, config: TwoViewConfig):
    """COLMAP SIFT keypoints of two uint8 grey images and their matches:
    ``(p1, p2, (M, 2) index pairs, time.perf_counter() after extraction)``;
    keypoints in COLMAP pixel coordinates (centres at half-integers)."""
    import pycolmap

    eo = pycolmap.FeatureExtractionOptions()
    eo.num_threads = int(config.num_threads)
    eo.use_gpu = False
    eo.sift.max_num_features = int(config.max_features)
    extractor = pycolmap.FeatureExtractor.create(eo, pycolmap.Device.cpu)
    kp1, de1 = extractor.extract_from_uint8_array(g1)
    kp2, de2 = extractor.extract_from_uint8_array(g2)
    p1 = np.asarray(pycolmap.keypoints_to_matrix(kp1), np.float64).reshape(-1, 4)[:, :2]
    p2 = np.asarray(pycolmap.keypoints_to_matrix(kp2), np.float64).reshape(-1, 4)[:, :2]
    t_feat = time.perf_counter()
    if len(p1) < 2 or len(p2) < 2:
        return p1, p2, np.zeros((0, 2), np.int64), t_feat
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = int(config.num_threads)
    mo.use_gpu = False
    mo.sift.max_ratio = float(config.ratio)
    mo.sift.cross_check = bool(config.cross_check)
    mo.sift.cpu_brute_force_matcher = True  # exact and deterministic
    matcher = pycolmap.FeatureMatcher.create(mo, pycolmap.Device.cpu)
    matches = np.asarray(matcher.match(kp1, de1, kp2, de2), np.int64).reshape(-1, 2)
    return p1, p2, matches, t_feat


def _essential_candidates(K: np.ndarray, x1: np.ndarray, x2: np.ndarray,
                          config: TwoViewConfig, notes: List[str]) -> list:
    """``(R, t)`` candidates of :func:`opencv_geometry` from the essential matrix
    (RANSAC, then USAC_ACCURATE where available), each solution disambiguated
    by ``cv2.recoverPose``; why a method gave none is appended to ``notes``."""
    import cv2

    thr = float(config.ransac_threshold_px)
    candidates = []
    methods = [("RANSAC", cv2.RANSAC)]
    if hasattr(cv2, "USAC_ACCURATE"):
        methods.append(("USAC_ACCURATE", cv2.USAC_ACCURATE))
    for name, method in methods:
        try:
            E, mask = cv2.findEssentialMat(x1, x2, K, method=method,
                                           prob=float(config.ransac_confidence), threshold=thr,
                                           maxIters=int(config.ransac_max_iterations))
        except cv2.error as exc:
            notes.append(f"findEssentialMat({name}) failed: {exc}")
            continue
        if E is None or E.shape[0] < 3 or mask is None or not np.all(np.isfinite(E)):
            notes.append(f"findEssentialMat({name}) found no essential matrix")
            continue
        for k in range(E.shape[0] // 3):  # several solutions may be stacked
            try:
                n_good, R, t, _ = cv2.recoverPose(E[3 * k:3 * k + 3], x1, x2, K,
                                                  mask=mask.astype(np.uint8).copy())
            except cv2.error as exc:
                notes.append(f"recoverPose failed: {exc}")
                continue
            if n_good >= 5:
                candidates.append((R, t.ravel()))
    return candidates


def _homography_candidates(K: np.ndarray, x1: np.ndarray, x2: np.ndarray,
                           config: TwoViewConfig) -> list:
    """``(R, t)`` candidates of :func:`opencv_geometry` from the decompositions of
    a RANSAC homography (planar scenes); none when it fails."""
    import cv2

    thr = float(config.ransac_threshold_px)
    candidates = []
    try:
        H, hmask = cv2.findHomography(x1, x2, cv2.RANSAC, thr, maxIters=int(config.ransac_max_iterations),
                                      confidence=float(config.ransac_confidence))
    except cv2.error:
        H = None
    if H is not None and np.all(np.isfinite(H)):
        try:
            _, Rs, ts, _ = cv2.decomposeHomographyMat(H, K)
        except cv2.error:
            Rs, ts = [], []
        for R, t in zip(Rs, ts):
            if np.linalg.norm(t) > 1e-9:
                candidates.append((np.asarray(R, float), np.asarray(t, float).ravel()))
    return candidates


def opencv_geometry(cam: PinholeCamera, x1: np.ndarray, x2: np.ndarray, config: TwoViewConfig):
    """(R_tgt_ref, t, inlier mask, message) from OpenCV.

    Candidate poses come from the essential matrix (``cv2.findEssentialMat``
    with RANSAC and, where available, USAC_ACCURATE, each disambiguated by
    ``cv2.recoverPose``) and from the decompositions of a RANSAC homography
    (planar scenes, where a five-point RANSAC may stop on the wrong one of the
    two plane-induced solutions).  Each candidate is optionally refined on its
    inliers (Sampson error) and scored with the MSAC cost over all matches
    (squared Sampson error, truncated at the threshold; matches that triangulate
    behind a camera count as outliers); the lowest cost wins.
    """
    thr = float(config.ransac_threshold_px)
    notes: List[str] = []
    candidates = _essential_candidates(cam.K, x1, x2, config, notes)
    candidates += _homography_candidates(cam.K, x1, x2, config)
    if not candidates:
        return None, None, None, "; ".join(notes) or "no essential matrix found"

    def score(R, t):
        # MSAC score: truncated squared Sampson error, matches behind a camera
        # count as outliers; returns (-cost, inliers, mask, R, t) (larger is better)
        t = t / np.linalg.norm(t)
        err = np.abs(sampson_px(cam, R, t, x1, x2))
        inl = (err < thr) & positive_depth(cam, R, t, x1, x2)
        cost = float(np.sum(np.where(inl, err ** 2, thr ** 2)))
        return -cost, int(inl.sum()), inl, R, t

    best = None
    for R, t in candidates:
        s0 = score(nearest_rotation(R), t)
        if config.refine and s0[1] >= 8:
            Rr, tr = refine_sampson(cam, s0[3], s0[4], x1[s0[2]], x2[s0[2]], thr)
            s1 = score(Rr, tr)
            s0 = s1 if s1[:2] >= s0[:2] else s0
        if best is None or s0[:2] > best[:2]:
            best = s0
    _, n_inl, inl, R, t = best
    if n_inl < 5:
        return None, None, inl, "no pose passes the cheirality check"
    return R, t, inl, ""


def pycolmap_geometry(cam: PinholeCamera, x1: np.ndarray, x2: np.ndarray,
                      config: TwoViewConfig):
    """(R_tgt_ref, t, inlier mask, message) from COLMAP's calibrated two-view geometry."""
    import pycolmap

    ccam = colmap_camera(cam)
    opts = pycolmap.TwoViewGeometryOptions()
    opts.compute_relative_pose = True
    opts.min_num_inliers = int(config.min_inliers)
    opts.ransac.max_error = float(config.ransac_threshold_px)
    opts.ransac.confidence = float(config.ransac_confidence)
    opts.ransac.max_num_trials = int(config.ransac_max_iterations)
    opts.ransac.random_seed = int(config.random_seed)
    opts.ransac.num_threads = 1
    opts.detect_watermark = False
    idx = np.arange(len(x1), dtype=np.uint32)
    with quiet_colmap():
        geom = pycolmap.estimate_calibrated_two_view_geometry(
            ccam, x1 + 0.5, ccam, x2 + 0.5, np.stack([idx, idx], 1), opts)
    Cfg = pycolmap.TwoViewGeometryConfiguration
    config_id = geom.config
    inl_idx = np.asarray(geom.inlier_matches, np.int64).reshape(-1, 2)[:, 0]
    inl = np.zeros(len(x1), bool)
    inl[inl_idx] = True
    if config_id in (Cfg.PANORAMIC, Cfg.PLANAR_OR_PANORAMIC) and is_panoramic(geom):
        return None, None, inl, "panoramic"
    if config_id not in (Cfg.CALIBRATED, Cfg.PLANAR, Cfg.PLANAR_OR_PANORAMIC):
        name = getattr(config_id, "name", str(config_id))
        return None, None, inl, f"COLMAP two-view configuration {name}"
    pose = geom.cam2_from_cam1
    if pose is None:
        return None, None, inl, "COLMAP returned no relative pose"
    M = np.asarray(pose.matrix(), np.float64)  # 3x4, x_cam2 = R x_cam1 + t
    R, t = nearest_rotation(M[:, :3]), M[:, 3]
    if not np.all(np.isfinite(M)) or np.linalg.norm(t) < 1e-12:
        return None, None, inl, "panoramic"
    return R, t, inl, ""


def is_panoramic(geom) -> bool:
    """True when a COLMAP two-view geometry has no (or a zero) translation."""
    pose = geom.cam2_from_cam1
    if pose is None:
        return True
    t = np.asarray(pose.matrix(), np.float64)[:, 3]
    return bool(np.linalg.norm(t) < 1e-12)
