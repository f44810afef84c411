"""Feature-based two-view relative pose with known intrinsics.

:func:`estimate_relative_pose` matches local features between a reference and
a target image and estimates the essential matrix, returning the pose of the
target camera in the reference camera, ``T_ref_tgt`` (4x4, camera-to-reference,
docs/design.md §1: ``x_ref = T_ref_tgt @ x_tgt``), with a **unit-norm translation**
(monocular scale is unknown).  It is used by the few-view SfM as an optional
initialisation and by visual odometry for its two-view start.

Two interchangeable back-ends (:attr:`TwoViewConfig.backend`):

* ``"opencv"``: SIFT (``cv2.SIFT_create``) or ORB features, brute-force k-NN
  matching with Lowe's ratio test (and an optional mutual-nearest check),
  ``cv2.findEssentialMat`` (RANSAC) + ``cv2.recoverPose`` (cheirality), then an
  optional Levenberg-Marquardt refinement of (R, t) minimising the Sampson
  error of the inliers.
* ``"pycolmap"``: COLMAP's SIFT extractor and matcher on in-memory images and
  ``pycolmap.estimate_calibrated_two_view_geometry`` (5-point RANSAC with local
  optimisation, E/F/H model selection) with a fixed RANSAC seed.

Conventions checked by the tests on synthetic views with known poses:
OpenCV's ``recoverPose`` returns ``(R, t)`` with ``x_tgt = R x_ref + t``
(``T_tgt_ref``), and COLMAP's ``TwoViewGeometry.cam2_from_cam1`` is the same
transform (COLMAP's ``cam_from_world`` poses are world-to-camera); both are
inverted to ``T_ref_tgt``.  COLMAP puts pixel centres at half-integers
(``(0.5, 0.5)`` is the centre of the top-left pixel) while spgeo puts them at
integers, so the COLMAP camera gets ``cx + 0.5, cy + 0.5`` and returned
keypoints are shifted back by 0.5.

The result is *flagged*, never silently wrong (:attr:`TwoViewResult.status`):

* ``"ok"``: a reliable pose.
* ``"too_few_matches"``: fewer than ``min_matches`` putative matches or
  ``min_inliers`` geometric inliers (blank or unrelated images);
  ``T_ref_tgt`` is None.
* ``"low_parallax"``: (almost) no translation-induced parallax (identical
  images, no motion or pure rotation): the translation direction is
  unobservable.  ``T_ref_tgt`` then holds the rotation-only estimate with a
  **zero** translation.
* ``"degenerate"``: the estimation failed or is unreliable (no essential
  matrix, too low an inlier ratio, a translation direction whose first-order
  standard deviation exceeds ``max_translation_std_deg``); ``T_ref_tgt`` is None.
"""
from __future__ import annotations

import contextlib
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from .camera import PinholeCamera
from .geometry import so3_exp

__all__ = [
    "TWO_VIEW_STATUSES", "TwoViewConfig", "TwoViewResult", "estimate_relative_pose",
    "to_gray_uint8", "colmap_camera", "rotation_only_fit", "parallax_angles_deg",
    "quiet_colmap",
]

logger = logging.getLogger(__name__)

#: Possible values of :attr:`TwoViewResult.status`.
TWO_VIEW_STATUSES = ("ok", "too_few_matches", "low_parallax", "degenerate")

_BACKENDS = ("opencv", "pycolmap")
_FEATURES = ("sift", "orb")


@dataclass(frozen=True)
class TwoViewConfig:
    """Options of :func:`estimate_relative_pose`.

    Attributes:
        backend: ``"opencv"`` (default) or ``"pycolmap"``.
        features: opencv back-end feature type, ``"sift"`` (default) or ``"orb"``
            (the pycolmap back-end always uses COLMAP's SIFT).
        max_features: maximum number of features per image, default 8000.
        sift_contrast_threshold: ``contrastThreshold`` of ``cv2.SIFT_create``,
            default 0.02 (OpenCV's 0.04 divided by 3 layers equals COLMAP's
            peak threshold 0.0067 at 0.02: about 50 % more features on
            weakly textured images than OpenCV's default).
        ratio: Lowe ratio-test threshold (best / second-best descriptor
            distance), default 0.8 (COLMAP's default too).
        cross_check: keep only mutual nearest neighbours, default True.
        ransac_threshold_px: RANSAC inlier threshold on the epipolar (Sampson)
            error in pixels, default 1.0.
        ransac_confidence: RANSAC confidence, default 0.9999.
        ransac_max_iterations: RANSAC iteration cap, default 10000.
        random_seed: RANSAC seed of the pycolmap back-end (OpenCV's RANSAC
            uses a fixed internal seed), default 0: results are deterministic.
        refine: opencv back-end: refine (R, t) on the inliers by minimising the
            Sampson error (Levenberg-Marquardt, 5 DoF), default True.
        min_matches: fewer putative matches give ``"too_few_matches"``, default 30.
        min_inliers: fewer geometric inliers give ``"too_few_matches"``, default 50
            (fewer inliers at small baselines often give a confidently wrong pose).
        min_inlier_ratio: an inlier / putative-match ratio below this gives
            ``"degenerate"``, default 0.1.
        min_flow_px: median image displacement of the matches (pixels) below
            which there is no motion to speak of: ``"low_parallax"`` without
            estimating an essential matrix, default 0.5.
        min_parallax_deg: median rotation-compensated parallax angle of the
            inliers (the angle between a target ray and the rotated reference
            ray; zero for pure rotation) below which the translation direction
            is deemed unobservable: ``"low_parallax"``, default 0.5.  A pair is
            also ``"low_parallax"`` when the best pure rotation leaves a median
            parallax below twice ``ransac_threshold_px`` (a rotation explains
            the matches as well as the essential matrix).
        max_translation_std_deg: a first-order standard deviation of the
            translation direction (from the inliers' Sampson residuals) above
            this flags the pose as poorly constrained: ``"degenerate"``, default 3.
        num_threads: threads of the pycolmap extractor / matcher, default 1
            (deterministic).
    """

    backend: str = "opencv"
    features: str = "sift"
    max_features: int = 8000
    sift_contrast_threshold: float = 0.02
    ratio: float = 0.8
    cross_check: bool = True
    ransac_threshold_px: float = 1.0
    ransac_confidence: float = 0.9999
    ransac_max_iterations: int = 10000
    random_seed: int = 0
    refine: bool = True
    min_matches: int = 30
    min_inliers: int = 50
    min_inlier_ratio: float = 0.1
    min_flow_px: float = 0.5
    min_parallax_deg: float = 0.5
    max_translation_std_deg: float = 3.0
    num_threads: int = 1

    def __post_init__(self) -> None:
        if self.backend not in _BACKENDS:
            raise ValueError(f"TwoViewConfig.backend must be one of {_BACKENDS}, "
                             f"got {self.backend!r}")
        if self.features not in _FEATURES:
            raise ValueError(f"TwoViewConfig.features must be one of {_FEATURES}, "
                             f"got {self.features!r}")
        if int(self.max_features) < 8:
            raise ValueError(f"TwoViewConfig.max_features must be >= 8, got {self.max_features}")
        if not 0.0 < float(self.ratio) <= 1.0:
            raise ValueError(f"TwoViewConfig.ratio must be in (0, 1], got {self.ratio}")
        if not float(self.ransac_threshold_px) > 0:
            raise ValueError("TwoViewConfig.ransac_threshold_px must be > 0, "
                             f"got {self.ransac_threshold_px}")
        if not 0.0 < float(self.ransac_confidence) < 1.0:
            raise ValueError("TwoViewConfig.ransac_confidence must be in (0, 1), "
                             f"got {self.ransac_confidence}")
        if int(self.min_inliers) < 5 or int(self.min_matches) < 5:
            raise ValueError("TwoViewConfig.min_inliers and min_matches must be >= 5 "
                             "(the five-point solver needs five correspondences)")
        if self.min_flow_px < 0 or self.min_parallax_deg < 0 or self.min_inlier_ratio < 0:
            raise ValueError("TwoViewConfig thresholds must be non-negative")


@dataclass
class TwoViewResult:
    """Output of :func:`estimate_relative_pose`.

    Attributes:
        status: one of :data:`TWO_VIEW_STATUSES` (see the module docstring).
        T_ref_tgt: 4x4 pose of the target camera in the reference camera
            (camera-to-reference) with a unit-norm translation when ``status``
            is ``"ok"``; the rotation-only estimate with zero translation for
            ``"low_parallax"``; None otherwise.
        num_keypoints: features detected in (reference, target).
        num_matches: putative matches after the ratio / mutual tests.
        num_inliers: geometric inliers of the final model (cheirality-checked
            for the opencv back-end).
        inlier_ratio: ``num_inliers / num_matches`` (0 when there are no matches).
        median_parallax_deg: median rotation-compensated parallax angle of the
            inliers with the estimated rotation (degrees); NaN when not computed.
        rotation_only_parallax_deg: the same with the best pure-rotation fit
            (what a rotation cannot explain); NaN when not computed.
        median_flow_px: median image displacement of the putative matches (px).
        rotation_std_deg, translation_std_deg: first-order standard deviations
            of the rotation and of the translation direction (degrees) from
            the inliers' Sampson residuals; NaN when not computed.
        points_ref, points_tgt: (N, 2) inlier pixel coordinates (spgeo
            convention, undistorted) in the reference and target images.
        backend: back-end used.
        message: human-readable reason for a non-``"ok"`` status.
        timings: seconds per stage (``features``, ``matching``, ``geometry``).
    """

    status: str
    T_ref_tgt: Optional[np.ndarray] = None
    num_keypoints: Tuple[int, int] = (0, 0)
    num_matches: int = 0
    num_inliers: int = 0
    inlier_ratio: float = 0.0
    median_parallax_deg: float = float("nan")
    rotation_only_parallax_deg: float = float("nan")
    median_flow_px: float = float("nan")
    rotation_std_deg: float = float("nan")
    translation_std_deg: float = float("nan")
    points_ref: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    points_tgt: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    backend: str = ""
    message: str = ""
    timings: Dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when ``status == "ok"``."""
        return self.status == "ok"

    @property
    def translation_direction(self) -> Optional[np.ndarray]:
        """Unit translation of :attr:`T_ref_tgt` (None unless ``status == "ok"``)."""
        if self.T_ref_tgt is None or not self.ok:
            return None
        return self.T_ref_tgt[:3, 3].copy()

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no arrays except the pose as nested lists)."""
        return {
            "status": self.status, "backend": self.backend, "message": self.message,
            "T_ref_tgt": None if self.T_ref_tgt is None else self.T_ref_tgt.tolist(),
            "num_keypoints": list(self.num_keypoints), "num_matches": self.num_matches,
            "num_inliers": self.num_inliers, "inlier_ratio": self.inlier_ratio,
            "median_parallax_deg": self.median_parallax_deg,
            "rotation_only_parallax_deg": self.rotation_only_parallax_deg,
            "median_flow_px": self.median_flow_px, "rotation_std_deg": self.rotation_std_deg,
            "translation_std_deg": self.translation_std_deg, "timings": dict(self.timings),
        }


# ================================================================== helpers
def to_gray_uint8(image: np.ndarray, name: str = "image") -> np.ndarray:
    """(H, W) C-contiguous uint8 grey image from uint8 / uint16 / float [0, 1]
    grey or RGB input (BT.601).  Raises ``ValueError`` for NaN/inf, float values
    outside [0, 1] or unsupported shapes."""
    from .images import to_gray

    try:
        grey = to_gray(image)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    return np.ascontiguousarray(np.clip(np.round(grey * 255.0), 0, 255).astype(np.uint8))


def colmap_camera(camera: PinholeCamera):
    """``pycolmap.Camera`` (PINHOLE) of an undistorted spgeo camera.

    COLMAP's pixel centres are at half-integers, so the principal point is
    shifted by +0.5 (spgeo: pixel centres at integers)."""
    import pycolmap

    return pycolmap.Camera(model="PINHOLE", width=int(camera.width), height=int(camera.height),
                           params=[camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5])


def _bearings(camera: PinholeCamera, pts: np.ndarray) -> np.ndarray:
    f = np.stack([(pts[:, 0] - camera.cx) / camera.fx, (pts[:, 1] - camera.cy) / camera.fy,
                  np.ones(len(pts))], axis=1)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def parallax_angles_deg(camera: PinholeCamera, pts_ref: np.ndarray, pts_tgt: np.ndarray,
                        R_tgt_ref: np.ndarray) -> np.ndarray:
    """Rotation-compensated parallax angle (degrees) of each correspondence:
    the angle between the target ray and the reference ray rotated into the
    target frame (``R_tgt_ref @ f_ref``).  Zero for pure rotation."""
    f1 = _bearings(camera, np.asarray(pts_ref, float)) @ np.asarray(R_tgt_ref, float).T
    f2 = _bearings(camera, np.asarray(pts_tgt, float))
    s = np.linalg.norm(np.cross(f1, f2), axis=1)
    c = np.sum(f1 * f2, axis=1)
    return np.degrees(np.arctan2(s, c))


def _kabsch(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising ``sum |f2 - R f1|^2`` over unit rays."""
    U, _, Vt = np.linalg.svd(f1.T @ f2)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def rotation_only_fit(camera: PinholeCamera, pts_ref: np.ndarray, pts_tgt: np.ndarray,
                      max_error_px: float = 2.0, iterations: int = 5) -> Tuple[np.ndarray, np.ndarray]:
    """Robust rotation-only model ``f_tgt ~ R_tgt_ref f_ref`` (Kabsch on rays,
    re-fitted on the points whose rotated ray lands within ``max_error_px``).

    Returns ``(R_tgt_ref (3, 3), inlier mask)``."""
    f1 = _bearings(camera, np.asarray(pts_ref, float))
    f2 = _bearings(camera, np.asarray(pts_tgt, float))
    keep = np.ones(len(f1), bool)
    R = np.eye(3)
    tol = math.atan(float(max_error_px) / max(camera.fx, camera.fy))
    for _ in range(max(1, int(iterations))):
        if keep.sum() < 3:
            break
        R = _kabsch(f1[keep], f2[keep])
        ang = np.arctan2(np.linalg.norm(np.cross(f1 @ R.T, f2), axis=1), np.sum(f1 @ R.T * f2, 1))
        new_keep = ang < max(tol, np.median(ang) * 3.0)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return R, keep


def _pose_from_tgt_ref(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``T_ref_tgt`` from ``x_tgt = R x_ref + t`` (translation normalised if nonzero)."""
    R = np.asarray(R, float)
    t = np.asarray(t, float).reshape(3)
    T = np.eye(4)
    T[:3, :3] = R.T
    c = -R.T @ t
    n = np.linalg.norm(c)
    T[:3, 3] = c / n if n > 0 else c
    return T


def _orthonormalise(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    return R


def _undistort_points(camera: PinholeCamera, pts: np.ndarray) -> np.ndarray:
    if camera.distortion is None or len(pts) == 0:
        return pts
    import cv2

    out = cv2.undistortPoints(pts.reshape(-1, 1, 2).astype(np.float64), camera.K,
                              np.asarray(camera.distortion, float), P=camera.K)
    return out.reshape(-1, 2)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _sampson_px(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
                x2: np.ndarray) -> np.ndarray:
    """Signed Sampson distances (pixels) of pixel correspondences for ``x2 = R x1 + t``."""
    Kinv = camera.K_inv
    F = Kinv.T @ _skew(t) @ R @ Kinv
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.sum(h2 * Fx1, axis=1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2) + 1e-15
    return num / den


def _pose_std_deg(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
                  x2: np.ndarray) -> Tuple[float, float]:
    """First-order standard deviations (degrees) of the rotation and of the
    translation direction of ``x2 = R x1 + t`` from the Sampson residuals of the
    inliers (largest principal axis of each block of ``sigma^2 (J^T J)^-1``,
    with a numerical 5-column Jacobian).  ``(inf, inf)`` when unconstrained."""
    n = len(x1)
    if n < 8:
        return float("inf"), float("inf")
    t = t / np.linalg.norm(t)
    a = np.eye(3)[int(np.argmin(np.abs(t)))]
    b1 = np.cross(t, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(t, b1)

    def res(p):
        tt = t + p[3] * b1 + p[4] * b2
        return _sampson_px(camera, so3_exp(p[:3]) @ R, tt / np.linalg.norm(tt), x1, x2)

    r0 = res(np.zeros(5))
    h = 1e-6
    J = np.empty((n, 5))
    for k in range(5):
        e = np.zeros(5)
        e[k] = h
        J[:, k] = (res(e) - res(-e)) / (2 * h)
    sigma2 = float(r0 @ r0) / max(n - 5, 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float("inf"), float("inf")
    if not np.all(np.isfinite(cov)):
        return float("inf"), float("inf")
    rot = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov[:3, :3])[-1]), 0.0)))
    tra = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov[3:, 3:])[-1]), 0.0)))
    return rot, tra


def _refine_sampson(camera: PinholeCamera, R0: np.ndarray, t0: np.ndarray, x1: np.ndarray,
                    x2: np.ndarray, scale_px: float) -> Tuple[np.ndarray, np.ndarray]:
    """LM refinement of (R, unit t) minimising robust Sampson errors (5 DoF)."""
    from scipy.optimize import least_squares

    t0 = t0 / np.linalg.norm(t0)
    # tangent basis of the unit sphere at t0
    a = np.eye(3)[int(np.argmin(np.abs(t0)))]
    b1 = np.cross(t0, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(t0, b1)

    def unpack(p):
        R = so3_exp(p[:3]) @ R0
        t = t0 + p[3] * b1 + p[4] * b2
        return R, t / np.linalg.norm(t)

    def fun(p):
        R, t = unpack(p)
        return _sampson_px(camera, R, t, x1, x2)

    sol = least_squares(fun, np.zeros(5), method="trf", loss="soft_l1", f_scale=scale_px,
                        x_scale=1.0, max_nfev=50)
    if not sol.success and sol.status <= 0:
        return R0, t0
    R, t = unpack(sol.x)
    return _orthonormalise(R), t


# ============================================================ feature stages
def _opencv_features(grey: np.ndarray, config: TwoViewConfig):
    import cv2

    if config.features == "sift":
        det = cv2.SIFT_create(nfeatures=int(config.max_features),
                              contrastThreshold=float(config.sift_contrast_threshold))
    else:
        det = cv2.ORB_create(nfeatures=int(config.max_features))
    kps, desc = det.detectAndCompute(grey, None)
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return pts, desc


def _ratio_matches(d1: Optional[np.ndarray], d2: Optional[np.ndarray], config: TwoViewConfig,
                   norm: int) -> np.ndarray:
    """(M, 2) index pairs passing the ratio test (and the mutual check)."""
    import cv2

    if d1 is None or d2 is None or len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), np.int64)
    bf = cv2.BFMatcher(norm, crossCheck=False)

    def one_way(a, b):
        out = {}
        for pair in bf.knnMatch(a, b, k=2):
            if len(pair) < 2:
                continue
            m, n = pair
            if m.distance < config.ratio * n.distance:
                out[m.queryIdx] = m.trainIdx
        return out

    fwd = one_way(d1, d2)
    if config.cross_check:
        bwd = one_way(d2, d1)
        pairs = [(i, j) for i, j in fwd.items() if bwd.get(j) == i]
    else:
        pairs = list(fwd.items())
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


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


def _pycolmap_features_and_matches(g1: np.ndarray, g2: np.ndarray, config: TwoViewConfig):
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


# ================================================================= estimate
def _check_camera_images(image_ref, image_tgt, camera: PinholeCamera) -> None:
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    camera.check_image(np.asarray(image_ref), "image_ref")
    camera.check_image(np.asarray(image_tgt), "image_tgt")


def estimate_relative_pose(image_ref: np.ndarray, image_tgt: np.ndarray, camera: PinholeCamera,
                           config: Optional[TwoViewConfig] = None) -> TwoViewResult:
    """Relative pose ``T_ref_tgt`` of ``image_tgt`` w.r.t. ``image_ref`` from
    feature matches and the essential matrix (known intrinsics).

    Args:
        image_ref, image_tgt: (H, W) or (H, W, 3) RGB images, uint8 / uint16 or
            float in [0, 1], both of ``camera``'s size.
        camera: intrinsics shared by both images.  With distortion
            coefficients, keypoints are undistorted before the geometry
            (returned points are undistorted pixel coordinates).
        config: :class:`TwoViewConfig` (defaults if None).
    Returns:
        :class:`TwoViewResult`; check ``status`` (``"ok"`` or a flagged failure).
    Raises:
        ValueError / TypeError for malformed input (wrong sizes, NaN, ...).
    """
    config = config or TwoViewConfig()
    _check_camera_images(image_ref, image_tgt, camera)
    g1 = to_gray_uint8(image_ref, "image_ref")
    g2 = to_gray_uint8(image_tgt, "image_tgt")
    timings: Dict[str, float] = {}
    t0 = time.perf_counter()
    res = TwoViewResult(status="degenerate", backend=config.backend, timings=timings)

    # ---- features and putative matches
    if config.backend == "opencv":
        import cv2

        p1, d1 = _opencv_features(g1, config)
        p2, d2 = _opencv_features(g2, config)
        t_feat = time.perf_counter()
        norm = cv2.NORM_L2 if config.features == "sift" else cv2.NORM_HAMMING
        matches = _ratio_matches(d1, d2, config, norm)
    else:
        with quiet_colmap():
            p1, p2, matches, t_feat = _pycolmap_features_and_matches(g1, g2, config)
        p1, p2 = p1 - 0.5, p2 - 0.5  # COLMAP pixel centres -> spgeo
    t_match = time.perf_counter()
    timings["features"] = t_feat - t0
    timings["matching"] = t_match - t_feat
    res.num_keypoints = (int(len(p1)), int(len(p2)))
    res.num_matches = int(len(matches))
    if res.num_matches < config.min_matches:
        res.status = "too_few_matches"
        res.message = (f"{res.num_matches} putative matches < min_matches = {config.min_matches} "
                       f"({res.num_keypoints[0]} / {res.num_keypoints[1]} keypoints)")
        logger.info("two-view: %s", res.message)
        timings["geometry"] = 0.0
        return res

    x1 = _undistort_points(camera, p1[matches[:, 0]])
    x2 = _undistort_points(camera, p2[matches[:, 1]])
    cam = camera.undistorted()
    res.median_flow_px = float(np.median(np.linalg.norm(x2 - x1, axis=1)))

    def finish(status: str, message: str = "") -> TwoViewResult:
        res.status, res.message = status, message
        res.inlier_ratio = res.num_inliers / res.num_matches if res.num_matches else 0.0
        timings["geometry"] = time.perf_counter() - t_match
        if status != "ok":
            logger.info("two-view (%s): %s: %s", config.backend, status, message)
        return res

    def low_parallax(mask: Optional[np.ndarray], message: str) -> TwoViewResult:
        sel = np.ones(len(x1), bool) if mask is None else mask
        R, keep = rotation_only_fit(cam, x1[sel], x2[sel], max(2.0, config.ransac_threshold_px))
        res.T_ref_tgt = _pose_from_tgt_ref(R, np.zeros(3))
        res.points_ref, res.points_tgt = x1[sel][keep], x2[sel][keep]
        res.num_inliers = int(keep.sum())
        res.rotation_only_parallax_deg = float(np.median(
            parallax_angles_deg(cam, res.points_ref, res.points_tgt, R))) if keep.any() else 0.0
        if not np.isfinite(res.median_parallax_deg):  # no essential matrix was estimated
            res.median_parallax_deg = res.rotation_only_parallax_deg
        return finish("low_parallax", message)

    if res.median_flow_px < config.min_flow_px:
        return low_parallax(None, f"median image motion {res.median_flow_px:.3f} px < "
                                  f"min_flow_px = {config.min_flow_px}: no motion")

    # ---- geometry
    if config.backend == "opencv":
        R, t, inl, msg = _opencv_geometry(cam, x1, x2, config)
    else:
        R, t, inl, msg = _pycolmap_geometry(cam, x1, x2, config)
    if inl is not None:
        res.num_inliers = int(inl.sum())
    if msg == "panoramic":
        return low_parallax(inl, "COLMAP classified the pair as panoramic (pure rotation)")
    if R is None:
        if res.num_inliers and res.num_inliers < config.min_inliers:
            return finish("too_few_matches", f"{res.num_inliers} inliers < min_inliers = "
                                             f"{config.min_inliers} ({msg})")
        return finish("degenerate", msg or "no essential matrix found")
    if res.num_inliers < config.min_inliers:
        return finish("too_few_matches", f"{res.num_inliers} geometric inliers < min_inliers = "
                                         f"{config.min_inliers}")
    res.points_ref, res.points_tgt = x1[inl], x2[inl]
    par = parallax_angles_deg(cam, res.points_ref, res.points_tgt, R)
    res.median_parallax_deg = float(np.median(par))
    # how much parallax is left by the best pure rotation (least squares on the
    # inliers' rays): ~ the noise level for a rotation, even where the essential
    # matrix has absorbed the noise into a spurious translation
    R_rot = _kabsch(_bearings(cam, res.points_ref), _bearings(cam, res.points_tgt))
    res.rotation_only_parallax_deg = float(np.median(
        parallax_angles_deg(cam, res.points_ref, res.points_tgt, R_rot)))
    # a pure rotation explains the matches within twice the RANSAC threshold
    rotation_tol_deg = math.degrees(math.atan(2.0 * config.ransac_threshold_px
                                              / max(cam.fx, cam.fy)))
    if res.median_parallax_deg < config.min_parallax_deg:
        return low_parallax(inl, f"median parallax {res.median_parallax_deg:.3f} deg < "
                                 f"min_parallax_deg = {config.min_parallax_deg}: translation "
                                 "direction unobservable")
    if res.rotation_only_parallax_deg < rotation_tol_deg:
        return low_parallax(inl, f"a pure rotation leaves only {res.rotation_only_parallax_deg:.3f}"
                                 f" deg of median parallax (< {rotation_tol_deg:.3f} deg, twice "
                                 "the RANSAC threshold): translation direction unobservable")
    res.T_ref_tgt = _pose_from_tgt_ref(R, t)
    res.rotation_std_deg, res.translation_std_deg = _pose_std_deg(cam, R, t, res.points_ref,
                                                                  res.points_tgt)
    ratio = res.num_inliers / res.num_matches
    if ratio < config.min_inlier_ratio:
        res.T_ref_tgt = None
        return finish("degenerate", f"inlier ratio {ratio:.3f} < min_inlier_ratio = "
                                    f"{config.min_inlier_ratio}")
    if not res.translation_std_deg <= config.max_translation_std_deg:
        res.T_ref_tgt = None
        return finish("degenerate", f"pose poorly constrained: translation-direction std "
                                    f"{res.translation_std_deg:.2f} deg > "
                                    f"max_translation_std_deg = {config.max_translation_std_deg}")
    return finish("ok")


def _opencv_geometry(cam: PinholeCamera, x1: np.ndarray, x2: np.ndarray, config: TwoViewConfig):
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
    import cv2

    K = cam.K
    thr = float(config.ransac_threshold_px)
    candidates = []
    notes = []
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
    if not candidates:
        return None, None, None, "; ".join(notes) or "no essential matrix found"

    def score(R, t):
        # MSAC score: truncated squared Sampson error, matches behind a camera
        # count as outliers; returns (-cost, inliers, mask, R, t) (larger is better)
        t = t / np.linalg.norm(t)
        err = np.abs(_sampson_px(cam, R, t, x1, x2))
        inl = (err < thr) & _positive_depth(cam, R, t, x1, x2)
        cost = float(np.sum(np.where(inl, err ** 2, thr ** 2)))
        return -cost, int(inl.sum()), inl, R, t

    best = None
    for R, t in candidates:
        s0 = score(_orthonormalise(R), t)
        if config.refine and s0[1] >= 8:
            Rr, tr = _refine_sampson(cam, s0[3], s0[4], x1[s0[2]], x2[s0[2]], thr)
            s1 = score(Rr, tr)
            s0 = s1 if s1[:2] >= s0[:2] else s0
        if best is None or s0[:2] > best[:2]:
            best = s0
    _, n_inl, inl, R, t = best
    if n_inl < 5:
        return None, None, inl, "no pose passes the cheirality check"
    return R, t, inl, ""


def _positive_depth(cam: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
                    x2: np.ndarray) -> np.ndarray:
    """Cheirality: both midpoint-triangulated depths positive."""
    f1 = _bearings(cam, x1)
    f2 = _bearings(cam, x2)
    # solve d1 R f1 + t = d2 f2 in least squares for (d1, d2)
    a = f1 @ R.T
    b = -f2
    aa, bb, ab = np.sum(a * a, 1), np.sum(b * b, 1), np.sum(a * b, 1)
    at, bt = a @ t, b @ t
    det = aa * bb - ab ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        d1 = (-at * bb + bt * ab) / det
        d2 = (-bt * aa + at * ab) / det
    return np.isfinite(d1) & (d1 > 0) & (d2 > 0)


def _pycolmap_geometry(cam: PinholeCamera, x1: np.ndarray, x2: np.ndarray,
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
    if config_id in (Cfg.PANORAMIC, Cfg.PLANAR_OR_PANORAMIC) and _is_panoramic(geom):
        return None, None, inl, "panoramic"
    if config_id not in (Cfg.CALIBRATED, Cfg.PLANAR, Cfg.PLANAR_OR_PANORAMIC):
        name = getattr(config_id, "name", str(config_id))
        return None, None, inl, f"COLMAP two-view configuration {name}"
    pose = geom.cam2_from_cam1
    if pose is None:
        return None, None, inl, "COLMAP returned no relative pose"
    M = np.asarray(pose.matrix(), np.float64)  # 3x4, x_cam2 = R x_cam1 + t
    R, t = _orthonormalise(M[:, :3]), M[:, 3]
    if not np.all(np.isfinite(M)) or np.linalg.norm(t) < 1e-12:
        return None, None, inl, "panoramic"
    return R, t, inl, ""


def _is_panoramic(geom) -> bool:
    pose = geom.cam2_from_cam1
    if pose is None:
        return True
    t = np.asarray(pose.matrix(), np.float64)[:, 3]
    return bool(np.linalg.norm(t) < 1e-12)
