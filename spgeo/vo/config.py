"""Typed options of the monocular VO: :class:`TrackerConfig` (frame-to-keyframe
tracking) and :class:`OdometryConfig` (keyframes, window mapping,
initialisation); the primitive-shape ablations are
:data:`spgeo.primitive_models.PRIMITIVE_MODELS`."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from ..configs import config_class
from ..factors.photometric import PhotometricConfig
from ..loop.config import LoopClosureConfig
from ..primitive_models import PRIMITIVE_MODELS
from ..sfm import SfMConfig
from ..validation import MAX_IMAGE_SIDE, InputError
from .feature_retry import FeatureRetryConfig
from .landmarks import LandmarkConfig
from .pixels import PixelSelectionConfig
from .processing import DEFAULT_TARGET_PIXELS, processing_size

__all__ = ["TrackerConfig", "KeyframeDecisionConfig", "ScaleCheckConfig", "InitConfig",
           "MappingConfig", "OdometryConfig", "INIT_METHODS", "MAPPING_MODES", "MAPPING_SCHEDULES"]

#: how a monocular map's initialisation SfM starts (``InitConfig.method``)
INIT_METHODS = ("twoview", "tracked")
#: where the VO's back end runs (``MappingConfig.mode``)
MAPPING_MODES = ("live", "inline")
#: when live mapping's updates are applied (``MappingConfig.schedule``)
MAPPING_SCHEDULES = ("fixed", "ready")


@config_class
@dataclass(frozen=True)
class TrackerConfig:
    """Options of :func:`spgeo.vo.tracking.track_frame`.

    Attributes:
        levels: pyramid levels used, coarse-to-fine (default 3: 160x120 ->
            40x30 coarsest).  Limited by the keyframe's pyramid.
        iterations: maximum LM iterations per level, coarsest first (the last
            value repeats for further levels); default ``(20, 12, 8)``.
        photometric: per-pixel cost options of tracking and of the mapping
            factors (one cost: :class:`PhotometricConfig`; default Huber 0.04,
            per-primitive mean over valid pixels, behind-camera penalty 0.5).
        brightness: estimate the frame's affine brightness ``(a, b)``
            (``exp(-a) I_frame + b`` is compared with the keyframe).
            No prior pulls ``(a, b)`` to ``(0, 0)``: with the per-primitive
            mean cost the contrast direction has a curvature of only about
            ``N_primitives * var(I)``, and the SfM graph's prior
            (``SfMConfig.brightness_prior_sigma``) would pull a real gain
            change most of the way back to 1.
        relative_cost_tol: a level stops when an accepted step decreases the
            cost by less than this fraction (default 1e-3).  The other LM
            constants (damping, step tolerances) are
            :mod:`spgeo.vo.tracking`'s module constants.
        min_level_pixels: primitives with fewer pixels at a level are left
            out of that level, and out of the mapping factors at
            ``OdometryConfig.mapping.level`` (as :class:`spgeo.sfm.SfMConfig`;
            default 4).
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
            :class:`KeyframeDecisionConfig`) are taken on the *decision pixels*: the
            primitive pixels of the finest level on a lattice of stride
            ``round(width / decision_width)`` (default 160: every pixel at
            160x120, every other one at 320x240), whatever pixels the pose was
            optimised on (pixel selection).
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
    relative_cost_tol: float = 1e-3
    min_level_pixels: int = 4
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
        if not 0 <= self.min_valid_fraction <= 1:
            raise InputError("TrackerConfig.min_valid_fraction must be in [0, 1]")
        if not self.max_relative_cost > 0 or not self.max_cost_increase > 0:
            raise InputError("TrackerConfig.max_relative_cost and max_cost_increase must be > 0")
        if self.decision_width < 1 or self.decision_iterations < 0:
            raise InputError("TrackerConfig: decision_width >= 1 and decision_iterations >= 0 "
                             "required")


@config_class
@dataclass(frozen=True)
class KeyframeDecisionConfig:
    """When a frame tracked against the latest keyframe becomes a keyframe
    (``OdometryConfig.keyframe``): when any threshold is crossed, on the
    tracker's decision pixels.

    Attributes:
        min_valid_fraction: fewer of the latest keyframe's primitive pixels
            project into the frame (fraction in [0, 1]; default 0.6).
        max_translation: the translation from the latest keyframe over its
            median depth exceeds this (unitless, > 0; default 0.2).
        max_relative_cost: the tracked frame's relative photometric cost
            (``TrackResult.relative_cost``) exceeds this (> 0; default 0.2:
            the tracker declares ``"lost"`` at 0.35, and slow hand-held motion
            reaches that before the translation threshold).
        max_rotation_deg: the rotation from the latest keyframe exceeds this
            (degrees, > 0; default 15).
    """

    min_valid_fraction: float = 0.6
    max_translation: float = 0.2
    max_relative_cost: float = 0.2
    max_rotation_deg: float = 15.0


@config_class
@dataclass(frozen=True)
class ScaleCheckConfig:
    """The reverse scale check of a new monocular keyframe
    (``OdometryConfig.scale_check``; :func:`~spgeo.vo.scale_check.reverse_scale_check`).

    Attributes:
        enabled: monocular front-ends: after a new keyframe's log-scales are
            rendered from the window, the previous keyframe's image is tracked
            against it and its log-scales are shifted so that the tracked
            translation matches the known one (default True; docs/results.md
            says why).
        min_parallax: ... only when the two keyframes' translation over the
            new one's median depth reaches this (unitless, >= 0; default 0.01).
        max_change: ... by a factor of at most ``1 + max_change`` either way
            (> 0; default 0.05: on the synthetic street larger limits let biased
            checks under forward motion compound; docs/results.md, issue 51).
    """

    enabled: bool = True
    min_parallax: float = 0.01
    max_change: float = 0.05


@config_class
@dataclass(frozen=True)
class InitConfig:
    """The initialisation of a map segment (``OdometryConfig.init``;
    :class:`spgeo.vo.initialisation.Initialiser`).

    Attributes:
        min_parallax: keyframe 1 is the first frame whose tracked translation
            over keyframe 0's median depth reaches this (unitless, >= 0;
            default 0.08) ...
        max_gap: ... or the frame this many frames after keyframe 0 (default
            30: 1 s at 30 Hz), or the first frame whose tracking against
            keyframe 0 fails (large motion; its initialisation is kept only
            when the SfM's status is ``"ok"`` and its own baseline reaches
            ``min_parallax``).  A keyframe pair without parallax (the SfM flags
            keyframe 1's view ``"low_parallax"``) never initialises a map: the
            frames stay ``init`` / ``lost``, the SfM is retried at gaps growing
            by half (:attr:`Odometry.init_failure` says why;
            :func:`spgeo.vo.initialisation.init_rejection`).
        min_gap: keyframe 1 is at least this many frames after keyframe 0
            (default 3; ``1 <= min_gap <= max_gap``).
        method: how a monocular map's initialisation SfM starts (one of
            :data:`INIT_METHODS`): ``"twoview"`` (default): keyframe 1's pose
            and keyframe 0's primitive scales from feature-based two-view
            geometry (:func:`~spgeo.vo.initialisation.twoview_start`), falling
            back to ``"tracked"`` when that has no estimate; ``"tracked"``:
            keyframe 1's pose tracked against keyframe 0's unscaled primitives,
            every primitive at depth 1.  (A depth-using front-end has no
            initialisation: its keyframe 0 comes with the sensor depth's scale.)
        extra_views: frames between keyframes 0 and 1 (evenly spaced) added as
            supporting views to the initialisation's SfM (>= 0; default 1):
            with keyframe 1 alone the monocular structure of keyframe 0 fits
            that one baseline.  0 is the plain two-view initialisation.
        min_parallax_deg: an alternative to ``min_parallax`` for a keyframe 1
            that tracking against keyframe 0 lost (large motion): its SfM also
            passes when the ``parallax_percentile``-th percentile of the
            triangulation angles of keyframe 0's constrained primitives seen
            from keyframes 0 and 1 (degrees,
            :func:`~spgeo.vo.initialisation.sfm_parallax_deg`) reaches this:
            the near structure's parallax, which opens under forward motion in
            a deep scene where ``|t| / median depth`` stays small (degrees > 0,
            default 8; None: off).  A pure rotation has no triangulation angle.
            Measured (issue 30): the KITTI clip's SfM of keyframes 0 and 4
            (``|t| / median depth`` 0.062) has 12.7 degrees, the synthetic
            rooms' SfMs at 0.071-0.073 have 5.4-6.1 (they keep waiting for
            0.08, as before).
        parallax_percentile: that percentile (in [0, 100]; default 95: the
            nearest twentieth of the structure).
    """

    min_parallax: float = 0.08
    max_gap: int = 30
    min_gap: int = 3
    method: str = "twoview"
    extra_views: int = 1
    min_parallax_deg: Optional[float] = 8.0
    parallax_percentile: float = 95.0


@config_class
@dataclass(frozen=True)
class MappingConfig:
    """Where, when and how the VO's back end runs (``OdometryConfig.mapping``; the
    mapping port, :mod:`spgeo.vo.mapping_port`, and the window smoother,
    :mod:`spgeo.vo.smoother`).

    Attributes:
        mode: where a new keyframe's landmarks and window update run, one of
            :data:`MAPPING_MODES`: ``"live"`` (default) in a worker process
            (:mod:`spgeo.vo.mapping_worker`) while the next frames are tracked
            against the map before the update; ``"inline"`` between two frames,
            in this process (the smoother can be reached).  Both run the same
            back end (landmarks, loop closure, window update) through the
            mapping port.
        lead: live mapping: an update is applied before the frame ``lead``
            frames after its keyframe, waited for when not ready (>= 0; default
            8, about what a 30 Hz camera gives during one update on two cores;
            docs/results.md).  Frames may apply it earlier (a keyframe decision,
            a lost frame), the same way on any machine.
        schedule: live mapping, one of :data:`MAPPING_SCHEDULES`: ``"fixed"``
            (default; recorded input) only the rule above, so the trajectory does
            not depend on the machine or its load; ``"ready"`` (a live camera) the
            tracker never waits for the back end: the update is applied at the
            first frame that finds it ready (``lead`` unused) and a keyframe wanted
            before it is deferred (:class:`~spgeo.vo.keyframe_policy.KeyframePolicy`).
        level: pyramid level of the mapping factors (default 1: half resolution,
            80x60 at 160x120), in ``[0, OdometryConfig.keyframe_levels)``: speed
            against accuracy (level 0 is more accurate and slower).
        iterations: LM iterations per smoother update (>= 1; default 10; the
            other LM constants are :mod:`spgeo.vo.smoother`'s module constants).
        pixel_fraction: fraction of the level's primitive pixels used by mapping,
            those with the largest reference image gradient (at least
            ``tracker.min_level_pixels`` per primitive), in (0, 1] (default 1: all).
        chunk: shape-variable columns per gtsam factor in mapping (>= 1; default
            128: 128 scaled or 42 planar primitives; 1 = one factor per primitive;
            the cost and the Gauss-Newton system are identical,
            :class:`~spgeo.factors.photometric_group.PhotometricFactorGroup`, whose
            chunks are in square-root form).  gtsam's Python ``CustomFactor``
            copies the whole ``Values`` on every call, so per-primitive factors
            make a window update quadratic in its size; very large chunks make
            gtsam's dense blocks large instead.
    """

    mode: str = "live"
    lead: int = 8
    schedule: str = "fixed"
    level: int = 1
    iterations: int = 10
    pixel_fraction: float = 1.0
    chunk: int = 128

    @property
    def in_worker(self) -> bool:
        """Whether the back end runs in the mapping worker process (``mode`` ``"live"``)."""
        return self.mode == "live"

    def __post_init__(self) -> None:
        if self.mode not in MAPPING_MODES:
            raise InputError(f"MappingConfig.mode (OdometryConfig.mapping.mode) must be one of "
                             f"{MAPPING_MODES}, got {self.mode!r}")
        if self.schedule not in MAPPING_SCHEDULES:
            raise InputError(f"MappingConfig.schedule (OdometryConfig.mapping.schedule) must be "
                             f"one of {MAPPING_SCHEDULES}, got {self.schedule!r}")


#: what each condition name of :data:`_ODOMETRY_CHECKS` requires of a value
_CONDITIONS = {
    ">= 0": lambda v: v >= 0,
    "> 0": lambda v: v > 0,
    ">= 1": lambda v: v >= 1,
    ">= 2": lambda v: v >= 2,
    "in [0, 1]": lambda v: 0 <= v <= 1,
    "in (0, 1]": lambda v: 0 < v <= 1,
    "None or >= 1": lambda v: v is None or v >= 1,
    "None or > 0": lambda v: v is None or v > 0,
    "in [0, 100]": lambda v: 0 <= v <= 100,
}

#: ``(field, condition)`` checks of :meth:`OdometryConfig.__post_init__`, in order
_ODOMETRY_CHECKS = (
    ("window", ">= 2"), ("mapping.iterations", ">= 1"), ("init.max_gap", ">= 1"),
    ("max_lost_frames", ">= 1"), ("mapping.chunk", ">= 1"),
    ("mapping.pixel_fraction", "in (0, 1]"),
    ("pixel_budget", "None or >= 1"), ("init.extra_views", ">= 0"), ("n_support", ">= 0"),
    ("scale_prior_weight", "> 0"), ("render_prior_weight", "> 0"),
    ("keyframe.min_valid_fraction", "in [0, 1]"), ("keyframe.max_translation", "> 0"),
    ("init.min_parallax", ">= 0"), ("keyframe.max_rotation_deg", "> 0"),
    ("keyframe.max_relative_cost", "> 0"), ("render_tolerance", ">= 0"),
    ("scale_check.min_parallax", ">= 0"), ("scale_check.max_change", "> 0"),
    ("keyframe_levels", ">= 1"), ("init.min_parallax_deg", "None or > 0"),
    ("init.parallax_percentile", "in [0, 100]"), ("mapping.lead", ">= 0"))


@config_class
@dataclass(frozen=True)
class OdometryConfig:
    """Options of :class:`spgeo.vo.Odometry` (defaults: docs/design.md §5 where
    it gives one; the others chosen on synthetic 160x120 hand-held sequences,
    ``python -m spgeo.evaluation.vo.synthetic``; measurements in
    docs/results.md).

    Attributes:
        resolution: ``(width, height)`` in pixels the VO works at (frames of
            the input camera's size are resized to it,
            :mod:`spgeo.vo.processing`); default None:
            :func:`~spgeo.vo.processing.processing_size` of the input camera's
            size with ``target_pixels`` (its aspect ratio kept; 4:3 gives 320x240).
        target_pixels: processing area in pixels when ``resolution`` is None
            (default :data:`~spgeo.vo.processing.DEFAULT_TARGET_PIXELS`, that of
            320x240; in [64, 2**26]).
        tracker: :class:`TrackerConfig` of frame-to-keyframe tracking.
        keyframe: :class:`KeyframeDecisionConfig`: when a tracked frame becomes
            a keyframe (default: fewer than 0.6 valid pixels, translation over
            median depth 0.2, relative cost 0.2, rotation 15 degrees).
        window: keyframes kept in the smoother (default 5, >= 2); older ones
            are marginalised.
        n_support: supporting non-keyframes linked to each keyframe (paper: 4; default 2,
            docs/results.md says why).
        keyframe_levels: pyramid levels built for each keyframe (default 3); the
            tracker uses at most ``tracker.levels`` of them, mapping works on
            ``mapping.level``.
        pixel_budget: about this many tracking pixels per pyramid level,
            selected by :func:`spgeo.vo.pixels.select_pixels` with
            ``pixel_selection``'s options (default 1500; docs/results.md
            says why); None: every primitive pixel of a level's lattice.
            The mapping factors use every pixel of ``mapping.level``.
        pixel_selection: :class:`~spgeo.vo.pixels.PixelSelectionConfig` (its
            ``budget`` is replaced by ``pixel_budget``).
        primitive_model: one of :data:`PRIMITIVE_MODELS` (ablations).
        scale_prior_weight: weight of each log-scale's prior to its initial
            value (paper: 1e-5).
        render_prior_weight: weight of the prior of a new keyframe's
            primitive scale to its rendered value (primitives the render did
            not reach keep ``scale_prior_weight`` with a monocular front-end).
            Default 1e-2 (sigma 10 in log-scale; for planes, in inverse
            depth): large against the noise that moved unobservable scales,
            small against the photometric information of a primitive seen
            with parallax.
        render_tolerance: the window's keyframes are rendered into a new
            keyframe with this log-depth tolerance of
            :func:`~spgeo.vo.rendering.render_depth`: depths within it of a
            pixel's nearest are averaged (0: the nearest wins, which biases
            overlapping estimates of one surface towards the camera and makes
            the monocular scale shrink keyframe after keyframe).
        scale_check: :class:`ScaleCheckConfig`: the reverse scale check of a
            new monocular keyframe (default on).
        init: :class:`InitConfig`: when and how a map segment is initialised
            (keyframe 1's parallax and frame gap, the SfM's start and extra views).
        max_lost_frames: re-initialise after this many consecutive lost frames,
            each of which tried relocalisation into the map (landmarks and the
            window's keyframes); also the frames a segment's keyframe 0 waits for
            a frame tracked against it before it starts again (default 30: 1 s at
            30 Hz, 3 s at 10 Hz; with 10 a 12-frame foreign interval re-initialised
            on a foreign view, docs/results.md issue 51).
        sfm: :class:`SfMConfig` of the two-view initialisation (its
            ``reset_scales`` is overridden: False with a depth-using
            front-end, True otherwise; ``init="twoview"``: when keyframe 1 was
            not tracked its start is the two-view pose, as measured for the VO;
            few-view SfM's own default, the landmark bundle, is not measured here;
            ``depth_stage=False``: measured neither better nor worse for the
            VO, docs/results.md, issue 54).
        feature_retry: :class:`~spgeo.vo.feature_retry.FeatureRetryConfig`:
            when tracking against the latest keyframe fails, a PnP pose from
            features lifted with its primitive depth restarts the tracker.
        loop_closure: :class:`~spgeo.loop.LoopClosureConfig` (docs/design.md
            §5.2): with ``enabled``, keyframes are matched against older ones of
            their map segment and a verified loop corrects the segment's
            keyframes with a Sim(3) pose graph (default off).
        landmarks: :class:`~spgeo.vo.landmarks.LandmarkConfig`: sparse feature
            landmarks with projection factors in the window (default on).
        mapping: :class:`MappingConfig`: where, when and how a new keyframe's back
            end (landmarks, loop closure, the window update) runs.
    """

    #: the table of a ``spgeo vo`` config file that is this config's
    #: (:func:`spgeo.configs.own_section`)
    config_section = "odometry"

    resolution: Optional[Tuple[int, int]] = None
    target_pixels: int = DEFAULT_TARGET_PIXELS
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    keyframe: KeyframeDecisionConfig = field(default_factory=KeyframeDecisionConfig)
    window: int = 5
    n_support: int = 2
    keyframe_levels: int = 3
    pixel_budget: Optional[int] = 1500
    pixel_selection: PixelSelectionConfig = field(default_factory=PixelSelectionConfig)
    primitive_model: str = "integrated"
    scale_prior_weight: float = 1e-5
    render_prior_weight: float = 1e-2
    render_tolerance: float = 0.2
    scale_check: ScaleCheckConfig = field(default_factory=ScaleCheckConfig)
    init: InitConfig = field(default_factory=InitConfig)
    max_lost_frames: int = 30
    sfm: SfMConfig = field(default_factory=lambda: SfMConfig(levels=3, marginals=False,
                                                             init="twoview", depth_stage=False))
    feature_retry: FeatureRetryConfig = field(default_factory=FeatureRetryConfig)
    loop_closure: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    landmarks: LandmarkConfig = field(default_factory=LandmarkConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)

    def __post_init__(self) -> None:
        self._check_size()
        if self.init.method not in INIT_METHODS:
            raise InputError(f"OdometryConfig.init.method must be one of {INIT_METHODS}, "
                             f"got {self.init.method!r}")
        if self.primitive_model not in PRIMITIVE_MODELS:
            raise InputError(f"OdometryConfig.primitive_model must be one of {PRIMITIVE_MODELS}, "
                             f"got {self.primitive_model!r}")
        for name, expected in _ODOMETRY_CHECKS:
            value = self
            for part in name.split("."):
                value = getattr(value, part)
            if not _CONDITIONS[expected](value):    # NaN fails every comparison
                raise InputError(f"OdometryConfig.{name} must be {expected}, got {value!r}")
        if not 0 <= self.mapping.level < self.keyframe_levels:
            raise InputError("OdometryConfig.mapping.level must be in [0, keyframe_levels)")
        if not 1 <= self.init.min_gap <= self.init.max_gap:
            raise InputError("OdometryConfig: 1 <= init.min_gap <= init.max_gap required")

    def _check_size(self) -> None:
        if self.resolution is not None:
            res = tuple(self.resolution)
            if len(res) != 2 or not all(isinstance(v, (int, np.integer))
                                        and 0 < v <= MAX_IMAGE_SIDE for v in res):
                raise InputError(f"OdometryConfig.resolution must be None or (width, height) "
                                 f"integers in [1, {MAX_IMAGE_SIDE}] pixels, got "
                                 f"{self.resolution!r}")
            object.__setattr__(self, "resolution", (int(res[0]), int(res[1])))
        tp = self.target_pixels
        if isinstance(tp, bool) or not isinstance(tp, (int, np.integer)) or not 64 <= tp <= 2 ** 26:
            raise InputError(f"OdometryConfig.target_pixels must be an integer in [64, 2**26], "
                             f"got {tp!r}")

    def processing_size_for(self, input_size: Tuple[int, int]) -> Tuple[int, int]:
        """The ``(width, height)`` the VO works at for input frames of ``input_size``:
        ``resolution`` when set, else :func:`~spgeo.vo.processing.processing_size`
        with ``target_pixels``."""
        if self.resolution is not None:
            return self.resolution
        return processing_size(input_size, self.target_pixels)

    @property
    def selection(self) -> Optional[PixelSelectionConfig]:
        """The tracker's pixel selection (None without ``pixel_budget``)."""
        if self.pixel_budget is None:
            return None
        return dataclasses.replace(self.pixel_selection, budget=int(self.pixel_budget))

