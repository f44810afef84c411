"""Typed options of the monocular VO: :class:`TrackerConfig` (frame-to-keyframe
tracking) and :class:`OdometryConfig` (keyframes, window mapping,
initialisation), and the primitive-shape ablations :data:`PRIMITIVE_MODELS`."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional, Tuple

from ..factors.photometric import PhotometricConfig
from ..sfm import SfMConfig
from ..validation import InputError
from .feature_retry import FeatureRetryConfig
from .pixels import PixelSelectionConfig

__all__ = ["TrackerConfig", "OdometryConfig", "PRIMITIVE_MODELS", "INIT_METHODS"]

#: ``OdometryConfig.primitive_model`` values: ``"integrated"`` (the paper's model),
#: ``"constant_depth"`` (each primitive a fronto-parallel plane at its anchor depth),
#: ``"constant_normal"`` (the least-squares plane of its integrated shape) and
#: ``"planar"`` (those planes with their three parameters optimised in mapping).
PRIMITIVE_MODELS = ("integrated", "constant_depth", "constant_normal", "planar")

#: how a monocular map's initialisation SfM starts (``OdometryConfig.init_method``)
INIT_METHODS = ("twoview", "tracked")


@dataclass(frozen=True)
class TrackerConfig:
    """Options of :func:`spgeo.vo.tracking.track_frame`.

    Attributes:
        levels: pyramid levels used, coarse-to-fine (default 3: 160x120 ->
            40x30 coarsest).  Limited by the keyframe's pyramid.
        iterations: maximum LM iterations per level, coarsest first (the last
            value repeats for further levels); default ``(20, 12, 8)``.
        photometric: per-pixel cost options, identical to the factors'
            (:class:`PhotometricConfig`; default Huber 0.04, per-primitive
            mean over valid pixels, behind-camera penalty 0.5).
        brightness: estimate the frame's affine brightness ``(a, b)``
            (``exp(-a) I_frame + b`` is compared with the keyframe).
        brightness_prior_sigma: sigmas of the prior pulling ``(a, b)`` to
            ``(0, 0)``, as :func:`spgeo.factors.priors.brightness_prior`;
            None (default): no prior.  With the per-primitive mean cost the
            contrast direction of ``(a, b)`` has a curvature of only about
            ``N_primitives * var(I)``: the SfM graph's ``(0.3, 0.3)`` would
            pull a real gain change most of the way back to 1.
        lm_lambda_initial: initial LM damping (multiplies ``diag(H)``).
        lm_lambda_factor: damping multiplier on a rejected step / divisor
            on an accepted one.
        lm_lambda_max: a level stops when the damping exceeds this (no step
            decreases the cost any more).
        relative_cost_tol: a level stops when an accepted step decreases the
            cost by less than this fraction (default 1e-3).
        rotation_tol: a level stops when a step (accepted or rejected) turns
            by less than this (radians; default 5e-5, 0.003 deg) and moves by
            less than ``translation_tol``.
        translation_tol: translation step threshold as a fraction of the
            keyframe's median depth (default 5e-5: 0.1 mm at 2 m).
        min_level_pixels: primitives with fewer pixels at a level are left
            out of that level (as :class:`spgeo.sfm.SfMConfig`; default 4).
        subsample: extra pixel stride per level (level 0 first; the last
            value repeats): at level ``l`` only pixels on the
            ``2^l * subsample[l]`` lattice are used.  Default ``(1,)``: the
            exact factor-graph cost at every level.
        min_valid_fraction: status ``"lost"`` when fewer of the decision
            pixels (``decision_width``) project inside the frame at the final
            pose (default 0.3).
        max_relative_cost: status ``"lost"`` when the final photometric cost
            exceeds this fraction of the cost of a featureless frame (every
            residual ``mean(I_kf) - I_kf``, same valid pixels), both on the
            decision pixels: default 0.35 (a tracked frame is well below, a
            different scene or a blank frame near 1).
        decision_width: the tracking decisions (``min_valid_fraction``,
            ``max_relative_cost`` and the keyframe thresholds of
            :class:`OdometryConfig`) are taken on the *decision pixels*: the
            primitive pixels of the finest level on a lattice of stride
            ``round(width / decision_width)`` (default 160: every pixel at
            160x120, every other one at 320x240), whatever pixels the pose was
            optimised on (pixel selection, subsampling).
        decision_iterations: when the finest level was optimised on fewer
            pixels than the decision pixels (pixel selection), at most this
            many LM steps on the decision pixels refine the pose before the
            decisions (default 2; 0: none).
        max_cost_increase: with ``reference_cost`` given to
            :func:`~spgeo.vo.tracking.track_frame` (e.g. the previous frame's
            final cost against the same keyframe), status ``"lost"`` when the
            final cost exceeds ``max_cost_increase * reference_cost`` (default 10).
    """

    levels: int = 3
    iterations: Tuple[int, ...] = (20, 12, 8)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    brightness: bool = True
    brightness_prior_sigma: Optional[Tuple[float, float]] = None
    lm_lambda_initial: float = 1e-4
    lm_lambda_factor: float = 10.0
    lm_lambda_max: float = 1e5
    relative_cost_tol: float = 1e-3
    rotation_tol: float = 5e-5
    translation_tol: float = 5e-5
    min_level_pixels: int = 4
    subsample: Tuple[int, ...] = (1,)
    min_valid_fraction: float = 0.3
    max_relative_cost: float = 0.35
    max_cost_increase: float = 10.0
    decision_width: int = 160
    decision_iterations: int = 2

    def __post_init__(self) -> None:
        if self.levels < 1:
            raise InputError(f"TrackerConfig.levels must be >= 1, got {self.levels}")
        if not self.iterations or any(int(i) < 0 for i in self.iterations):
            raise InputError("TrackerConfig.iterations must be a non-empty tuple of counts >= 0")
        if not self.subsample or any(int(s) < 1 for s in self.subsample):
            raise InputError("TrackerConfig.subsample must be a non-empty tuple of strides >= 1")
        if self.brightness_prior_sigma is not None and (
                len(self.brightness_prior_sigma) != 2
                or not all(s > 0 for s in self.brightness_prior_sigma)):
            raise InputError("TrackerConfig.brightness_prior_sigma must be None or two sigmas > 0")
        if not (self.lm_lambda_initial > 0 and self.lm_lambda_factor > 1 and self.lm_lambda_max > 0):
            raise InputError("TrackerConfig: LM damping parameters must be positive "
                             "(lambda_factor > 1)")
        if not 0 <= self.min_valid_fraction <= 1:
            raise InputError("TrackerConfig.min_valid_fraction must be in [0, 1]")
        if not self.max_relative_cost > 0 or not self.max_cost_increase > 0:
            raise InputError("TrackerConfig.max_relative_cost and max_cost_increase must be > 0")
        if self.decision_width < 1 or self.decision_iterations < 0:
            raise InputError("TrackerConfig: decision_width >= 1 and decision_iterations >= 0 "
                             "required")


@dataclass(frozen=True)
class OdometryConfig:
    """Options of :class:`spgeo.vo.Odometry` (defaults: docs/design.md §5 where
    it gives one; the others chosen on synthetic 160x120 hand-held sequences,
    ``python -m spgeo.evaluation.vo.synthetic``; measurements in
    docs/results.md).

    Attributes:
        tracker: :class:`TrackerConfig` of frame-to-keyframe tracking.
        kf_min_valid_fraction: new keyframe when fewer of the latest
            keyframe's primitive pixels project into the frame (default 0.6).
        kf_max_translation: new keyframe when the translation from the latest
            keyframe over its median depth exceeds this (default 0.2).
        kf_max_relative_cost: new keyframe when the tracked frame's relative
            photometric cost (``TrackResult.relative_cost``) exceeds this
            (default 0.2; the tracker declares ``"lost"`` at 0.35, and slow
            hand-held motion reaches that before the translation threshold).
        kf_max_rotation_deg: new keyframe when the rotation from the latest
            keyframe exceeds this (default 15 degrees).
        window: keyframes kept in the smoother (default 5, >= 2); older ones
            are marginalised.
        n_support: supporting non-keyframes linked to each keyframe (paper: 4; default 2,
            docs/results.md says why).
        covisible_links: besides the previous keyframe, a new keyframe is
            linked (photometric factors both ways) to up to this many older
            window keyframes, those sharing the largest view with it (default
            0: the paper's chain; docs/results.md says why).
        covisible_min_overlap: an older keyframe is linked only when at least
            this fraction of its primitive pixels project into the new
            keyframe's image (default 0.5).
        levels: pyramid levels of the keyframes (default 3).
        map_level: pyramid level of the mapping factors (default 1: half
            resolution, 80x60 at 160x120), in ``[0, levels)``: speed against
            accuracy (level 0 is more accurate and slower).
        map_stride: extra pixel stride of the mapping factors on that level's
            lattice (default 1).
        map_pixel_fraction: fraction of the level's primitive pixels used by
            mapping, those with the largest reference image gradient (at least
            ``min_level_pixels`` per primitive), in (0, 1] (default 1: all).
        pixel_budget: about this many tracking pixels per pyramid level,
            selected by :func:`spgeo.vo.pixels.select_pixels` with
            ``pixel_selection``'s options (default 1500; docs/results.md
            says why); None: every primitive pixel of a level's lattice.
        map_pixel_budget: the same for the mapping factors at ``map_level``
            (None, default: every pixel there).
        pixel_selection: :class:`~spgeo.vo.pixels.PixelSelectionConfig` (its
            ``budget`` is replaced by ``pixel_budget`` / ``map_pixel_budget``).
        map_iterations: LM iterations per smoother update (default 10).
        map_relative_tol: an update stops when an LM iteration lowers the
            window's cost by less than this fraction (default 1e-2: every
            keyframe stays in ``window`` updates).
        map_lambda_initial: initial LM damping of every window update
            (default 1e-5, gtsam's).
        map_lambda_max: an LM iteration gives up when its damping exceeds
            this (default 1e3; each rejected trial costs a solve and a cost
            evaluation of the whole window, and near convergence gtsam keeps
            raising the damping until this bound).
        map_chunk: shape-variable columns per gtsam factor in mapping
            (default 128: 128 scaled or 42 planar primitives; 1 = one factor
            per primitive; the cost and the Gauss-Newton system
            are identical, :class:`~spgeo.factors.photometric.PhotometricFactorGroup`,
            whose chunks are in square-root form).  gtsam's Python
            ``CustomFactor`` copies the whole ``Values`` on every call, so
            per-primitive factors make a window update quadratic in its size;
            very large chunks make gtsam's dense blocks large instead.
        photometric: per-pixel cost of the mapping factors.
        primitive_model: one of :data:`PRIMITIVE_MODELS` (ablations).
        scale_prior_weight: weight of each log-scale's prior to its initial
            value (paper: 1e-5).
        planar_slope_sigma: sigma of the planar model's slope prior (towards
            fronto-parallel; default 2, weak).
        render_prior_weight: weight of the prior of a new keyframe's
            primitive scale to its rendered value (primitives the render did
            not reach keep ``scale_prior_weight`` with a monocular front-end).
            Default 1e-2 (sigma 10 in log-scale; for planes, in inverse
            depth): large against the noise that moved unobservable scales,
            small against the photometric information of a primitive seen
            with parallax.
        kf_depth_link_sigma: sigma (log units) of the mean depth consistency
            of a new keyframe with the previous one
            (:class:`~spgeo.factors.depth_consistency.DepthConsistencyFactor`);
            None (default) disables it.
        kf_depth_link_tolerance: correspondences whose log depth ratio is
            further than this from the median are occlusions and left out
            (default 0.1).
        kf_depth_link_primitives: the factor uses the correspondences of at
            most this many primitives per keyframe, those with the most
            (default 32): it joins its shape variables in one dense block.
        brightness_prior_sigma: sigmas of the brightness ``(a, b)`` priors.
        gauge_sigma: sigma of the first keyframe's pose prior.
        min_level_pixels: primitives with fewer pixels at ``map_level`` get no
            mapping factor.
        render_splat: splat size when rendering the window into a new keyframe.
        render_tolerance: the window's keyframes are rendered into a new
            keyframe with this log-depth tolerance of
            :func:`~spgeo.vo.rendering.render_depth`: depths within it of a
            pixel's nearest are averaged (0: the nearest wins, which biases
            overlapping estimates of one surface towards the camera and makes
            the monocular scale shrink keyframe after keyframe).
        kf_scale_check: monocular front-ends: after a new keyframe's
            log-scales are rendered from the window, the previous keyframe's
            image is tracked against it and its log-scales are shifted so
            that the tracked translation matches the known one
            (:func:`~spgeo.vo.scale_check.reverse_scale_check`; default True;
            docs/results.md says why).
        kf_scale_check_min_parallax: ... only when the two keyframes'
            translation over the new one's median depth reaches this
            (default 0.01).
        kf_scale_check_max_change: ... by a factor of at most
            ``1 + kf_scale_check_max_change`` either way (default 0.2, > 0).
        propagate_shape: monocular front-ends: a new keyframe's primitives
            that the rendered window covers take the shape integrated from the
            render's normals (:mod:`spgeo.vo.shape_propagation`) instead of the
            front-end's (default False; docs/results.md says why).
        propagate_min_coverage: ... when at least this fraction (0, 1] of a
            primitive's pixels has a rendered normal (default 0.6).
        init_min_parallax: keyframe 1 is the first frame whose tracked
            translation over keyframe 0's median depth reaches this
            (default 0.08) ...
        init_max_gap: ... or the frame this many frames after keyframe 0
            (default 30: 1 s at 30 Hz), or the first frame whose tracking
            against keyframe 0 fails (large motion; its initialisation is
            kept only when the SfM's status is ``"ok"`` and its own baseline
            reaches ``init_min_parallax``).  A keyframe pair without parallax
            (the SfM flags keyframe 1's view ``"low_parallax"``) never
            initialises a map: the frames stay ``init`` / ``lost``, the SfM
            is retried at gaps growing by half (:attr:`Odometry.init_failure`
            says why; :func:`spgeo.vo.initialisation.init_rejection`).
        init_min_gap: keyframe 1 is at least this many frames after keyframe
            0 (default 3; ``1 <= init_min_gap <= init_max_gap``).
        init_method: how a monocular map's initialisation SfM starts:
            ``"twoview"`` (default): keyframe 1's pose and keyframe 0's
            primitive scales from feature-based two-view geometry
            (:func:`~spgeo.vo.initialisation.twoview_start`), falling back to
            ``"tracked"`` when that has no estimate; ``"tracked"``: keyframe 1's
            pose tracked against keyframe 0's unscaled primitives, every
            primitive at depth 1.  A depth-using front-end always starts from
            the tracked pose and its metric scales.
        init_extra_views: frames between keyframes 0 and 1 (evenly spaced)
            added as supporting views to the initialisation's SfM (default
            1): with keyframe 1 alone the monocular structure of keyframe 0
            fits that one baseline.  0 is the plain two-view initialisation.
        max_lost_frames: re-initialise after this many consecutive lost frames
            (default 10).
        sfm: :class:`SfMConfig` of the two-view initialisation (its
            ``reset_scales`` is overridden: False with a depth-using
            front-end, True otherwise).
        feature_retry: :class:`~spgeo.vo.feature_retry.FeatureRetryConfig`:
            when tracking against the latest keyframe fails, a PnP pose from
            features lifted with its primitive depth restarts the tracker.
    """

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    kf_min_valid_fraction: float = 0.6
    kf_max_translation: float = 0.2
    kf_max_relative_cost: float = 0.2
    kf_max_rotation_deg: float = 15.0
    window: int = 5
    n_support: int = 2
    covisible_links: int = 0
    covisible_min_overlap: float = 0.5
    levels: int = 3
    map_level: int = 1
    map_stride: int = 1
    map_iterations: int = 10
    map_relative_tol: float = 1e-2
    map_lambda_max: float = 1e3
    map_lambda_initial: float = 1e-5
    map_pixel_fraction: float = 1.0
    pixel_budget: Optional[int] = 1500
    map_pixel_budget: Optional[int] = None
    pixel_selection: PixelSelectionConfig = field(default_factory=PixelSelectionConfig)
    map_chunk: int = 128
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    primitive_model: str = "integrated"
    scale_prior_weight: float = 1e-5
    planar_slope_sigma: float = 2.0
    render_prior_weight: float = 1e-2
    kf_depth_link_sigma: Optional[float] = None
    kf_depth_link_tolerance: float = 0.1
    kf_depth_link_primitives: int = 32
    brightness_prior_sigma: tuple = (0.3, 0.3)
    gauge_sigma: float = 1e-6
    min_level_pixels: int = 4
    render_splat: int = 2
    render_tolerance: float = 0.2
    kf_scale_check: bool = True
    kf_scale_check_min_parallax: float = 0.01
    kf_scale_check_max_change: float = 0.2
    propagate_shape: bool = False
    propagate_min_coverage: float = 0.6
    init_min_parallax: float = 0.08
    init_max_gap: int = 30
    init_min_gap: int = 3
    init_method: str = "twoview"
    init_extra_views: int = 1
    max_lost_frames: int = 10
    sfm: SfMConfig = field(default_factory=lambda: SfMConfig(levels=3, marginals=False))
    feature_retry: FeatureRetryConfig = field(default_factory=FeatureRetryConfig)

    def __post_init__(self) -> None:
        if self.window < 2:
            raise InputError(f"OdometryConfig.window must be >= 2, got {self.window}")
        if not 0 <= self.map_level < self.levels:
            raise InputError("OdometryConfig.map_level must be in [0, levels)")
        if (self.map_stride < 1 or self.map_iterations < 1 or self.init_max_gap < 1
                or self.max_lost_frames < 1):
            raise InputError("OdometryConfig: map_stride, map_iterations, init_max_gap and "
                             "max_lost_frames must be >= 1")
        if self.map_chunk < 1:
            raise InputError("OdometryConfig.map_chunk must be >= 1")
        if not 0 < self.map_pixel_fraction <= 1:
            raise InputError("OdometryConfig.map_pixel_fraction must be in (0, 1]")
        if any(b is not None and b < 1 for b in (self.pixel_budget, self.map_pixel_budget)):
            raise InputError("OdometryConfig: pixel_budget and map_pixel_budget must be None "
                             "or >= 1")
        if not self.map_lambda_initial > 0:
            raise InputError("OdometryConfig.map_lambda_initial must be > 0")
        if self.init_method not in INIT_METHODS:
            raise InputError(f"OdometryConfig.init_method must be one of {INIT_METHODS}, "
                             f"got {self.init_method!r}")
        if self.init_extra_views < 0:
            raise InputError("OdometryConfig.init_extra_views must be >= 0")
        if not 1 <= self.init_min_gap <= self.init_max_gap:
            raise InputError("OdometryConfig: 1 <= init_min_gap <= init_max_gap required")
        if self.n_support < 0:
            raise InputError("OdometryConfig.n_support must be >= 0")
        if not self.scale_prior_weight > 0:
            raise InputError("OdometryConfig.scale_prior_weight must be > 0")
        if not self.render_prior_weight > 0:
            raise InputError("OdometryConfig.render_prior_weight must be > 0")
        if self.kf_depth_link_sigma is not None and not self.kf_depth_link_sigma > 0:
            raise InputError("OdometryConfig.kf_depth_link_sigma must be > 0 or None")
        if not self.kf_depth_link_tolerance > 0 or self.kf_depth_link_primitives < 1:
            raise InputError("OdometryConfig: kf_depth_link_tolerance > 0 and "
                             "kf_depth_link_primitives >= 1 required")
        if not 0 <= self.kf_min_valid_fraction <= 1 or not self.kf_max_translation > 0:
            raise InputError("OdometryConfig: kf_min_valid_fraction in [0, 1] and "
                             "kf_max_translation > 0 required")
        if self.primitive_model not in PRIMITIVE_MODELS:
            raise InputError(f"OdometryConfig.primitive_model must be one of {PRIMITIVE_MODELS}, "
                             f"got {self.primitive_model!r}")
        for name, ok, expected in (
                ("init_min_parallax", self.init_min_parallax >= 0, ">= 0"),
                ("kf_max_rotation_deg", self.kf_max_rotation_deg > 0, "> 0"),
                ("kf_max_relative_cost", self.kf_max_relative_cost > 0, "> 0"),
                ("render_tolerance", self.render_tolerance >= 0, ">= 0"),
                ("kf_scale_check_min_parallax", self.kf_scale_check_min_parallax >= 0, ">= 0"),
                ("kf_scale_check_max_change", self.kf_scale_check_max_change > 0, "> 0"),
                ("propagate_min_coverage", 0 < self.propagate_min_coverage <= 1, "in (0, 1]"),
                ("gauge_sigma", self.gauge_sigma > 0, "> 0"),
                ("planar_slope_sigma", self.planar_slope_sigma > 0, "> 0"),
                ("map_lambda_max", self.map_lambda_max > 0, "> 0"),
                ("map_relative_tol", self.map_relative_tol >= 0, ">= 0"),
                ("covisible_min_overlap", 0 <= self.covisible_min_overlap <= 1, "in [0, 1]")):
            if not ok:    # NaN fails every comparison
                raise InputError(f"OdometryConfig.{name} must be {expected}, "
                                 f"got {getattr(self, name)!r}")
        for name in ("levels", "render_splat", "min_level_pixels"):
            if getattr(self, name) < 1:
                raise InputError(f"OdometryConfig.{name} must be >= 1, got {getattr(self, name)!r}")
        if self.covisible_links < 0:
            raise InputError(f"OdometryConfig.covisible_links must be >= 0, "
                             f"got {self.covisible_links!r}")

    @property
    def selection(self) -> Optional[PixelSelectionConfig]:
        """The tracker's pixel selection (None without ``pixel_budget``)."""
        if self.pixel_budget is None:
            return None
        return dataclasses.replace(self.pixel_selection, budget=int(self.pixel_budget))

    @property
    def map_selection(self) -> Optional[PixelSelectionConfig]:
        """The mapping factors' pixel selection (None without ``map_pixel_budget``)."""
        if self.map_pixel_budget is None:
            return None
        return dataclasses.replace(self.pixel_selection, budget=int(self.map_pixel_budget))
