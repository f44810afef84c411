"""Options of :func:`spgeo.sfm.few_view_sfm`: :class:`SfMConfig`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Tuple

from ..configs import config_class
from ..factors.photometric import PhotometricConfig
from ..twoview.config import TwoViewConfig

__all__ = ["SfMConfig"]


@config_class
@dataclass(frozen=True)
class SfMConfig:
    """Options of :func:`spgeo.sfm.few_view_sfm` (defaults follow the paper where it says).

    Attributes:
        shape_model: ``"scaled"`` (1-DoF log-scale on the integrated shape, the
            paper) or ``"planar"`` (3-DoF inverse-depth plane per primitive).
        levels: pyramid levels (coarse-to-fine; 4 at 320x240 -> 40x30 coarsest).
        max_iterations: LM iterations per level, coarsest first (the last
            value repeats for extra levels).
        relative_error_tol: LM stops at a level when the cost decreases by
            less than this fraction.
        photometric: per-pixel robust cost options.
        brightness: estimate an affine brightness ``(a, b)`` per view.
        brightness_prior_sigma: prior sigma of ``(a, b)`` towards 0.
        scale_prior_weight: weight of the prior pulling each log-scale to its
            initial value (paper: 1e-5); sigma = ``1 / sqrt(weight)``.
        planar_prior_sigma: prior sigma pulling the plane's slopes ``(a, b)``
            towards fronto-parallel, or towards the chosen orientation
            (planar model only).
        orientation_choice: planar model: after the coarse-to-fine solve from
            fronto-parallel planes, each primitive takes its front-end shape's
            orientation or one of the scene's dominant orientations where that
            lowers its photometric cost at the solved poses, and the finest
            level is solved once more (:mod:`spgeo.sfm.orientation`; default
            True; no effect when every front-end shape is flat).
        ref_prior_sigma: sigma of the gauge prior on the reference pose.
        reset_scales: start every log-scale at 0 (paper) even if the front-end
            fitted scales (depth-using front-ends do).
        init: ``"features"`` (default): the landmark bundle of all views
            (:class:`spgeo.sfm.landmarks.LandmarkStage`: SIFT tracks over every
            pair, the best-conditioned pair, PnP, a GTSAM bundle adjustment) sets
            the poses and, through the landmarks seen in the reference, the
            initial log-scales; the photometric solve then refines the poses, and
            each view keeps its photometric pose only where the bundle's held-out
            matches fit it at least as well; views it cannot place start at
            identity and are flagged.
            ``"twoview"``: one feature-based relative pose per view
            (:func:`spgeo.sfm.init.twoview_initialisation`), the default until
            d00416a; the VO's start keeps it (``OdometryConfig.sfm``: its
            keyframe 1 when tracking it failed, measured there), few-view SfM
            loses with it at every baseline (docs/results.md, issue 40).
            ``"identity"``: the paper's start (poses at identity, log-scales 0).
        features: SIFT features and pair geometry of ``init="features"``
            (default: :class:`~spgeo.twoview.TwoViewConfig` with ``min_inliers=30``,
            as the bundle checks each pair once more).
        rotation_first: when a view starts at identity, at the coarsest
            level first solve the views' rotations and brightness with translations held at their initial
            values (a tight translation prior) and scales fixed: rotational
            alignment does not depend on depth, so the wrong initial depths
            cannot pull it into a rotation/translation confusion.  Then all
            variables are freed.
        min_level_pixels: skip a primitive at a level where it has fewer pixels.
        min_parallax: a view whose translation is below this fraction of the
            median depth is flagged ``low_parallax``.
        min_valid_fraction: a view in which fewer primitive pixels project
            inside the image is flagged ``low_overlap``.
        depth_stage: with ``shape_model="scaled"``, solve the scales once more
            at the finest level with every pose held and continuity factors
            between adjacent primitives across weak image edges
            (:func:`spgeo.graph.builders.continuity_factors`); the poses are
            those of the solve before it.  Default True (docs/results.md, issue
            54, has the measurements); the VO's two-view initialisation sets
            False (its window re-solves the scales).
        marginals: compute per-primitive scale stds and pose covariances.
        max_log_scale_std: primitives whose gauge-free log-scale std exceeds
            this (0.5: a factor 1.65 in depth) are unconstrained by the views
            (e.g. textureless, or seen by no view): they are listed in
            ``SfMResult.unconstrained`` and left out of ``depth`` instead of
            reporting a depth the data does not support (needs ``marginals``).
        lm_lambda_initial: initial LM damping.
        chunk: primitives per gtsam factor (default 32; 1 = one factor per
            primitive and view; the cost and its linear system are the same,
            :class:`PhotometricFactorGroup`; timings in docs/results.md).
    """

    shape_model: str = "scaled"
    levels: int = 4
    max_iterations: Tuple[int, ...] = (30, 20, 15, 10)
    relative_error_tol: float = 1e-4
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    brightness: bool = True
    brightness_prior_sigma: Tuple[float, float] = (0.3, 0.3)
    scale_prior_weight: float = 1e-5
    planar_prior_sigma: float = 2.0
    orientation_choice: bool = True
    ref_prior_sigma: float = 1e-6
    reset_scales: bool = True
    min_level_pixels: int = 4
    rotation_first: bool = True
    init: str = "features"
    features: TwoViewConfig = field(default_factory=lambda: TwoViewConfig(min_inliers=30))
    min_parallax: float = 0.01
    min_valid_fraction: float = 0.3
    depth_stage: bool = True
    marginals: bool = True
    max_log_scale_std: float = 0.5
    lm_lambda_initial: float = 1e-3
    chunk: int = 32

    def __post_init__(self) -> None:
        if self.shape_model not in ("scaled", "planar"):
            raise ValueError(f"shape_model must be 'scaled' or 'planar', got {self.shape_model!r}")
        if self.levels < 1 or not self.max_iterations:
            raise ValueError("levels must be >= 1 and max_iterations non-empty")
        if self.init not in ("features", "twoview", "identity"):
            raise ValueError(f"init must be 'features', 'twoview' or 'identity', "
                             f"got {self.init!r}")
        if self.scale_prior_weight <= 0:
            raise ValueError("scale_prior_weight must be > 0 (it fixes the scale gauge)")
        if self.chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {self.chunk}")
