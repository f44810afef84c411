"""Keyframe-based monocular visual odometry on SuperPrimitives (DESIGN.md §5).

One thread, one call per frame (:meth:`Odometry.track`):

* **Initialisation.**  The first frame is keyframe 0 (pose identity: the
  gauge).  Following frames are tracked against it (status ``"init"``).
  From ``init_min_gap`` frames on, the first frame with enough parallax
  (translation / median depth >= ``OdometryConfig.init_min_parallax``), or
  that is about to lose keyframe 0 (valid fraction or rotation past the
  keyframe thresholds), or the frame ``init_max_gap`` frames after keyframe
  0, becomes keyframe 1 and few-view SfM
  (:func:`spgeo.sfm.few_view_sfm`, keyframe 0 as reference; keyframe 1 and
  ``init_extra_views`` frames between them as supporting views) gives
  keyframe 0's log-scales and ``T_0_1``.  The frames in between are then re-tracked
  against the solved keyframe 0.  With a depth-using front-end (RGB-D /
  oracle, ``frontend.uses_depth``) keyframe 0's scales start from that depth
  (so the trajectory is metric); with a monocular front-end they start at 0
  and SfM starts from the feature-based two-view pose.
* **Tracking.**  :func:`spgeo.tracking.track_frame` (a batched Gauss-Newton
  / LM over the pyramid minimising exactly the factors' cost, tested) against
  the latest keyframe from a constant-velocity guess, then from the last good
  pose.
* **Failure.**  A frame that cannot be tracked (low valid fraction, cost
  blow-up, divergence) is tried against the window's other keyframes
  (newest first, *relocalisation*); if that fails too it is flagged
  ``"lost"`` and keeps the last good pose.  The first frame tracked after a
  loss is ``"relocalised"``.  After ``max_lost_frames`` consecutive lost
  frames the map is *re-initialised*: the frame becomes keyframe 0 of a new
  map segment (status ``"reinit"``) at the last good pose, the smoother is
  restarted and two-view initialisation runs again.  A monocular re-init
  cannot know the old scale: its depths are set to the last keyframe's median
  depth, so segments may differ in scale (``report.json`` counts segments;
  the status file marks every frame).
* **Keyframes.**  A tracked frame becomes a keyframe when its valid fraction
  drops below ``kf_min_valid_fraction``, its translation from the latest
  keyframe over that keyframe's median depth exceeds ``kf_max_translation``,
  its rotation exceeds ``kf_max_rotation_deg`` or its relative photometric
  cost exceeds ``kf_max_relative_cost``.  Its primitives get log-scales from
  the z-buffered rendering of the window's keyframes
  (:func:`spgeo.rendering.render_primitives`,
  :func:`spgeo.rendering.init_scales_from_render`).
* **Mapping.**  A gtsam ``BatchFixedLagSmoother`` (Levenberg-Marquardt) over
  keyframe poses, per-keyframe primitive shape variables (log-scales, or
  inverse-depth planes with ``primitive_model="planar"``), supporting-frame
  poses and an affine brightness per directed (reference, target) pair.  Each
  new keyframe is linked to the previous one by photometric factors in both
  directions, and the previous keyframe to up to ``n_support`` supporting
  non-keyframes tracked against it (evenly spaced; paper: 4), whose poses are
  optimised too.  One :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor`
  per primitive and pair, built at pyramid level ``map_level``; the factors of
  a pair are evaluated together
  (:class:`~spgeo.factors.photometric.PhotometricFactorGroup`, identical
  values, one vectorised pass).  The first keyframe's pose has a tight gauge
  prior; every shape variable a weak prior (weight ``scale_prior_weight``) to
  its initial value; a new keyframe's primitives whose scale was rendered
  from the map (or, with a depth-using front-end, all of them) get the
  stronger ``render_prior_weight``: the render is a measurement of their
  scale.  This matters after a pure rotation: the photometric factors
  between the two keyframes then carry no parallax, and with only the 1e-5
  priors mapping scattered the new keyframe's per-primitive scales (measured
  after the synthetic seed-1 rotation, depth front-end: the 10th-90th
  percentiles of the primitives' log-depth errors went from -0.07..-0.03 to
  -0.87..+0.53) and the map's scale drifted.  Optionally
  (``kf_depth_link_sigma``) a
  :class:`~spgeo.factors.depth_consistency.DepthConsistencyFactor` also ties
  the new keyframe's mean depth to where the previous keyframe's surface is.  Smoother
  timestamps are keyframe indices (a supporting frame carries its
  keyframe's) and the lag keeps ``window`` keyframes: older keys are
  *marginalised* (their information stays as a linear prior), not
  dropped.  After each update the window's :class:`~spgeo.tracking.Keyframe`
  objects are rebuilt from the smoother's estimate.
* **Trajectory.**  :meth:`Odometry.result` gives keyframes and supporting
  frames at their latest smoothed poses and every other tracked frame at its
  tracked pose relative to its keyframe composed with that keyframe's latest
  pose (lost frames repeat the previous frame's pose).  ``FrameResult`` keeps
  the online (causal) estimate.

Ablations (``OdometryConfig.primitive_model``, DESIGN.md §5): ``"integrated"``
(default, the paper's model), ``"constant_depth"`` (each primitive a
fronto-parallel plane at its anchor depth), ``"constant_normal"`` (each
primitive replaced by the least-squares plane of its integrated shape) and
``"planar"`` (planes as ``constant_normal`` whose three parameters are
optimised in mapping).  Depth-derived (oracle) normals are the ``"depth"``
front-end.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Union

import numpy as np

import gtsam

from .camera import PinholeCamera
from .factors.photometric import (PhotometricConfig, PhotometricFactorGroup, PlanarShape,
                                  ScaledShape)
from .factors.depth_consistency import DepthConsistencyFactor
from .factors.priors import brightness_prior, log_scale_prior, planar_slope_prior, pose_gauge_prior
from .frame import Frame
from .frontend import PrimitiveFrontEnd
from .geometry import invert_pose, rotation_angle_deg
from .jsonio import json_default
from .primitives import PrimitiveSet
from .rendering import init_scales_from_render, render_primitives
from .sfm import SfMConfig, few_view_sfm
from .tracking import Keyframe, TrackerConfig, TrackResult, constant_velocity_guess, track_frame

__all__ = ["OdometryConfig", "FrameResult", "OdometryResult", "Odometry", "PRIMITIVE_MODELS",
           "STATUSES", "kf_pose_key", "kf_scale_key", "kf_brightness_key", "support_pose_key",
           "apply_primitive_model"]

log = logging.getLogger(__name__)

STATUSES = ("init", "ok", "keyframe", "lost", "relocalised", "reinit")
PRIMITIVE_MODELS = ("integrated", "constant_depth", "constant_normal", "planar")
_MAX_PRIMS = 1_000_000


def kf_pose_key(k: int) -> int:
    """Smoother key of keyframe ``k``'s pose ``T_world_kf``."""
    return gtsam.symbol("x", int(k))


def kf_scale_key(k: int, i: int) -> int:
    """Smoother key of primitive ``i``'s shape variable (log-scale, or plane
    with the planar model) in keyframe ``k``."""
    return gtsam.symbol("s", int(k) * _MAX_PRIMS + int(i))


def kf_brightness_key(ref: int, tgt: int) -> int:
    """Smoother key of the affine brightness of keyframe ``tgt`` seen from ``ref``
    (``ref`` and ``tgt`` are consecutive keyframes)."""
    return gtsam.symbol("b" if tgt > ref else "c", int(max(ref, tgt)))


def support_pose_key(frame: int) -> int:
    """Smoother key of supporting frame ``frame``'s pose (frame number)."""
    return gtsam.symbol("f", int(frame))


def _support_brightness_key(frame: int) -> int:
    return gtsam.symbol("d", int(frame))


def apply_primitive_model(primitives: PrimitiveSet, model: str) -> PrimitiveSet:
    """The shapes of an ablation (:data:`PRIMITIVE_MODELS`): ``"integrated"``
    unchanged; ``"constant_depth"``: each primitive fronto-parallel at its
    anchor depth; ``"constant_normal"`` / ``"planar"``: each primitive the
    least-squares inverse-depth plane of its integrated shape."""
    if model == "integrated":
        return primitives
    if model == "constant_depth":
        return primitives.with_scaled_log_depth(np.repeat(primitives.log_scales, primitives.sizes))
    if model in ("constant_normal", "planar"):
        return primitives.with_planes(primitives.fit_planes())[0]
    raise ValueError(f"unknown primitive model {model!r}; expected one of {PRIMITIVE_MODELS}")


@dataclass(frozen=True)
class OdometryConfig:
    """Options of :class:`Odometry` (defaults: DESIGN.md §5 where it gives
    one; the others measured on synthetic 160x120 hand-held sequences, see
    ``evaluation/vo_synthetic.py``).

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
        window: keyframes kept in the smoother (default 5); older ones are
            marginalised.
        n_support: supporting non-keyframes linked to each keyframe (paper: 4).
        levels: pyramid levels of the keyframes (default 3).
        map_level: pyramid level of the mapping factors (default 1: half
            resolution, 80x60 at 160x120).  The choice is speed against
            accuracy: on the 150-frame synthetic runs (seeds 0-3,
            ``python -m spgeo.evaluation.vo_synthetic --seeds 0 1 2 3``) the
            mean per-frame ATE depth / classical / planar was 0.48 / 1.26 /
            1.35 % at level 1 with all pixels, and 0.39 / 0.83 / 0.92 % at
            level 0 with ``map_pixel_fraction=0.5`` (``--set map_level=0
            map_pixel_fraction=0.5``), both within the issue's targets
            (< 1 % depth, < 3 % planar).  Level 1 is the default because the
            >= 10 FPS target must hold on the 2-core CPU, whose speed varies
            up to 2x within a session: level-0 mapping takes 1.6x the time
            (0.92-0.95 against 0.53-0.63 s per keyframe in three ``bench_vo``
            runs, whole pipeline 13.4-13.7 against 14.7-17.0 FPS), and in the
            slower periods the level-0 pipeline fell to 8.0-8.8 FPS.
        map_stride: extra pixel stride of the mapping factors on that level's
            lattice (default 1; a stride of 2 at level 0 was worse than level
            1: it drops three of four pixels on every edge).
        map_pixel_fraction: fraction of the level's primitive pixels used by
            mapping, those with the largest reference image gradient (at least
            ``min_level_pixels`` per primitive; default 1: all).  At level 0,
            0.5 keeps most of the accuracy at half the cost (flat pixels carry
            little pose or depth information: on depth seed 0 mapping took
            1.28 instead of 1.84 s per keyframe for 0.43 instead of 0.37 %
            ATE) and 0.3 lost accuracy on classical seed 1.
        map_iterations: LM iterations per smoother update (default 10).
        map_relative_tol: an update stops when an LM iteration lowers the
            window's cost by less than this fraction (default 1e-2: every
            keyframe stays in ``window`` updates, and 1e-3 doubled the mapping
            time for the same ATE on the synthetic runs).
        map_lambda_initial: initial LM damping of every window update
            (default 1e-5, gtsam's).
        map_lambda_max: an LM iteration gives up when its damping exceeds
            this (default 1e3; each rejected trial costs a solve and a cost
            evaluation of the whole window, and near convergence gtsam keeps
            raising the damping until this bound).
        map_chunk: primitives per gtsam factor in mapping (default 32; 1 =
            one factor per primitive; the cost and the Gauss-Newton system
            are identical, :class:`~spgeo.factors.photometric.PhotometricFactorGroup`,
            whose chunks are in square-root form).  gtsam's Python
            ``CustomFactor`` copies the whole ``Values`` on every call, so
            per-primitive factors make a window update quadratic in its size;
            very large chunks make gtsam's dense blocks large instead (on the
            synthetic runs 32, 64 and one chunk per pair were within timing
            noise of each other; per-primitive factors were 5x slower, see
            ``evaluation/bench_vo.py``).
        photometric: per-pixel cost of the mapping factors.
        primitive_model: :data:`PRIMITIVE_MODELS` (ablations; module docstring).
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
            with parallax.  On the 150-frame synthetic runs (seeds 0-3,
            ``python -m spgeo.evaluation.vo_synthetic --seeds 0 1 2 3 --set
            render_prior_weight=1e-5``) 1e-5 instead gave mean per-frame ATE
            0.78 vs 0.48 % (depth, seed 3 1.35 %), 1.52 vs 1.26 %
            (classical), 1.14 vs 1.35 % (planar); with the former level-0
            mapping (``--set map_level=0 map_pixel_fraction=0.5
            tracker.relative_cost_tol=1e-4``) depth seed 1, with its pure
            rotation, went from 1.98 to 0.34 %.
        kf_depth_link_sigma: sigma (log units) of the mean depth consistency
            of a new keyframe with the previous one
            (:class:`~spgeo.factors.depth_consistency.DepthConsistencyFactor`);
            None (default) disables it.  Measured on the same synthetic runs
            with sigma 0.02 (and ``--set map_level=0 map_pixel_fraction=0.5
            tracker.relative_cost_tol=1e-4``): mean per-frame ATE 0.39 / 0.84
            / 1.04 % (depth / classical / planar) against 0.38 / 0.82 / 0.92 %
            without, and slower planar mapping, so it is off; it helped
            (planar seed 1, 3.71 -> 3.27 %) only while the initialisation had
            no extra view.
        kf_depth_link_tolerance: correspondences whose log depth ratio is
            further than this from the median are occlusions and left out
            (default 0.1).
        kf_depth_link_primitives: the factor uses the correspondences of at
            most this many primitives per keyframe, those with the most
            (default 32): it joins its shape variables in one dense block,
            and with all of them the planar model's mapping took 15 s per
            keyframe on synthetic seed 1.
        brightness_prior_sigma: sigmas of the brightness ``(a, b)`` priors.
        gauge_sigma: sigma of the first keyframe's pose prior.
        min_level_pixels: primitives with fewer pixels at ``map_level`` get no
            mapping factor.
        render_splat: splat size when rendering the window into a new keyframe.
        init_min_parallax: keyframe 1 is the first frame whose tracked
            translation over keyframe 0's median depth reaches this
            (default 0.08) ...
        init_max_gap: ... or the frame this many frames after keyframe 0
            (default 30: 1 s at 30 Hz; at 10 the synthetic runs started
            from 2-3 % baselines and the depth front-end's per-frame ATE was
            about 1.4x that at 20-30 on seeds 0 and 1).
        init_min_gap: keyframe 1 is at least this many frames after keyframe
            0 (default 3).
        init_extra_views: frames between keyframes 0 and 1 (evenly spaced)
            added as supporting views to the initialisation's SfM (default
            1).  With keyframe 1 alone the monocular structure of keyframe 0
            fitted that one baseline, and the frames between (tracked against
            it after the SfM) converged to poses 1-2 deg and up to 100 deg of
            translation direction off (synthetic seed 1, classical; the
            tracker started from the true pose drifted to the same poses).
            On the 150-frame synthetic runs (seeds 0-3, ``--set
            init_extra_views=0`` for the comparison) one extra view took the
            mean per-frame ATE from 1.75 to 1.26 % (classical; seed 1 3.84 ->
            1.85 %) and from 1.96 to 1.35 % (planar; seed 1 4.03 -> 1.58 %),
            depth 0.50 -> 0.48 %.  0 is the plain two-view initialisation.
        max_lost_frames: re-initialise after this many consecutive lost frames
            (default 10).
        sfm: :class:`SfMConfig` of the two-view initialisation (its
            ``reset_scales`` is overridden: False with a depth-using
            front-end, True otherwise).
    """

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    kf_min_valid_fraction: float = 0.6
    kf_max_translation: float = 0.2
    kf_max_relative_cost: float = 0.2
    kf_max_rotation_deg: float = 15.0
    window: int = 5
    n_support: int = 4
    levels: int = 3
    map_level: int = 1
    map_stride: int = 1
    map_iterations: int = 10
    map_relative_tol: float = 1e-2
    map_lambda_max: float = 1e3
    map_lambda_initial: float = 1e-5
    map_pixel_fraction: float = 1.0
    map_chunk: int = 32
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
    init_min_parallax: float = 0.08
    init_max_gap: int = 30
    init_min_gap: int = 3
    init_extra_views: int = 1
    max_lost_frames: int = 10
    sfm: SfMConfig = field(default_factory=lambda: SfMConfig(levels=3, marginals=False))

    def __post_init__(self) -> None:
        if self.window < 2:
            raise ValueError(f"OdometryConfig.window must be >= 2, got {self.window}")
        if not 0 <= self.map_level < self.levels:
            raise ValueError("OdometryConfig.map_level must be in [0, levels)")
        if (self.map_stride < 1 or self.map_iterations < 1 or self.init_max_gap < 1
                or self.max_lost_frames < 1):
            raise ValueError("OdometryConfig: map_stride, map_iterations, init_max_gap and "
                             "max_lost_frames must be >= 1")
        if self.map_chunk < 1:
            raise ValueError("OdometryConfig.map_chunk must be >= 1")
        if not 0 < self.map_pixel_fraction <= 1:
            raise ValueError("OdometryConfig.map_pixel_fraction must be in (0, 1]")
        if not self.map_lambda_initial > 0:
            raise ValueError("OdometryConfig.map_lambda_initial must be > 0")
        if self.init_extra_views < 0:
            raise ValueError("OdometryConfig.init_extra_views must be >= 0")
        if not 1 <= self.init_min_gap <= self.init_max_gap:
            raise ValueError("OdometryConfig: 1 <= init_min_gap <= init_max_gap required")
        if self.n_support < 0:
            raise ValueError("OdometryConfig.n_support must be >= 0")
        if not self.scale_prior_weight > 0:
            raise ValueError("OdometryConfig.scale_prior_weight must be > 0")
        if not self.render_prior_weight > 0:
            raise ValueError("OdometryConfig.render_prior_weight must be > 0")
        if self.kf_depth_link_sigma is not None and not self.kf_depth_link_sigma > 0:
            raise ValueError("OdometryConfig.kf_depth_link_sigma must be > 0 or None")
        if not self.kf_depth_link_tolerance > 0 or self.kf_depth_link_primitives < 1:
            raise ValueError("OdometryConfig: kf_depth_link_tolerance > 0 and "
                             "kf_depth_link_primitives >= 1 required")
        if not 0 <= self.kf_min_valid_fraction <= 1 or not self.kf_max_translation > 0:
            raise ValueError("OdometryConfig: kf_min_valid_fraction in [0, 1] and "
                             "kf_max_translation > 0 required")
        if self.primitive_model not in PRIMITIVE_MODELS:
            raise ValueError(f"OdometryConfig.primitive_model must be one of {PRIMITIVE_MODELS}, "
                             f"got {self.primitive_model!r}")


@dataclass
class FrameResult:
    """Outcome of :meth:`Odometry.track` for one frame.

    Attributes:
        index: frame number (0-based, in call order).
        timestamp: the frame's timestamp.
        T_world_cam: 4x4 camera-to-world online pose (world = the first
            keyframe's camera); the last good pose for a ``"lost"`` frame.
        status: one of :data:`STATUSES`: ``"init"`` (before keyframe 1 of a
            map segment; refined once that keyframe exists), ``"ok"``,
            ``"keyframe"``, ``"lost"``, ``"relocalised"`` (first tracked frame
            after a loss, or tracked against an older keyframe), ``"reinit"``
            (started a new map segment).
        keyframe_index: the keyframe's index if this frame became one.
        segment: map segment (0, then +1 at each re-initialisation).
        track: the :class:`TrackResult` of the final tracking attempt (None
            for a frame that started a segment).
        timings: seconds per stage (``track``, ``frontend``, ``mapping``,
            ``init``, ``total``).
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: str
    keyframe_index: Optional[int] = None
    segment: int = 0
    track: Optional[TrackResult] = None
    timings: Dict[str, float] = field(default_factory=dict)


@dataclass
class OdometryResult:
    """The trajectory so far (:meth:`Odometry.result`).

    Attributes:
        timestamps: (n,) frame timestamps.
        poses: (n, 4, 4) camera-to-world poses (module docstring).
        statuses: per-frame status strings.
        is_keyframe: (n,) bool.
        segments: (n,) map segment of each frame.
    """

    timestamps: np.ndarray
    poses: np.ndarray
    statuses: List[str]
    is_keyframe: np.ndarray
    segments: np.ndarray

    @property
    def keyframe_timestamps(self) -> np.ndarray:
        return self.timestamps[self.is_keyframe]

    @property
    def keyframe_poses(self) -> np.ndarray:
        return self.poses[self.is_keyframe]

    @property
    def tracked(self) -> np.ndarray:
        """(n,) bool: frames with a pose of their own (not ``"lost"``)."""
        return np.array([s != "lost" for s in self.statuses], dtype=bool)


@dataclass
class _KF:
    index: int          # keyframe number
    frame: int          # frame number
    image: np.ndarray
    keyframe: Keyframe
    segment: int = 0
    map_pixels: Optional[tuple] = None   # cached _map_pixels (pixels and image never change)
    prior_weights: Optional[np.ndarray] = None   # (N,) weights of the shape priors


@dataclass
class _Candidate:
    """A frame tracked against the latest keyframe (supporting-frame candidate)."""

    frame: int
    image: np.ndarray
    T_kf_frame: np.ndarray
    brightness: np.ndarray


class Odometry:
    """Streaming monocular VO (module docstring).

    Args:
        camera: intrinsics of the input frames.
        config: :class:`OdometryConfig`.
        frontend: the :class:`PrimitiveFrontEnd` that primifies keyframes
            (give it a small ``working_size``, e.g. 160x120).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig = OdometryConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None) -> None:
        if frontend is None:
            raise ValueError("Odometry needs a front-end (spgeo.frontend.make_frontend)")
        self.camera = camera
        self.config = config
        self.frontend = frontend
        self._frames: List[FrameResult] = []
        self._kfs: Dict[int, _KF] = {}
        self._kf_order: List[int] = []
        # frame -> (kf, T_kf_frame, the keyframe's median depth when it was tracked)
        self._rel: Dict[int, Tuple[int, np.ndarray, float]] = {}
        self._support_pose: Dict[int, np.ndarray] = {}       # frame -> smoothed T_world
        self._support_frames: List[int] = []
        self._candidates: List[_Candidate] = []
        self._init_buffer: List[tuple] = []   # (frame index, image) before keyframe 1
        self._segment = 0
        self._seg_kfs: List[int] = []          # keyframes of the current segment
        self._last_good: Optional[np.ndarray] = None
        self._prev_good: Optional[np.ndarray] = None
        self._brightness = np.zeros(2)
        self._n_lost = 0
        self._groups: List[PhotometricFactorGroup] = []     # alive while in the smoother
        self.smoother = self._new_smoother()
        self._map_reports: List[dict] = []
        self._sfm_reports: List[dict] = []

    # ------------------------------------------------------------ public API
    def track(self, frame: Frame) -> FrameResult:
        """Process the next frame (a :class:`~spgeo.frame.Frame`; its depth is
        read only by a depth-using front-end)."""
        t0 = time.perf_counter()
        image = np.asarray(frame.image)
        if image.ndim not in (2, 3) or tuple(image.shape[:2]) != self.camera.shape:
            raise ValueError(f"Odometry.track: image of shape {image.shape} does not match the "
                             f"camera {self.camera.shape}")
        if not np.all(np.isfinite(image)):
            raise ValueError("Odometry.track: image contains NaN or inf")
        idx = len(self._frames)
        timings: Dict[str, float] = {}
        if idx == 0:
            res = self._start(frame, idx, np.eye(4), timings)
        elif len(self._seg_kfs) < 2:
            res = self._initialise(frame, idx, timings)
        else:
            res = self._track(frame, idx, timings)
        timings["total"] = time.perf_counter() - t0
        res.timings = timings
        res.segment = self._segment
        self._frames.append(res)
        return res

    def result(self) -> OdometryResult:
        """Per-frame trajectory (module docstring, *Trajectory*)."""
        n = len(self._frames)
        poses = np.empty((n, 4, 4))
        is_kf = np.zeros(n, dtype=bool)
        kf_of_frame = {kf.frame: kf for kf in self._kfs.values()}
        for i, f in enumerate(self._frames):
            if i in kf_of_frame:
                poses[i] = kf_of_frame[i].keyframe.T_world_kf
                is_kf[i] = True
            elif i in self._support_pose:
                poses[i] = self._support_pose[i]
            elif i in self._rel and self._rel[i][0] in self._kfs:
                poses[i] = self._frame_pose(*self._rel[i])
            elif f.status == "lost" and i > 0:
                poses[i] = poses[i - 1]
            else:
                poses[i] = f.T_world_cam
        return OdometryResult(np.array([f.timestamp for f in self._frames], dtype=float),
                              poses, [f.status for f in self._frames], is_kf,
                              np.array([f.segment for f in self._frames], dtype=int))

    def _frame_pose(self, k: int, T_kf_frame: np.ndarray, median_then: float) -> np.ndarray:
        """``T_world_frame`` of a frame tracked against keyframe ``k``: the
        keyframe's latest pose composed with the tracked relative pose, whose
        translation is rescaled by the change of the keyframe's median depth
        since tracking (mapping refines the keyframe's scales; the tracked
        translation was measured in the old depth units)."""
        kf = self._kfs[k].keyframe
        T = np.array(T_kf_frame, dtype=float)
        if median_then > 0:
            T[:3, 3] *= kf.median_depth / median_then
        return kf.T_world_kf @ T

    def smoother_estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window)."""
        return self.smoother.calculateEstimate()

    @property
    def keyframes(self) -> List[Keyframe]:
        """All keyframes in creation order (the window's at their smoothed state)."""
        return [self._kfs[k].keyframe for k in self._kf_order]

    @property
    def frames(self) -> List[FrameResult]:
        """The :class:`FrameResult` of every frame so far."""
        return list(self._frames)

    def report(self) -> dict:
        """Run statistics (JSON-ready): counts, per-stage seconds, mapping and
        initialisation reports, configuration."""
        res = self.result()
        counts = {s: int(sum(1 for x in res.statuses if x == s)) for s in STATUSES}
        tot = [f.timings.get("total", 0.0) for f in self._frames]
        n_track = [f.timings["track"] for f in self._frames if "track" in f.timings]
        maps = [m["seconds"] for m in self._map_reports if "seconds" in m]
        return {
            "n_frames": len(self._frames), "n_keyframes": len(self._kf_order),
            "n_segments": self._segment + 1,
            "status_counts": counts,
            "seconds_total": float(np.sum(tot)),
            "fps": float(len(tot) / max(np.sum(tot), 1e-9)),
            "seconds_per_stage": {k: float(sum(f.timings.get(k, 0.0) for f in self._frames))
                                  for k in ("track", "frontend", "mapping", "init")},
            "tracking_fps": float(len(n_track) / max(np.sum(n_track), 1e-9)),
            "mapping_seconds_per_keyframe": float(np.mean(maps)) if maps else None,
            "config": dataclasses.asdict(self.config),
            "frontend": getattr(self.frontend, "name", str(self.frontend)),
            "sfm": self._sfm_reports,
            "mapping": self._map_reports,
            "frames": [{"index": f.index, "timestamp": f.timestamp, "status": f.status,
                        "keyframe": f.keyframe_index, "segment": f.segment, "timings": f.timings}
                       for f in self._frames],
        }

    def save(self, directory: Union[str, Path], clouds: bool = True) -> Dict[str, object]:
        """Write ``trajectory.txt`` (every frame, TUM ``timestamp tx ty tz qx qy
        qz qw``, camera-to-world, :meth:`result` poses), ``keyframes.txt``,
        ``trajectory.status.txt`` (per-frame status, keyframe flag, segment),
        ``report.json`` and, with ``clouds``, one PLY per keyframe in
        ``clouds/`` (world frame, metres, coloured); returns their paths."""
        from spgeo.evaluation.trajectory import status_path_for, write_status, write_tum

        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        res = self.result()
        traj = out / "trajectory.txt"
        kfs = out / "keyframes.txt"
        write_tum(traj, res.timestamps, list(res.poses), header=["spgeo.odometry per-frame"])
        write_tum(kfs, res.keyframe_timestamps, list(res.keyframe_poses),
                  header=["spgeo.odometry keyframes"])
        status = status_path_for(traj)
        write_status(status, res.timestamps, res.statuses,
                     {"keyframe": [int(k) for k in res.is_keyframe],
                      "segment": [int(s) for s in res.segments]})
        rep = out / "report.json"
        rep.write_text(json.dumps(self.report(), indent=1, default=json_default),
                       encoding="utf-8")
        paths: Dict[str, object] = {"trajectory": traj, "keyframes": kfs, "status": status,
                                    "report": rep}
        if clouds:
            cdir = out / "clouds"
            cdir.mkdir(exist_ok=True)
            paths["clouds"] = []
            for k in self._kf_order:
                kf = self._kfs[k]
                pc = kf.keyframe.primitives.point_cloud(kf.image).transformed(kf.keyframe.T_world_kf)
                p = cdir / f"keyframe_{k:04d}.ply"
                pc.save_ply(p)
                paths["clouds"].append(p)
        return paths

    # ------------------------------------------------------------ stages
    def _new_smoother(self) -> gtsam.BatchFixedLagSmoother:
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(int(self.config.map_iterations))
        p.setRelativeErrorTol(float(self.config.map_relative_tol))
        p.setAbsoluteErrorTol(1e-9)
        p.setlambdaUpperBound(float(self.config.map_lambda_max))
        p.setlambdaInitial(float(self.config.map_lambda_initial))
        return gtsam.BatchFixedLagSmoother(float(self.config.window) - 0.5, p)

    def _primify(self, frame: Frame) -> PrimitiveSet:
        depth = frame.depth if self.frontend.uses_depth else None
        prims = self.frontend.primify(frame.image, self.camera, depth)
        if len(prims) == 0:
            raise ValueError("the front-end produced no primitive")
        return prims

    def _start(self, frame: Frame, idx: int, T_world: np.ndarray,
               timings: Dict[str, float], median_depth: Optional[float] = None) -> FrameResult:
        """Keyframe 0 of a map segment at ``T_world``."""
        t = time.perf_counter()
        prims = self._primify(frame)
        if not self.frontend.uses_depth:
            s0 = 0.0 if median_depth is None else float(np.log(median_depth))
            prims = prims.with_log_scales(np.full(len(prims), s0))
        prims = apply_primitive_model(prims, self.config.primitive_model)
        timings["frontend"] = time.perf_counter() - t
        k = len(self._kf_order)
        kf = Keyframe.build(frame.image, prims, T_world, self.config.levels)
        self._kfs[k] = _KF(k, idx, np.asarray(frame.image), kf, self._segment)
        self._kf_order.append(k)
        self._seg_kfs = [k]
        self._candidates.clear()
        self._init_buffer.clear()
        self._last_good, self._prev_good = np.array(T_world, dtype=float), None
        self._brightness = np.zeros(2)
        self._n_lost = 0
        return FrameResult(idx, float(frame.timestamp), np.array(T_world, dtype=float),
                           "keyframe" if idx == 0 else "reinit", keyframe_index=k)

    def _track_against(self, kf: Keyframe, image: np.ndarray):
        """Constant-velocity guess, then the last good pose; returns the TrackResult."""
        guess = constant_velocity_guess(self._last_good, self._prev_good)
        tr = track_frame(kf, image, guess, self._brightness, self.config.tracker)
        if not tr.ok and self._prev_good is not None:
            tr2 = track_frame(kf, image, self._last_good, self._brightness, self.config.tracker)
            if tr2.ok or tr2.photometric_cost < tr.photometric_cost:
                tr = tr2
        return tr

    def _accept(self, tr: TrackResult) -> None:
        self._prev_good, self._last_good = self._last_good, tr.T_world_frame.copy()
        self._brightness = np.asarray(tr.brightness, dtype=float).copy()

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        kf0 = self._kfs[self._seg_kfs[0]]
        t = time.perf_counter()
        tr = self._track_against(kf0.keyframe, frame.image)
        timings["track"] = time.perf_counter() - t
        T_kf0_f = invert_pose(kf0.keyframe.T_world_kf) @ tr.T_world_frame
        if tr.ok:
            self._accept(tr)
            self._n_lost = 0
        else:
            self._n_lost += 1
        parallax = (np.linalg.norm(T_kf0_f[:3, 3]) / kf0.keyframe.median_depth
                    if tr.ok else 0.0)
        gap = idx - kf0.frame
        cfg = self.config
        # keyframe 1 must still overlap keyframe 0: the overlap criteria of
        # keyframes (valid fraction, rotation) end the wait too
        rot = rotation_angle_deg(T_kf0_f[:3, :3])
        overlap_ending = tr.ok and (tr.valid_fraction < cfg.kf_min_valid_fraction
                                    or rot > cfg.kf_max_rotation_deg)
        wait = (gap < cfg.init_max_gap and not overlap_ending
                and (parallax < cfg.init_min_parallax or gap < cfg.init_min_gap))
        if wait:
            self._init_buffer.append((idx, np.asarray(frame.image)))
            if tr.ok:
                self._rel[idx] = (kf0.index, T_kf0_f, kf0.keyframe.median_depth)
            pose = tr.T_world_frame if tr.ok else self._last_good
            return FrameResult(idx, float(frame.timestamp), pose.copy(),
                               "init" if tr.ok else "lost", track=tr)
        # ---- SfM: keyframe 0 of the segment (reference), this frame and extra views
        t = time.perf_counter()
        sfm_cfg = dataclasses.replace(self.config.sfm, reset_scales=not self.frontend.uses_depth)
        views, init = self._init_views(frame.image, idx, kf0.frame, T_kf0_f if tr.ok else None)
        prims0 = kf0.keyframe.primitives
        sfm = few_view_sfm(kf0.image, views, self.camera, prims0, sfm_cfg, init_T_ref_view=init)
        timings["init"] = time.perf_counter() - t
        self._sfm_reports.append({
            "status": sfm.status, "frame": idx, "segment": self._segment, "parallax": parallax,
            "n_views": len(views),
            **{k: sfm.report.get(k) for k in ("n_primitives", "final_cost", "seconds_total")}})
        if sfm.status == "diverged" or not np.all(np.isfinite(sfm.T_ref_view[0])):
            log.warning("two-view initialisation failed (%s) at frame %d; retrying later",
                        sfm.status, idx)
            self._init_buffer.append((idx, np.asarray(frame.image)))
            self._n_lost += 1
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), "lost",
                               track=tr)
        new_prims = sfm.primitives
        if self.config.primitive_model != "integrated":
            new_prims = apply_primitive_model(new_prims, self.config.primitive_model)
        T_w0 = kf0.keyframe.T_world_kf
        if not self.frontend.uses_depth and self._segment > 0:
            # a re-initialised monocular segment keeps the previous map's depth scale
            med = np.median(np.exp(prims0.scaled_log_depth()))
            med_new = np.median(np.exp(new_prims.scaled_log_depth()))
            c = float(np.log(med / med_new))
            new_prims = new_prims.with_log_scales(new_prims.log_scales + c)
            T_01 = np.asarray(sfm.T_ref_view[0], dtype=float).copy()
            T_01[:3, 3] *= np.exp(c)
        else:
            T_01 = np.asarray(sfm.T_ref_view[0], dtype=float)
        kf0.keyframe = Keyframe.build(kf0.image, new_prims, T_w0, self.config.levels)
        T1 = T_w0 @ T_01
        # re-track the buffered frames against the solved keyframe 0
        prev = None
        last = T_w0.copy()
        for j, img in self._init_buffer:
            tj = track_frame(kf0.keyframe, img, constant_velocity_guess(last, prev),
                             self._brightness, self.config.tracker)
            if tj.ok:
                prev, last = last, tj.T_world_frame
                self._frames[j].T_world_cam = tj.T_world_frame.copy()
                self._frames[j].status = "init"
                self._rel[j] = (kf0.index, invert_pose(T_w0) @ tj.T_world_frame,
                                kf0.keyframe.median_depth)
                self._candidates.append(_Candidate(j, img, self._rel[j][1],
                                                   np.asarray(tj.brightness, float)))
            else:
                self._frames[j].status = "lost"
                self._frames[j].T_world_cam = last.copy()
                self._rel.pop(j, None)
        self._init_buffer.clear()
        self._last_good, self._prev_good = T1.copy(), last.copy()
        self._n_lost = 0
        return self._new_keyframe(frame, idx, T1, timings, track=tr)

    def _init_views(self, image: np.ndarray, idx: int, frame0: int,
                    T_kf0_f: Optional[np.ndarray]):
        """Supporting views of the initialisation: keyframe 1's image first,
        then ``init_extra_views`` buffered frames evenly spaced between keyframes
        0 and 1, with initial poses from keyframe 1's tracked pose (the extra
        views at its motion interpolated in time), or None (the SfM's own
        two-view initialisation) when keyframe 1 was not tracked."""
        buf = self._init_buffer
        n = min(self.config.init_extra_views, len(buf))
        picks = sorted({int(round(q * len(buf) / (n + 1))) - 1 for q in range(1, n + 1)}) if n else []
        picks = [p for p in picks if 0 <= p < len(buf)]
        views = [image] + [buf[p][1] for p in picks]
        if T_kf0_f is None:
            return views, None
        xi = gtsam.Pose3.Logmap(gtsam.Pose3(T_kf0_f))
        init = [T_kf0_f] + [gtsam.Pose3.Expmap((buf[p][0] - frame0) / max(idx - frame0, 1) * xi)
                            .matrix() for p in picks]
        return views, init

    def _relocalise(self, image: np.ndarray) -> Tuple[Optional[TrackResult], Optional[_KF]]:
        """Track against the window's older keyframes, newest first."""
        for k in reversed(self._seg_kfs[-self.config.window:-1]):
            kf = self._kfs[k]
            tr = track_frame(kf.keyframe, image, self._last_good, self._brightness,
                             self.config.tracker)
            if tr.ok:
                return tr, kf
        return None, None

    def _track(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        latest = self._kfs[self._seg_kfs[-1]]
        ref = latest
        t = time.perf_counter()
        tr = self._track_against(latest.keyframe, frame.image)
        relocalised = False
        if not tr.ok:
            tr_old, kf_old = self._relocalise(frame.image)
            if tr_old is not None:
                tr, ref, relocalised = tr_old, kf_old, True
        timings["track"] = time.perf_counter() - t
        if not tr.ok:
            self._n_lost += 1
            log.info("frame %d lost (%s)", idx, tr.reason)
            if self._n_lost >= self.config.max_lost_frames:
                log.warning("frame %d: %d frames lost; re-initialising the map", idx,
                            self._n_lost)
                return self._reinitialise(frame, idx, timings)
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), "lost",
                               track=tr)
        was_lost = self._n_lost > 0
        self._n_lost = 0
        self._accept(tr)
        T_ref_f = invert_pose(ref.keyframe.T_world_kf) @ tr.T_world_frame
        self._rel[idx] = (ref.index, T_ref_f, ref.keyframe.median_depth)
        status = "relocalised" if (was_lost or relocalised) else "ok"
        if ref is latest:
            T_kf_f = T_ref_f
            rel_t = float(np.linalg.norm(T_kf_f[:3, 3])) / max(latest.keyframe.median_depth, 1e-9)
            rot = rotation_angle_deg(T_kf_f[:3, :3])
            if (tr.valid_fraction < self.config.kf_min_valid_fraction
                    or rel_t > self.config.kf_max_translation
                    or tr.relative_cost > self.config.kf_max_relative_cost
                    or rot > self.config.kf_max_rotation_deg):
                res = self._new_keyframe(frame, idx, tr.T_world_frame, timings, track=tr)
                if res is not None:
                    return res
            self._add_candidate(_Candidate(idx, np.asarray(frame.image), T_kf_f,
                                           np.asarray(tr.brightness, float)))
        else:
            # tracked against an older keyframe: make it a keyframe to re-anchor the map
            res = self._new_keyframe(frame, idx, tr.T_world_frame, timings, track=tr)
            if res is not None:
                return res
        return FrameResult(idx, float(frame.timestamp), tr.T_world_frame.copy(), status,
                           track=tr)

    def _add_candidate(self, cand: _Candidate) -> None:
        self._candidates.append(cand)
        cap = max(8 * self.config.n_support, 16)
        if len(self._candidates) > cap:
            self._candidates = self._candidates[::2]

    def _reinitialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        grey = np.asarray(frame.image, dtype=np.float64)
        if float(np.std(grey)) < 1e-3 * max(float(np.max(np.abs(grey))), 1.0):
            # a featureless frame cannot start a map: stay lost, retry on the next frame
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), "lost")
        med = self._kfs[self._seg_kfs[-1]].keyframe.median_depth
        self._segment += 1
        self.smoother = self._new_smoother()
        self._groups = []
        return self._start(frame, idx, self._last_good.copy(), timings, median_depth=med)

    def _new_keyframe(self, frame: Frame, idx: int, T_world: np.ndarray,
                      timings: Dict[str, float], track: Optional[TrackResult]):
        cfg = self.config
        t = time.perf_counter()
        prims = self._primify(frame)
        window = [self._kfs[k] for k in self._seg_kfs[-cfg.window:]]
        depth = render_primitives([(w.keyframe.primitives, w.keyframe.T_world_kf) for w in window],
                                  prims.camera, T_world, splat=cfg.render_splat)
        try:
            init = init_scales_from_render(prims, depth)
        except ValueError as exc:
            log.warning("frame %d: no keyframe (%s)", idx, exc)
            timings["frontend"] = time.perf_counter() - t
            return None
        prims = apply_primitive_model(init.primitives, cfg.primitive_model)
        timings["frontend"] = time.perf_counter() - t
        k = len(self._kf_order)
        kf = _KF(k, idx, np.asarray(frame.image),
                 Keyframe.build(frame.image, prims, T_world, cfg.levels), self._segment,
                 prior_weights=np.where(init.fallback & (not self.frontend.uses_depth),
                                        cfg.scale_prior_weight, cfg.render_prior_weight))
        self._kfs[k] = kf
        self._kf_order.append(k)
        self._seg_kfs.append(k)
        self._rel.pop(idx, None)
        t = time.perf_counter()
        self._map(k)
        timings["mapping"] = time.perf_counter() - t
        self._candidates.clear()
        T_new = self._kfs[k].keyframe.T_world_kf
        # the smoothed pose of the new keyframe replaces the tracked one
        # (the same world-frame correction moves the previous pose of the velocity model)
        if self._prev_good is not None:
            self._prev_good = T_new @ invert_pose(self._last_good) @ self._prev_good
        self._last_good = T_new.copy()
        self._brightness = np.zeros(2)
        return FrameResult(idx, float(frame.timestamp), T_new.copy(), "keyframe",
                           keyframe_index=k, track=track)

    # ------------------------------------------------------------ mapping
    @property
    def _planar(self) -> bool:
        return self.config.primitive_model == "planar"

    def _shape_values(self, kf: _KF) -> np.ndarray:
        """(N, dim) initial shape variables of a keyframe's primitives."""
        prims = kf.keyframe.primitives
        if self._planar:
            return prims.fit_planes()
        return prims.log_scales.reshape(-1, 1)

    def _shape_model(self, prims: PrimitiveSet, entries: np.ndarray, rays: np.ndarray):
        return PlanarShape(rays) if self._planar else ScaledShape(rays, prims.log_depth[entries])

    def _depth_link(self, ref: _KF, tgt: _KF) -> Optional[DepthConsistencyFactor]:
        """Mean depth consistency of ``ref``'s mapping pixels with ``tgt``'s
        primitives where they project (current estimates), or None (disabled,
        or fewer than ``min_level_pixels`` consistent correspondences).
        Correspondences whose log-ratio is more than ``kf_depth_link_tolerance``
        from the median one are occlusions or disocclusions and are left out."""
        cfg = self.config
        if cfg.kf_depth_link_sigma is None:
            return None
        sel = self._map_pixels(ref)
        if sel is None:
            return None
        entries = sel[0]
        pr, pt = ref.keyframe.primitives, tgt.keyframe.primitives
        cam = pt.camera
        rays_all = cam.rays().reshape(-1, 3)
        th_r, th_t = self._shape_values(ref), self._shape_values(tgt)
        ref_ids = pr.primitive_ids[entries]
        shape_r = self._shape_model(pr, entries, rays_all[pr.pixels[entries]])
        X = shape_r.points(th_r[ref_ids])[0]
        T = invert_pose(tgt.keyframe.T_world_kf) @ ref.keyframe.T_world_kf
        Y = X @ T[:3, :3].T + T[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(cam.fx * Y[:, 0] / Y[:, 2] + cam.cx)
            v = np.rint(cam.fy * Y[:, 1] / Y[:, 2] + cam.cy)
        ok = (Y[:, 2] > cfg.photometric.min_depth) & (u >= 0) & (u < cam.width) & (v >= 0) \
            & (v < cam.height)
        label = np.full(cam.width * cam.height, -1, dtype=np.int64)
        label[pt.pixels] = np.arange(pt.pixels.size)
        t_ent = np.full(ok.size, -1, dtype=np.int64)
        t_ent[ok] = label[(v[ok] * cam.width + u[ok]).astype(np.int64)]
        ok &= t_ent >= 0
        if np.count_nonzero(ok) < cfg.min_level_pixels:
            return None
        t_ent, entries, ref_ids, z = t_ent[ok], entries[ok], ref_ids[ok], Y[ok, 2]
        tgt_ids = pt.primitive_ids[t_ent]
        shape_t = self._shape_model(pt, t_ent, rays_all[pt.pixels[t_ent]])
        Xt, _, ok_t = shape_t.points(th_t[tgt_ids])
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.log(z) - np.log(Xt[:, 2])
        ok = ok_t & np.isfinite(d)
        if np.count_nonzero(ok) >= cfg.min_level_pixels:
            ok &= np.abs(d - np.median(d[ok])) <= cfg.kf_depth_link_tolerance
        # the factor joins all its shape variables in one dense block: keep the
        # correspondences of the primitives with the most of them on both sides
        m = cfg.kf_depth_link_primitives
        for ids_side in (ref_ids, tgt_ids):
            cnt = np.bincount(ids_side[ok], minlength=ids_side.max() + 1)
            if np.count_nonzero(cnt) > m:
                top = np.argsort(-cnt, kind="stable")[:m]
                ok &= np.isin(ids_side, top)
        if np.count_nonzero(ok) < cfg.min_level_pixels:
            return None
        entries, t_ent = entries[ok], t_ent[ok]
        return DepthConsistencyFactor(
            kf_pose_key(ref.index), kf_pose_key(tgt.index),
            [kf_scale_key(ref.index, i) for i in range(len(pr))],
            self._shape_model(pr, entries, rays_all[pr.pixels[entries]]), ref_ids[ok],
            [kf_scale_key(tgt.index, i) for i in range(len(pt))],
            self._shape_model(pt, t_ent, rays_all[pt.pixels[t_ent]]), tgt_ids[ok],
            cfg.kf_depth_link_sigma, cfg.photometric.min_depth)

    def _group(self, ref: _KF, tgt_key: int, tgt_image: np.ndarray,
               tgt_camera: PinholeCamera, bkey: int) -> Optional[PhotometricFactorGroup]:
        """Photometric factors of ref's primitives observed in a target (map level)."""
        cfg = self.config
        sel = self._map_pixels(ref)
        if sel is None:
            return None
        entries, ids, prim_index, ref_int = sel
        prims = ref.keyframe.primitives
        rays = prims.camera.rays().reshape(-1, 3)[prims.pixels[entries]]
        shape = self._shape_model(prims, entries, rays)
        counts = np.bincount(ids, minlength=prim_index.size)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        keys = [kf_scale_key(ref.index, i) for i in prim_index]
        return PhotometricFactorGroup(kf_pose_key(ref.index), tgt_key, keys, shape, offsets,
                                      ref_int, tgt_image, tgt_camera, bkey,
                                      cfg.photometric, n_pixels=counts.astype(float),
                                      chunk=cfg.map_chunk)

    def _map_pixels(self, ref: _KF):
        """Mapping pixels of a keyframe: ``(entries, compact ids, primitive
        index, reference intensities)``; with ``map_pixel_fraction < 1`` the
        highest-gradient fraction of the map level's pixels (at least
        ``min_level_pixels`` per primitive).  Cached per keyframe (mapping
        changes its scales and pose, never its pixels or image)."""
        cfg = self.config
        if ref.map_pixels is not None:
            return ref.map_pixels[0]
        data = ref.keyframe.level_data(cfg.map_level, cfg.map_stride, cfg.min_level_pixels)
        out = None
        if data.prim_index.size:
            entries, ids, ref_int = data.entries, data.ids, data.ref_intensity
            if cfg.map_pixel_fraction < 1.0:
                # central differences, as the factors' bilinear image derivatives
                # (Scharr's smoothed ones picked other pixels: classical:planar
                # seed 1 4.66 instead of 3.27 % ATE, the other runs within noise)
                img = ref.keyframe.pyramid.images[cfg.map_level].astype(np.float64)
                gy, gx = np.gradient(img)
                mag = np.hypot(gx, gy)
                w = ref.keyframe.primitives.camera.width
                stride = 2 ** cfg.map_level
                pix = ref.keyframe.primitives.pixels[entries]
                g = mag[(pix // w) // stride, (pix % w) // stride]
                thr = np.quantile(g, 1.0 - cfg.map_pixel_fraction)
                order = np.lexsort((-g, ids))                  # by primitive, strongest first
                rank = np.empty(ids.size, dtype=np.int64)
                starts = np.concatenate([[0], np.cumsum(np.bincount(ids))[:-1]])
                rank[order] = np.arange(ids.size) - starts[ids[order]]
                keep = (g >= thr) | (rank < cfg.min_level_pixels)
                entries, ids, ref_int = entries[keep], ids[keep], ref_int[keep]
            out = (entries, ids, data.prim_index, ref_int)
        ref.map_pixels = (out,)
        return out

    def _map(self, k: int) -> None:
        """Add keyframe ``k`` (second or later of its segment) and the previous
        keyframe's supporting frames to the smoother and update the window."""
        cfg = self.config
        lvl = cfg.map_level
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()

        def stamp(key: int, t: int) -> None:
            stamps.insert((key, float(t)))

        def add_kf(kf: _KF) -> None:
            values.insert(kf_pose_key(kf.index), gtsam.Pose3(kf.keyframe.T_world_kf))
            stamp(kf_pose_key(kf.index), kf.index)
            th = self._shape_values(kf)
            pw = (np.full(th.shape[0], cfg.scale_prior_weight) if kf.prior_weights is None
                  else kf.prior_weights)
            for i in range(th.shape[0]):
                key = kf_scale_key(kf.index, i)
                values.insert(key, th[i].copy())
                stamp(key, kf.index)
                if self._planar:
                    graph.add(planar_slope_prior(key, float(th[i, 2]), cfg.planar_slope_sigma,
                                                 1.0 / np.sqrt(pw[i])))
                else:
                    graph.add(log_scale_prior(key, float(th[i, 0]), pw[i]))

        def add_group(group: Optional[PhotometricFactorGroup], bkey: int, b0, t: int) -> int:
            if group is None:
                return 0
            for f in group.factors:
                graph.add(f)
            self._groups.append(group)
            values.insert(bkey, np.asarray(b0, dtype=float))
            stamp(bkey, t)
            graph.add(brightness_prior(bkey, cfg.brightness_prior_sigma))
            return len(group)

        new, prev = self._kfs[k], self._kfs[self._seg_kfs[-2]]
        if len(self._seg_kfs) == 2:
            add_kf(prev)
            graph.add(pose_gauge_prior(kf_pose_key(prev.index), prev.keyframe.T_world_kf,
                                       cfg.gauge_sigma))
        add_kf(new)
        n_pair = 0
        for ref, tgt in ((prev, new), (new, prev)):
            bkey = kf_brightness_key(ref.index, tgt.index)
            g = self._group(ref, kf_pose_key(tgt.index), tgt.keyframe.pyramid.images[lvl],
                            tgt.keyframe.pyramid.cameras[lvl], bkey)
            n_pair += add_group(g, bkey, np.zeros(2), k)
        link = self._depth_link(prev, new)
        if link is not None:
            graph.add(link.factor)
        # supporting frames of the previous keyframe: evenly spaced among its tracked frames
        cands = self._candidates
        chosen = []
        if cfg.n_support > 0 and cands:
            pick = np.unique(np.round(np.linspace(0, len(cands) - 1,
                                                  min(cfg.n_support, len(cands)))).astype(int))
            chosen = [cands[i] for i in pick]
        n_sup = 0
        for c in chosen:
            pkey = support_pose_key(c.frame)
            pyr = prev.keyframe.frame_pyramid(c.image, lvl + 1)
            T_w = prev.keyframe.T_world_kf @ c.T_kf_frame
            values.insert(pkey, gtsam.Pose3(T_w))
            stamp(pkey, prev.index)
            bkey = _support_brightness_key(c.frame)
            g = self._group(prev, pkey, pyr.images[lvl], pyr.cameras[lvl], bkey)
            n_sup += add_group(g, bkey, c.brightness, prev.index)
            self._support_frames.append(c.frame)
        t = time.perf_counter()
        try:
            self.smoother.update(graph, values, stamps)
        except RuntimeError as exc:       # e.g. gtsam.IndeterminantLinearSystemException
            if len(self._seg_kfs) == 2:
                log.warning("mapping keyframe %d failed (%s); keyframe poses kept as tracked",
                            k, str(exc).strip().splitlines()[0])
                self.smoother = self._new_smoother()
                self._map_reports.append({"keyframe": k, "segment": self._segment,
                                          "failed": True})
                return
            # restart the window from the last two keyframes (old ones stay as they are)
            log.warning("mapping keyframe %d failed (%s); restarting the window", k,
                        str(exc).strip().splitlines()[0])
            self.smoother = self._new_smoother()
            self._groups = []
            self._seg_kfs = self._seg_kfs[-2:]
            self._map(k)
            return
        est = self.smoother.calculateEstimate()
        secs = time.perf_counter() - t
        self._refresh(est)
        self._groups = [g for g in self._groups if est.exists(g.ref_key) and est.exists(g.tgt_key)]
        self._map_reports.append({"keyframe": k, "segment": self._segment,
                                  "factors_keyframe_pairs": n_pair, "factors_support": n_sup,
                                  "depth_link_correspondences": 0 if link is None else link.n,
                                  "support_frames": [c.frame for c in chosen],
                                  "seconds": secs, "keys_in_window": int(est.size())})
        log.debug("mapping kf %d: %d + %d factors, %.2f s", k, n_pair, n_sup, secs)

    def _refresh(self, est: gtsam.Values) -> None:
        """Window keyframes and supporting frames from the smoother's estimate."""
        for j in self._seg_kfs[-self.config.window - 1:]:
            kf = self._kfs[j]
            if not est.exists(kf_pose_key(j)):
                continue
            T = est.atPose3(kf_pose_key(j)).matrix()
            n_s = len(kf.keyframe.primitives)
            th = np.array([est.atVector(kf_scale_key(j, i)) for i in range(n_s)])
            if not (np.all(np.isfinite(T)) and np.all(np.isfinite(th))):
                log.warning("mapping produced non-finite values for keyframe %d; kept", j)
                continue
            prims = kf.keyframe.primitives
            if self._planar:
                prims = prims.with_planes(th)[0]
            else:
                prims = prims.with_log_scales(th[:, 0])
            kf.keyframe = Keyframe.build(kf.image, prims, T, self.config.levels)
        for f in self._support_frames[-(self.config.window + 1) * max(self.config.n_support, 1):]:
            key = support_pose_key(f)
            if est.exists(key):
                T = est.atPose3(key).matrix()
                if np.all(np.isfinite(T)):
                    self._support_pose[f] = T
