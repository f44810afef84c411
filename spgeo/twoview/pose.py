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

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import rotation_angle_deg
from .backends import (opencv_features, opencv_geometry, pycolmap_features_and_matches,
                       pycolmap_geometry, quiet_colmap, ratio_matches)
from .config import TwoViewConfig
from .geometry import (bearings, kabsch, parallax_angles_deg, pose_from_tgt_ref, pose_std_deg,
                       rotation_only_fit, undistort_points)

__all__ = ["TwoViewResult", "estimate_relative_pose", "relative_pose_from_matches",
           "to_gray_uint8"]

logger = logging.getLogger(__name__)


@dataclass
class TwoViewResult:
    """Output of :func:`estimate_relative_pose`.

    Attributes:
        status: one of :data:`~spgeo.twoview.config.TWO_VIEW_STATUSES` (see the module docstring).
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
        inliers: (N,) indices of those inliers among the putative matches
            (rows of the matches given to :func:`relative_pose_from_matches`).
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
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    backend: str = ""
    message: str = ""
    timings: Dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when ``status == "ok"``."""
        return self.status == "ok"

    def __repr__(self) -> str:
        """One line: status, matches, inliers, parallax and the rotation (degrees)."""
        rot = ("" if self.T_ref_tgt is None
               else f", rotation {rotation_angle_deg(self.T_ref_tgt[:3, :3]):.2f} deg")
        return (f"TwoViewResult({self.status}, {self.num_inliers}/{self.num_matches} inliers, "
                f"parallax {self.median_parallax_deg:.2f} deg{rot}, {self.backend})")

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


# ================================================================== input
def to_gray_uint8(image: np.ndarray, name: str = "image") -> np.ndarray:
    """(H, W) C-contiguous uint8 grey image from uint8 / uint16 / float [0, 1]
    grey or RGB input (BT.601).  Raises ``ValueError`` for NaN/inf, float values
    outside [0, 1] or unsupported shapes."""
    from ..images import to_gray

    try:
        grey = to_gray(image)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    return np.ascontiguousarray(np.clip(np.round(grey * 255.0), 0, 255).astype(np.uint8))


# ================================================================= estimate
def _check_camera_images(image_ref, image_tgt, camera: PinholeCamera) -> None:
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    camera.check_image(np.asarray(image_ref), "image_ref")
    camera.check_image(np.asarray(image_tgt), "image_tgt")


@dataclass
class _Pair:
    """The undistorted putative correspondences ``x1`` (reference) / ``x2``
    (target) of one image pair, their camera, the options, the result being
    filled and the time matching ended (the geometry timing starts there)."""

    res: TwoViewResult
    config: TwoViewConfig
    cam: PinholeCamera
    x1: np.ndarray
    x2: np.ndarray
    t_match: float


def _putative_matches(g1: np.ndarray, g2: np.ndarray, config: TwoViewConfig,
                      timings: Dict[str, float], t0: float):
    """Features of both grey images and their putative matches, keypoints in
    spgeo pixel coordinates; records the ``features`` and ``matching`` timings.
    Returns ``(p1, p2, matches (M, 2) indices, time matching ended)``."""
    if config.backend == "opencv":
        options = config.feature_options
        p1, d1 = opencv_features(g1, options)
        p2, d2 = opencv_features(g2, options)
        t_feat = time.perf_counter()
        matches = ratio_matches(d1, d2, options)
    else:
        with quiet_colmap():
            p1, p2, matches, t_feat = pycolmap_features_and_matches(g1, g2, config)
        p1, p2 = p1 - 0.5, p2 - 0.5  # COLMAP pixel centres -> spgeo
    t_match = time.perf_counter()
    timings["features"] = t_feat - t0
    timings["matching"] = t_match - t_feat
    return p1, p2, matches, t_match


def _finish(pair: _Pair, status: str, message: str = "") -> TwoViewResult:
    """``pair.res`` with ``status``, ``message``, the inlier ratio and the
    geometry timing set (a non-``"ok"`` status is logged)."""
    res, config = pair.res, pair.config
    res.status, res.message = status, message
    res.inlier_ratio = res.num_inliers / res.num_matches if res.num_matches else 0.0
    res.timings["geometry"] = time.perf_counter() - pair.t_match
    if status != "ok":
        logger.info("two-view (%s): %s: %s", config.backend, status, message)
    return res


def _low_parallax(pair: _Pair, mask: Optional[np.ndarray], message: str) -> TwoViewResult:
    """``"low_parallax"``: the rotation-only fit of the matches in ``mask``
    (all when None) with a zero translation."""
    res, cam, x1, x2 = pair.res, pair.cam, pair.x1, pair.x2
    sel = np.ones(len(x1), bool) if mask is None else mask
    R, keep = rotation_only_fit(cam, x1[sel], x2[sel], max(2.0, pair.config.ransac_threshold_px))
    res.T_ref_tgt = pose_from_tgt_ref(R, np.zeros(3))
    res.points_ref, res.points_tgt = x1[sel][keep], x2[sel][keep]
    res.inliers = np.flatnonzero(sel)[keep]
    res.num_inliers = int(keep.sum())
    res.rotation_only_parallax_deg = float(np.median(
        parallax_angles_deg(cam, res.points_ref, res.points_tgt, R))) if keep.any() else 0.0
    if not np.isfinite(res.median_parallax_deg):  # no essential matrix was estimated
        res.median_parallax_deg = res.rotation_only_parallax_deg
    return _finish(pair, "low_parallax", message)


def _geometry(pair: _Pair) -> TwoViewResult:
    """Relative pose of the back-end and the checks on its inliers: too few,
    panoramic, no pose; then :func:`_checked_pose`."""
    res, config, cam, x1, x2 = pair.res, pair.config, pair.cam, pair.x1, pair.x2
    if config.backend == "opencv":
        R, t, inl, msg = opencv_geometry(cam, x1, x2, config)
    else:
        R, t, inl, msg = pycolmap_geometry(cam, x1, x2, config)
    if inl is not None:
        res.num_inliers = int(inl.sum())
    if msg == "panoramic":
        return _low_parallax(pair, inl, "COLMAP classified the pair as panoramic (pure rotation)")
    if R is None:
        if res.num_inliers and res.num_inliers < config.min_inliers:
            return _finish(pair, "too_few_matches", f"{res.num_inliers} inliers < min_inliers = "
                                                    f"{config.min_inliers} ({msg})")
        return _finish(pair, "degenerate", msg or "no essential matrix found")
    if res.num_inliers < config.min_inliers:
        return _finish(pair, "too_few_matches", f"{res.num_inliers} geometric inliers < "
                                                f"min_inliers = {config.min_inliers}")
    return _checked_pose(pair, R, t, inl)


def _checked_pose(pair: _Pair, R: np.ndarray, t: np.ndarray, inl: np.ndarray) -> TwoViewResult:
    """The pose ``(R, t)`` (``x_tgt = R x_ref + t``) with inliers ``inl`` checked
    for parallax (``"low_parallax"``), inlier ratio and translation-direction
    uncertainty (``"degenerate"``); ``"ok"`` when it passes."""
    res, config, cam = pair.res, pair.config, pair.cam
    res.points_ref, res.points_tgt = pair.x1[inl], pair.x2[inl]
    res.inliers = np.flatnonzero(inl)
    par = parallax_angles_deg(cam, res.points_ref, res.points_tgt, R)
    res.median_parallax_deg = float(np.median(par))
    # how much parallax is left by the best pure rotation (least squares on the
    # inliers' rays): ~ the noise level for a rotation, even where the essential
    # matrix has absorbed the noise into a spurious translation
    R_rot = kabsch(bearings(cam, res.points_ref), bearings(cam, res.points_tgt))
    res.rotation_only_parallax_deg = float(np.median(
        parallax_angles_deg(cam, res.points_ref, res.points_tgt, R_rot)))
    # a pure rotation explains the matches within twice the RANSAC threshold
    rotation_tol_deg = math.degrees(math.atan(2.0 * config.ransac_threshold_px
                                              / max(cam.fx, cam.fy)))
    if res.median_parallax_deg < config.min_parallax_deg:
        return _low_parallax(pair, inl, f"median parallax {res.median_parallax_deg:.3f} deg < "
                                        f"min_parallax_deg = {config.min_parallax_deg}: "
                                        "translation direction unobservable")
    if res.rotation_only_parallax_deg < rotation_tol_deg:
        return _low_parallax(pair, inl, f"a pure rotation leaves only "
                                        f"{res.rotation_only_parallax_deg:.3f} deg of median "
                                        f"parallax (< {rotation_tol_deg:.3f} deg, twice the "
                                        "RANSAC threshold): translation direction unobservable")
    res.T_ref_tgt = pose_from_tgt_ref(R, t)
    res.rotation_std_deg, res.translation_std_deg = pose_std_deg(cam, R, t, res.points_ref,
                                                                 res.points_tgt)
    ratio = res.num_inliers / res.num_matches
    if ratio < config.min_inlier_ratio:
        res.T_ref_tgt = None
        return _finish(pair, "degenerate", f"inlier ratio {ratio:.3f} < min_inlier_ratio = "
                                           f"{config.min_inlier_ratio}")
    if not res.translation_std_deg <= config.max_translation_std_deg:
        res.T_ref_tgt = None
        return _finish(pair, "degenerate", f"pose poorly constrained: translation-direction std "
                                           f"{res.translation_std_deg:.2f} deg > "
                                           f"max_translation_std_deg = "
                                           f"{config.max_translation_std_deg}")
    return _finish(pair, "ok")


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
    p1, p2, matches, t_match = _putative_matches(g1, g2, config, timings, t0)
    res.num_keypoints = (int(len(p1)), int(len(p2)))
    res.num_matches = int(len(matches))
    if res.num_matches < config.min_matches:
        res.status = "too_few_matches"
        res.message = (f"{res.num_matches} putative matches < min_matches = {config.min_matches} "
                       f"({res.num_keypoints[0]} / {res.num_keypoints[1]} keypoints)")
        logger.info("two-view: %s", res.message)
        timings["geometry"] = 0.0
        return res

    x1 = undistort_points(camera, p1[matches[:, 0]])
    x2 = undistort_points(camera, p2[matches[:, 1]])
    return _pose_of_pair(_Pair(res, config, camera.undistorted(), x1, x2, t_match))


def _pose_of_pair(pair: _Pair) -> TwoViewResult:
    """The flow check, then :func:`_geometry`, on ``pair``'s putative matches."""
    res, config = pair.res, pair.config
    res.median_flow_px = float(np.median(np.linalg.norm(pair.x2 - pair.x1, axis=1)))
    if res.median_flow_px < config.min_flow_px:
        return _low_parallax(pair, None, f"median image motion {res.median_flow_px:.3f} px < "
                                         f"min_flow_px = {config.min_flow_px}: no motion")
    return _geometry(pair)


def relative_pose_from_matches(x_ref: np.ndarray, x_tgt: np.ndarray, camera: PinholeCamera,
                               config: Optional[TwoViewConfig] = None) -> TwoViewResult:
    """:func:`estimate_relative_pose` from putative correspondences already made.

    Args:
        x_ref, x_tgt: (M, 2) undistorted pixel coordinates (spgeo convention) of the
            putative matches in the reference and target images.
        camera: their (undistorted) intrinsics.
        config: :class:`TwoViewConfig` (its geometry and status options; the
            feature options are unused).
    Returns:
        :class:`TwoViewResult` with ``inliers`` indexing rows of ``x_ref``
        (``num_keypoints`` is (0, 0): no features were detected here).
    Raises:
        ValueError: ``x_ref`` and ``x_tgt`` not both (M, 2).
    """
    config = config or TwoViewConfig()
    x1, x2 = np.asarray(x_ref, np.float64), np.asarray(x_tgt, np.float64)
    if x1.ndim != 2 or x1.shape[1:] != (2,) or x1.shape != x2.shape:
        raise ValueError(f"relative_pose_from_matches: x_ref {x1.shape} and x_tgt {x2.shape} "
                         "must both be (M, 2)")
    res = TwoViewResult(status="degenerate", backend="opencv", timings={},
                        num_matches=len(x1))
    if len(x1) < config.min_matches:
        res.status = "too_few_matches"
        res.message = f"{len(x1)} putative matches < min_matches = {config.min_matches}"
        return res
    return _pose_of_pair(_Pair(res, dataclasses.replace(config, backend="opencv"),
                               camera.undistorted(), x1, x2, time.perf_counter()))
