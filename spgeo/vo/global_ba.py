"""Global photometric bundle adjustment of all keyframes after a VO run (``--refine``).

The window smoother (:class:`spgeo.vo.smoother.WindowMapper`) optimises only the
last ``window`` keyframes; a keyframe that leaves the window is final.
:func:`refine_keyframes` optimises again every keyframe of each map segment
(``MapKeyframe.segment``) in one GTSAM graph per segment, solved with
``gtsam.LevenbergMarquardtOptimizer``:

* variables: every keyframe's pose ``T_world_kf`` (camera-to-world), its
  primitives' shape variables (log-scales, or inverse-depth planes with
  ``primitive_model="planar"``) and one affine brightness per directed
  keyframe pair, all at their current values;
* factors: the window mapper's photometric factor groups (built by the same
  functions, :func:`spgeo.graph.builders.link_keyframe_pair`) between each keyframe
  and its ``GlobalBAConfig.neighbours`` previous keyframes of the segment, in
  both directions; the brightness priors; the shape priors at the current
  values (default weight: ``OdometryConfig.render_prior_weight``, the weight
  the window gives scales rendered from the map; ``GlobalBAConfig.shape_prior_weight``);
* gauge: the segment's first keyframe pose has a tight prior
  (``spgeo.graph.builders.GAUGE_SIGMA``) and the *scale gauge* fixes the length of the
  baseline between the segment's first two keyframes (its component along
  the initial baseline direction, linear in the positions) at its current
  value (:class:`_DistanceGauge`, relative sigma :data:`SCALE_GAUGE_SIGMA`).
  That pair is the segment's initialisation pair, which the VO creates only
  with parallax (:class:`spgeo.vo.initialisation.Initialiser`), so its
  distance is not degenerate; the gauge works for every primitive model.
  Without it only the weak shape priors would hold the scale.

Supporting frames and the other non-keyframes are not variables: they follow
their keyframe's correction (:meth:`spgeo.vo.Odometry.refine`).  Loop
constraints are not in the graph (a loop correction already moved the map).

Memory: a segment's keyframes are restored from the
:class:`~spgeo.vo.keyframe_store.KeyframeStore` (retired ones) and all their
images, pyramids, points and factor groups live at once while the segment is
optimised, then are dropped before the next segment: unlike the VO's memory,
bounded by the window, the peak grows linearly with the number of keyframes
of the largest segment (``run.memory`` of ``report.json`` has the peak RSS
before and after the refinement).

A gtsam ``RuntimeError`` (e.g. an indeterminant system) or non-finite
estimate leaves the segment unchanged (``status`` ``"failed"``).
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

import gtsam

from ..configs import config_repr
from ..factors.photometric_group import release_groups
from ..factors.priors import pose_gauge_prior
from ..graph.builders import (GAUGE_SIGMA, FactorBatch, add_keyframe_variables,
                              gtsam_error_line, link_keyframe_pair)
from ..graph.keys import landmark_key, pose_key, scale_key
from .config import OdometryConfig
from .landmarks import LandmarkMap, add_segment_landmark_factors
from .map import MapKeyframe

__all__ = ["GlobalBAConfig", "GlobalBAResult", "refine_keyframes", "SCALE_GAUGE_SIGMA"]

log = logging.getLogger(__name__)

#: sigma of the scale gauge: the length of the baseline between the segment's first
#: two keyframe positions (along its initial direction), relative to its initial length
SCALE_GAUGE_SIGMA = 1e-3


@config_repr
@dataclass(frozen=True)
class GlobalBAConfig:
    """Options of :func:`refine_keyframes`.

    Attributes:
        neighbours: each keyframe is linked (photometric factors, both
            directions) to this many previous keyframes of its segment
            (default 2; >= 1).
        max_iterations: Levenberg-Marquardt iterations per segment (>= 1).
        relative_tol: LM stops when an iteration lowers the cost by less than
            this fraction (> 0).
        map_level: pyramid level of the factors (default None: the odometry's
            ``OdometryConfig.map_level``, as the window mapper).
        shape_prior_weight: weight of every shape variable's prior to its value
            before the adjustment (default None: the odometry's
            ``OdometryConfig.render_prior_weight``, which holds the shapes near
            the window's estimate, whose supporting-frame factors are not in
            this graph; a smaller one, e.g. ``scale_prior_weight``, lets the
            adjustment move them further; docs/results.md compares the two).
    """

    neighbours: int = 2
    max_iterations: int = 20
    relative_tol: float = 1e-4
    map_level: Optional[int] = None
    shape_prior_weight: Optional[float] = None

    def __post_init__(self) -> None:
        if int(self.neighbours) < 0 or int(self.max_iterations) < 1:
            raise ValueError("GlobalBAConfig: neighbours must be >= 0, max_iterations >= 1")
        if not self.relative_tol > 0:
            raise ValueError("GlobalBAConfig: relative_tol must be > 0")
        if self.map_level is not None and int(self.map_level) < 0:
            raise ValueError("GlobalBAConfig: map_level must be None or >= 0")
        if self.shape_prior_weight is not None and not self.shape_prior_weight > 0:
            raise ValueError("GlobalBAConfig: shape_prior_weight must be None or > 0")


@dataclass
class GlobalBAResult:
    """Output of :func:`refine_keyframes` (nothing is applied to the keyframes).

    Attributes:
        T_world_kf: keyframe index -> refined 4x4 camera-to-world pose (only the
            keyframes of segments solved with status ``"ok"``).
        shapes: keyframe index -> refined ``(N, dim)`` shape variables of its
            primitives (log-scales ``(N, 1)``, or planes ``(N, 3)``;
            :func:`spgeo.primitive_models.shape_values` order).
        initial_cost, final_cost: graph error (gtsam's ``0.5 * sum of squared
            whitened residuals``) before and after, summed over the segments.
        iterations: LM iterations, summed over the segments.
        seconds: wall time of the whole call (restore, build, solve).
        n_factors: photometric factors (primitive, directed pair) in all graphs.
        points: landmark id -> refined (3,) world point (segments solved ``"ok"``).
        n_landmark_factors: landmark projection factors in all graphs.
        status: ``"ok"`` (every segment solved), ``"failed"`` (at least one
            segment kept unchanged after a gtsam error) or ``"skipped"`` (no
            segment with two keyframes).
        segments: one JSON-ready dict per segment (keyframes, costs, ...).
    """

    T_world_kf: Dict[int, np.ndarray] = field(default_factory=dict)
    shapes: Dict[int, np.ndarray] = field(default_factory=dict)
    initial_cost: float = 0.0
    final_cost: float = 0.0
    iterations: int = 0
    seconds: float = 0.0
    n_factors: int = 0
    points: Dict[int, np.ndarray] = field(default_factory=dict)
    n_landmark_factors: int = 0
    status: str = "skipped"
    segments: List[dict] = field(default_factory=list)

    def report(self) -> dict:
        """The scalars and per-segment reports (JSON-ready, no arrays)."""
        return {"status": self.status, "seconds": float(self.seconds),
                "initial_cost": float(self.initial_cost), "final_cost": float(self.final_cost),
                "iterations": int(self.iterations), "n_factors": int(self.n_factors),
                "n_landmarks": len(self.points),
                "n_landmark_factors": int(self.n_landmark_factors),
                "n_keyframes": len(self.T_world_kf), "segments": list(self.segments)}


class _DistanceGauge:
    """Scale gauge of two Pose3 keys (1 row): ``u0 . (t_b - t_a) / d0 - 1``,
    the baseline's length along its initial direction ``u0`` relative to its
    initial length ``d0`` (linear in the positions: no curvature when the
    baseline turns, so a tight sigma keeps the system well conditioned)."""

    def __init__(self, key_a: int, key_b: int, baseline: np.ndarray, sigma: float) -> None:
        baseline = np.asarray(baseline, dtype=np.float64).reshape(3)
        self.d0 = float(np.linalg.norm(baseline))
        if not self.d0 > 1e-12:
            raise ValueError("scale gauge: the two keyframes are at the same position")
        self.u0 = baseline / self.d0
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, float(sigma)),
                                         [int(key_a), int(key_b)], self._error)

    def _error(self, this, values: gtsam.Values, H) -> np.ndarray:
        pa, pb = values.atPose3(this.keys()[0]), values.atPose3(this.keys()[1])
        d = np.asarray(pb.translation()) - np.asarray(pa.translation())
        if H is not None:
            # retraction T Exp(omega, v): the position moves by R v to first order
            u = self.u0 / self.d0
            H[0] = np.concatenate([np.zeros(3), -u @ pa.rotation().matrix()]).reshape(1, 6)
            H[1] = np.concatenate([np.zeros(3), u @ pb.rotation().matrix()]).reshape(1, 6)
        return np.array([float(self.u0 @ d) / self.d0 - 1.0])


def _restored(kf: MapKeyframe, store, levels: int) -> MapKeyframe:
    """A live copy of a keyframe (retired ones read from ``store``) with no
    cached mapping pixels and no prior weights (the weak ones apply)."""
    image, keyframe = kf.restore(store, levels)
    return MapKeyframe(kf.index, kf.frame, image, keyframe, kf.segment)


def _build(kfs: List[MapKeyframe], config: OdometryConfig, ba: GlobalBAConfig,
           groups: list, landmarks: Optional[LandmarkMap]):
    """``(batch, n_factors, gauge, (landmark ids, n_landmark_factors))`` of one segment's graph (its
    factor groups appended to ``groups``).  Raises ValueError when the first two
    keyframes share a position (no scale gauge)."""
    first = kfs[0]
    baseline = kfs[1].keyframe.T_world_kf[:3, 3] - first.keyframe.T_world_kf[:3, 3]
    gauge = _DistanceGauge(pose_key(first.index), pose_key(kfs[1].index), baseline,
                           SCALE_GAUGE_SIGMA)
    batch = FactorBatch()
    w = config.render_prior_weight if ba.shape_prior_weight is None else ba.shape_prior_weight
    for kf in kfs:
        add_keyframe_variables(batch, kf, config, np.full(len(kf.keyframe.primitives), float(w)))
    batch.graph.add(pose_gauge_prior(pose_key(first.index), first.keyframe.T_world_kf,
                                     GAUGE_SIGMA))
    batch.graph.add(gauge.factor)
    n = 0
    for j, kf in enumerate(kfs):
        for prev in kfs[max(0, j - int(ba.neighbours)):j]:
            n += link_keyframe_pair(batch, config, prev, kf, kf.index, groups)
    lms = (([], 0) if landmarks is None else
           add_segment_landmark_factors(batch, landmarks, {kf.index for kf in kfs}))
    return batch, n, gauge, lms


def _solve(batch: FactorBatch, ba: GlobalBAConfig):
    """``(estimate, iterations, initial cost, final cost)`` of LM on the batch."""
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(int(ba.max_iterations))
    p.setRelativeErrorTol(float(ba.relative_tol))
    p.setAbsoluteErrorTol(1e-9)
    opt = gtsam.LevenbergMarquardtOptimizer(batch.graph, batch.values, p)
    c0 = float(batch.graph.error(batch.values))
    est = opt.optimize()
    return est, int(opt.iterations()), c0, float(batch.graph.error(est))


def _segment(kfs: List[MapKeyframe], config: OdometryConfig, ba: GlobalBAConfig,
             out: GlobalBAResult, landmarks: Optional[LandmarkMap]) -> bool:
    """Optimise one segment's (restored) keyframes into ``out``; False when it failed."""
    t = time.perf_counter()
    rep = {"segment": int(kfs[0].segment), "keyframes": [int(k.index) for k in kfs]}
    groups: list = []
    try:
        batch, n, _gauge, (lms, n_lm) = _build(kfs, config, ba, groups, landmarks)
        rep.update(n_factors=int(n), n_landmarks=len(lms), n_landmark_factors=int(n_lm))
        est, iters, c0, c1 = _solve(batch, ba)
        points = {lid: np.asarray(est.atPoint3(landmark_key(lid)), dtype=np.float64)
                  for lid in lms}
        poses = {k.index: est.atPose3(pose_key(k.index)).matrix() for k in kfs}
        shapes = {k.index: np.array([est.atVector(scale_key(i, keyframe=k.index))
                                     for i in range(len(k.keyframe.primitives))]) for k in kfs}
        if not all(np.all(np.isfinite(a)) for a in [*poses.values(), *shapes.values(),
                                                     *points.values()]):
            raise RuntimeError("non-finite estimate")
    except (RuntimeError, ValueError) as exc:   # e.g. gtsam.IndeterminantLinearSystemException
        log.warning("global BA of segment %d failed (%s); kept", kfs[0].segment,
                    gtsam_error_line(exc))
        out.segments.append({**rep, "status": "failed", "error": gtsam_error_line(exc)})
        return False
    finally:
        release_groups(groups)       # else never freed: a reference cycle through gtsam
    out.T_world_kf.update(poses)
    out.shapes.update(shapes)
    out.points.update(points)
    out.n_landmark_factors += n_lm
    out.initial_cost += c0
    out.final_cost += c1
    out.iterations += iters
    out.n_factors += n
    out.segments.append({**rep, "status": "ok", "initial_cost": c0, "final_cost": c1,
                         "iterations": iters, "seconds": time.perf_counter() - t})
    log.info("global BA segment %d: %d keyframes, %d factors, cost %.4g -> %.4g in %d "
             "iterations", kfs[0].segment, len(kfs), n, c0, c1, iters)
    return True


def refine_keyframes(keyframes: Sequence[MapKeyframe], store, config: OdometryConfig,
                     ba: GlobalBAConfig = GlobalBAConfig(),
                     landmarks: Optional[LandmarkMap] = None) -> GlobalBAResult:
    """Photometric bundle adjustment of every keyframe, one graph per map segment
    (module docstring); segments with fewer than two keyframes are left out.

    Args:
        keyframes: the odometry's :class:`~spgeo.vo.map.MapKeyframe` objects
            in creation order (live or retired; none is modified).
        store: the :class:`~spgeo.vo.keyframe_store.KeyframeStore` holding the
            retired ones.
        config: the odometry's :class:`~spgeo.vo.config.OdometryConfig`
            (photometric options, primitive model, pyramid levels, priors).
        ba: :class:`GlobalBAConfig`.
        landmarks: the odometry's :class:`~spgeo.vo.landmarks.LandmarkMap` (None:
            photometric factors only); its landmarks seen by two keyframes of a
            segment get projection factors there (none is modified).

    Returns:
        A :class:`GlobalBAResult` (apply it with :meth:`spgeo.vo.Odometry.refine`).

    Raises:
        ValueError: ``ba.map_level`` not below ``config.keyframe_levels``.
    """
    t0 = time.perf_counter()
    if ba.map_level is not None:
        if int(ba.map_level) >= config.keyframe_levels:
            raise ValueError(f"GlobalBAConfig.map_level {ba.map_level} must be below "
                             f"keyframe_levels {config.keyframe_levels}")
        config = dataclasses.replace(config, map_level=int(ba.map_level))
    out = GlobalBAResult()
    segments: Dict[int, List[MapKeyframe]] = {}
    for kf in keyframes:
        segments.setdefault(kf.segment, []).append(kf)
    ok = []
    for seg in sorted(segments):
        if len(segments[seg]) < 2:
            continue
        kfs = [_restored(kf, store, config.keyframe_levels) for kf in segments[seg]]
        ok.append(_segment(kfs, config, ba, out, landmarks))
        del kfs
    out.status = "skipped" if not ok else ("ok" if all(ok) else "failed")
    out.seconds = time.perf_counter() - t0
    return out

