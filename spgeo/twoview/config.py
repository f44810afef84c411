"""Options of :func:`spgeo.twoview.estimate_relative_pose`: :class:`TwoViewConfig`,
the result statuses and the back-end / feature names it accepts; and
:class:`FeatureOptions`, the feature type, count and matching alone (what the VO's
feature retry and loop closure use)."""
from __future__ import annotations

from dataclasses import dataclass

from ..configs import config_class

__all__ = ["TWO_VIEW_STATUSES", "FeatureOptions", "TwoViewConfig"]

#: Possible values of :attr:`TwoViewResult.status`.
TWO_VIEW_STATUSES = ("ok", "too_few_matches", "low_parallax", "degenerate")

_BACKENDS = ("opencv", "pycolmap")
_FEATURES = ("sift", "orb")


def _check_feature_fields(owner: str, features: str, max_features: int, ratio: float) -> None:
    """``ValueError`` (naming ``owner``'s field) for an unknown feature type, fewer than
    8 features or a ratio outside (0, 1]."""
    if features not in _FEATURES:
        raise ValueError(f"{owner}.features must be one of {_FEATURES}, got {features!r}")
    if int(max_features) < 8:
        raise ValueError(f"{owner}.max_features must be >= 8, got {max_features}")
    if not 0.0 < float(ratio) <= 1.0:
        raise ValueError(f"{owner}.ratio must be in (0, 1], got {ratio}")


@config_class
@dataclass(frozen=True)
class FeatureOptions:
    """OpenCV features and their matching (:func:`spgeo.twoview.backends.opencv_features`,
    :func:`~spgeo.twoview.backends.ratio_matches`): the feature part of
    :class:`TwoViewConfig`, alone for the VO's feature retry
    (:class:`spgeo.vo.feature_retry.FeatureRetryConfig`) and loop closure
    (:class:`spgeo.loop.config.PlaceRecognitionConfig`).

    Attributes:
        features: ``"sift"`` (default) or ``"orb"``.
        max_features: maximum number of features per image, default 8000.
        sift_contrast_threshold: ``contrastThreshold`` of ``cv2.SIFT_create``,
            default 0.02.
        ratio: Lowe ratio-test threshold (best / second-best descriptor
            distance), default 0.8.
        cross_check: keep only mutual nearest neighbours, default True.
    """

    features: str = "sift"
    max_features: int = 8000
    sift_contrast_threshold: float = 0.02
    ratio: float = 0.8
    cross_check: bool = True

    def __post_init__(self) -> None:
        _check_feature_fields("FeatureOptions", self.features, self.max_features, self.ratio)


@config_class
@dataclass(frozen=True)
class TwoViewConfig:
    """Options of :func:`spgeo.twoview.estimate_relative_pose`.

    Attributes:
        backend: ``"opencv"`` (default) or ``"pycolmap"``.
        features: opencv back-end feature type, ``"sift"`` (default) or ``"orb"``
            (the pycolmap back-end always uses COLMAP's SIFT).
        max_features: maximum number of features per image, default 8000.
        sift_contrast_threshold: ``contrastThreshold`` of ``cv2.SIFT_create``,
            default 0.02 (OpenCV's 0.04 divided by 3 layers equals COLMAP's
            peak threshold 0.0067 at 0.02).
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
        _check_feature_fields("TwoViewConfig", self.features, self.max_features, self.ratio)
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

    @property
    def feature_options(self) -> FeatureOptions:
        """The :class:`FeatureOptions` of this config (its ``features``,
        ``max_features``, ``sift_contrast_threshold``, ``ratio``, ``cross_check``)."""
        return FeatureOptions(self.features, self.max_features, self.sift_contrast_threshold,
                              self.ratio, self.cross_check)
