"""Pose-only photometric tracking of a frame against a keyframe's primitives.

The VO front-end (docs/design.md §5) aligns every new frame to the latest keyframe
(:class:`~spgeo.vo.keyframe.Keyframe`: batched pixels per level, pixel
selection) with the keyframe's primitive scales held fixed, minimising
the factor graph's photometric cost (:class:`~spgeo.vo.tracking_cost.TrackingCost`,
whose module docstring states it) coarse to fine.  At each level the 8x8
normal equations are solved with Levenberg-Marquardt damping; a step is taken
only if the cost decreases.  The pose update is gtsam's retraction
``T_world_frame <- T_world_frame Exp(xi)``, ``xi = (omega, v)``.

Decisions (``TrackResult.relative_cost`` and ``valid_fraction``, which the
failure test and the VO's keyframe test compare with thresholds) are taken on
*decision pixels* that do not depend on the pixels optimised on: every
primitive pixel of the finest level on a lattice of stride
``round(width / TrackerConfig.decision_width)``.  When the finest level was
optimised on fewer pixels (a selection), ``TrackerConfig.decision_iterations``
LM steps on the decision pixels refine the pose first; otherwise (all pixels)
the decision pixels are evaluated once, or, when they are the finest level's
own pixels (160x120 without selection), its evaluation is reused.

``Keyframe``, ``TrackingCost`` and ``TrackerConfig`` are re-exported here.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

import gtsam

from ..geometry import check_pose, invert_pose, nearest_rotation
from ..images import Pyramid
from .config import TrackerConfig
from .keyframe import Keyframe
from .tracking_cost import TrackingCost

__all__ = ["TrackerConfig", "Keyframe", "TrackResult", "track_frame", "valid_fraction",
           "constant_velocity_guess", "TrackingCost"]

log = logging.getLogger(__name__)

#: initial LM damping (multiplies ``diag(H)``)
LM_LAMBDA_INITIAL = 1e-4
#: damping multiplier on a rejected step / divisor on an accepted one
LM_LAMBDA_FACTOR = 10.0
#: a level stops when the damping exceeds this (no step decreases the cost any more)
LM_LAMBDA_MAX = 1e5
#: a level stops when a step (accepted or rejected) turns by less than this (radians;
#: 0.003 deg) and moves by less than ``TRANSLATION_TOL``
ROTATION_TOL = 5e-5
#: translation step threshold as a fraction of the keyframe's median depth (0.1 mm at 2 m)
TRANSLATION_TOL = 5e-5


@dataclass
class TrackResult:
    """Output of :func:`track_frame`.

    Attributes:
        T_world_frame: 4x4 camera-to-world pose of the frame.
        brightness: ``(a, b)`` of the frame relative to the keyframe.
        cost: final cost (photometric + brightness prior) at the finest level.
        photometric_cost: its photometric part (the factors' total error).
        relative_cost: photometric cost over the cost of a featureless frame
            on the same valid pixels (see ``TrackerConfig.max_relative_cost``),
            both on the *decision pixels*: every primitive pixel of the
            finest level on the lattice of ``decision_stride`` (no pixel
            selection), so it does not depend on the pixels the pose was
            optimised on.
        valid_fraction: fraction of the decision pixels that project inside
            the frame (in front of it) at the final pose.
        iterations: LM iterations (tried steps) per level, coarsest first.
        levels: the pyramid levels processed, coarsest first.
        status: ``"ok"`` or ``"lost"``.
        reason: why ``"lost"`` (``"diverged"``, ``"no_pixels"``,
            ``"low_overlap"``, ``"high_cost"``, ``"cost_increase"``); None if ok.
        timings: seconds: ``prepare`` (frame pyramid), ``level<l>`` per level,
            ``total``.
        report: per level: pixels, primitives, initial/final cost, accepted
            steps, final damping.
        decision_stride: lattice stride of the decision pixels
            (:func:`decision_stride`).
        decision_steps: LM steps tried on the decision pixels after the
            pyramid (``TrackerConfig.decision_iterations``); ``T_world_frame``
            and ``brightness`` include them, ``cost`` and
            ``photometric_cost`` are the finest level's before them.
        feature_checked: ``"ok"`` although ``relative_cost`` exceeds
            ``TrackerConfig.max_relative_cost``, because feature matches
            agree with the pose (:meth:`spgeo.vo.frame_tracker.FrameTracker.track`).
        feature_pose: ``T_world_frame`` is a feature-based PnP pose, kept because
            only the photometric cost refused every start (``feature_checked``
            too; :meth:`spgeo.vo.frame_tracker.FrameTracker.track`).
        pnp_inliers: the PnP inliers of the best feature-based pose the decision
            computed (map landmarks or keyframe features), or None.
    """

    T_world_frame: np.ndarray
    brightness: np.ndarray
    cost: float
    photometric_cost: float
    relative_cost: float
    valid_fraction: float
    iterations: List[int]
    levels: List[int]
    status: str
    reason: Optional[str]
    timings: Dict[str, float]
    report: List[dict]
    decision_stride: int = 1
    decision_steps: int = 0
    feature_checked: bool = False
    feature_pose: bool = False
    pnp_inliers: Optional[int] = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def __repr__(self) -> str:
        """One line: status (and reason), relative cost, valid fraction, LM steps."""
        why = "" if self.reason is None else f" ({self.reason})"
        return (f"TrackResult({self.status}{why}, relative cost {self.relative_cost:.3f}, "
                f"valid {self.valid_fraction:.2f}, {sum(self.iterations)} iterations)")

    def T_kf_frame(self, keyframe: Keyframe) -> np.ndarray:
        """The frame's pose in the keyframe's camera."""
        return invert_pose(keyframe.T_world_kf) @ self.T_world_frame


def _retract(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """gtsam's Pose3 retraction ``T Exp(xi)``, ``xi = (omega, v)``."""
    return gtsam.Pose3(T).retract(np.asarray(xi, dtype=np.float64)).matrix()


def valid_fraction(keyframe: Keyframe, T_world_frame: np.ndarray, min_depth: float,
                    stride: int = 1) -> float:
    """Fraction of the keyframe primitive points on the lattice of ``stride``
    (1: all of them) inside the frame's image."""
    T = invert_pose(T_world_frame) @ keyframe.T_world_kf
    P = keyframe.lattice_points(stride)
    Y = [T[i, 0] * P[0] + T[i, 1] * P[1] + T[i, 2] * P[2] + T[i, 3] for i in range(3)]
    cam = keyframe.camera
    z = Y[2]
    front = z > min_depth
    zs = np.where(front, z, 1.0)
    u = cam.fx * Y[0] / zs + cam.cx
    v = cam.fy * Y[1] / zs + cam.cy
    inside = front & (u >= 0) & (u <= cam.width - 1) & (v >= 0) & (v <= cam.height - 1)
    return float(np.count_nonzero(inside)) / max(inside.size, 1)


def _levenberg_marquardt(fn: TrackingCost, T: np.ndarray, ab: np.ndarray, cur: dict,
                         max_it: int, tr_tol: float, config: TrackerConfig):
    """LM over one :class:`TrackingCost` from ``(T, ab)`` (``cur``: its
    linearised evaluation there); returns ``(T, ab, evaluation (not
    linearised after an accepted last step), tried steps, accepted steps,
    final damping)``."""
    nd = fn.dim
    lam = LM_LAMBDA_INITIAL
    its = accepted = 0
    while its < max_it and np.isfinite(cur["cost"]):
        H, g = cur["H"], cur["g"]
        diag = np.diag(H).copy()
        diag = np.maximum(diag, 1e-9 * max(float(diag.max()), 1e-12))
        its += 1
        try:
            delta = np.linalg.solve(H + lam * np.diag(diag), -g)
        except np.linalg.LinAlgError:
            delta = np.full(nd, np.nan)
        if not np.all(np.isfinite(delta)):
            lam *= LM_LAMBDA_FACTOR
            if lam > LM_LAMBDA_MAX:
                break
            continue
        T_new = _retract(T, delta[:6])
        ab_new = ab + delta[6:] if config.brightness else ab
        new = fn.evaluate(T_new, ab_new, jacobians=False)
        small = (np.linalg.norm(delta[:3]) < ROTATION_TOL
                 and np.linalg.norm(delta[3:6]) < tr_tol)
        if np.isfinite(new["cost"]) and new["cost"] < cur["cost"]:
            rel = (cur["cost"] - new["cost"]) / max(cur["cost"], 1e-300)
            T, ab, cur = T_new, ab_new, new
            accepted += 1
            lam = max(lam / LM_LAMBDA_FACTOR, 1e-12)
            if rel < config.relative_cost_tol or small or its >= max_it:
                break
            fn.linearise(cur)
        else:
            # a rejected step that was already negligible: converged
            lam *= LM_LAMBDA_FACTOR
            if small or lam > LM_LAMBDA_MAX:
                break
    return T, ab, cur, its, accepted, lam


def decision_stride(width: int, decision_width: int) -> int:
    """Lattice stride of the decision pixels of an image ``width`` wide:
    ``round(width / decision_width)``, at least 1."""
    return max(1, int(round(int(width) / int(decision_width))))


def _decision_quantities(keyframe: Keyframe, pyr: Pyramid, stride: int, T: np.ndarray,
                         ab: np.ndarray, config: TrackerConfig, final: dict,
                         final_fn: TrackingCost, tr_tol: float
                         ) -> Tuple[np.ndarray, np.ndarray, float, float, int]:
    """``(T, ab, relative cost, valid fraction, refinement steps)`` on the
    decision pixels (the finest level's lattice of ``stride``,
    :class:`TrackResult`) from the pose ``T`` and brightness ``ab``;
    ``final`` / ``final_fn``: the last level's evaluation at that state
    (reused when it ran on the decision pixels).  When the last level had
    fewer pixels than the decision pixels, up to
    ``config.decision_iterations`` LM steps on the decision pixels refine
    ``(T, ab)`` first."""
    its = 0
    if (final_fn.level == 0
            and final_fn.data is keyframe.level_data(0, stride, config.min_level_pixels, None)):
        out, fn = final, final_fn
    else:
        fn = TrackingCost(keyframe, pyr.images[0], pyr.cameras[0], 0, config,
                          selection=None, subsample=stride)
        if fn.n_pixels == 0:
            return T, ab, float("nan"), valid_fraction(
                keyframe, T, config.photometric.min_depth, stride), 0
        if config.decision_iterations > 0 and final_fn.n_pixels < fn.n_pixels:
            out = fn.evaluate(T, ab, jacobians=True)
            T, ab, out, its, _, _ = _levenberg_marquardt(fn, T, ab, out,
                                                         config.decision_iterations, tr_tol,
                                                         config)
        else:
            out = fn.evaluate(T, ab, jacobians=False)
    vfrac = valid_fraction(keyframe, T, config.photometric.min_depth, stride)
    flat = fn.featureless_cost(out)
    rel = float(out["photometric_cost"]) / flat if flat > 0 else float("inf")
    return T, ab, rel, vfrac, its


def constant_velocity_guess(T_world_prev: np.ndarray,
                            T_world_prevprev: Optional[np.ndarray] = None) -> np.ndarray:
    """Initial pose of the next frame: the previous frame's pose moved by the
    last inter-frame motion (in the camera frame), ``T_prev (T_prevprev^-1 T_prev)``.
    Without ``T_world_prevprev`` the previous pose itself."""
    T_p = check_pose(np.asarray(T_world_prev, dtype=np.float64), "T_world_prev")
    if T_world_prevprev is None:
        return T_p.copy()
    T_pp = check_pose(np.asarray(T_world_prevprev, dtype=np.float64), "T_world_prevprev")
    T = T_p @ (invert_pose(T_pp) @ T_p)
    # re-orthonormalise the rotation (products accumulate rounding)
    T[:3, :3] = nearest_rotation(T[:3, :3])
    return T


def track_frame(keyframe: Keyframe, image: np.ndarray, T_world_init: np.ndarray,
                brightness_init: Sequence[float] = (0.0, 0.0),
                config: TrackerConfig = TrackerConfig(),
                reference_cost: Optional[float] = None) -> TrackResult:
    """Photometric pose-only alignment of ``image`` against ``keyframe``.

    Coarse-to-fine Levenberg-Marquardt over the frame pose (and affine
    brightness) minimising the factor graph's photometric cost with the
    keyframe's primitive scales fixed (module docstring,
    :mod:`spgeo.vo.tracking_cost`).

    Args:
        keyframe: :class:`Keyframe` (see :meth:`Keyframe.build`).
        image: the frame, same size as the keyframe's input image;
            uint8/uint16 or float in [0, 1], grey or RGB.
        T_world_init: initial 4x4 camera-to-world pose (e.g. the previous
            frame's, or :func:`constant_velocity_guess`).
        brightness_init: initial ``(a, b)``.
        config: :class:`TrackerConfig`.
        reference_cost: optional cost to compare with (cost blow-up check,
            ``config.max_cost_increase``).
    Returns:
        :class:`TrackResult`; a failed alignment is reported in ``status``
        (``"lost"``) and ``reason``, never raised.
    Raises:
        ValueError: malformed input (wrong image size, NaN/inf in the image,
            invalid pose or brightness).
    """
    t_start = time.perf_counter()
    T = check_pose(np.asarray(T_world_init, dtype=np.float64), "T_world_init").copy()
    ab = np.asarray(brightness_init, dtype=np.float64).reshape(-1)
    if ab.shape != (2,) or not np.all(np.isfinite(ab)):
        raise ValueError(f"brightness_init must be two finite numbers, got {brightness_init!r}")
    if not config.brightness:
        ab = np.zeros(2)
    pyr = keyframe.frame_pyramid(image, config.levels)
    timings: Dict[str, float] = {"prepare": time.perf_counter() - t_start}
    tr_tol = TRANSLATION_TOL * keyframe.median_depth
    T, ab, final, final_cost_fn, iterations, levels, report = _coarse_to_fine(
        keyframe, pyr, T, ab, config, tr_tol, timings)

    # ---- assessment on the decision pixels
    reason: Optional[str] = None
    finite = bool(np.all(np.isfinite(T)) and np.all(np.isfinite(ab)))
    dec = decision_stride(keyframe.camera.width, config.decision_width)
    rel_cost, vfrac, decision_steps = float("nan"), 0.0, 0
    if final is None:
        reason = "no_pixels"
        cost = photo = float("nan")
        if finite:
            vfrac = valid_fraction(keyframe, T, config.photometric.min_depth, dec)
    else:
        cost, photo = float(final["cost"]), float(final["photometric_cost"])
        if finite:
            t0 = time.perf_counter()
            T, ab, rel_cost, vfrac, decision_steps = _decision_quantities(
                keyframe, pyr, dec, T, ab, config, final, final_cost_fn, tr_tol)

            timings["decision"] = time.perf_counter() - t0
    if reason is None:
        reason = _lost_reason(finite, cost, vfrac, rel_cost, reference_cost, config)
    if not finite:
        vfrac = 0.0
        T, ab = check_pose(np.asarray(T_world_init, dtype=np.float64)).copy(), np.zeros(2)
    status = "ok" if reason is None else "lost"
    timings["total"] = time.perf_counter() - t_start
    if reason is not None:
        log.info("tracking lost (%s): valid fraction %.2f, relative cost %.3g",
                 reason, vfrac, rel_cost)
    return TrackResult(T, ab.copy(), cost, photo, float(rel_cost), vfrac, iterations, levels,
                       status, reason, timings, report, dec, decision_steps)


def _coarse_to_fine(keyframe: Keyframe, pyr: Pyramid, T: np.ndarray, ab: np.ndarray,
                    config: TrackerConfig, tr_tol: float, timings: Dict[str, float]):
    """LM at every level of ``pyr``, coarsest first: ``(T, ab, final evaluation
    (None without pixels), its TrackingCost, iterations, levels, report)``;
    adds ``timings["level<l>"]``."""
    n_levels = len(pyr)
    report: List[dict] = []
    iterations: List[int] = []
    levels: List[int] = []
    final: Optional[dict] = None
    final_cost_fn: Optional[TrackingCost] = None
    for lvl in reversed(range(n_levels)):
        t0 = time.perf_counter()
        fn = TrackingCost(keyframe, pyr.images[lvl], pyr.cameras[lvl], lvl, config)
        max_it = int(config.iterations[min(n_levels - 1 - lvl, len(config.iterations) - 1)])
        levels.append(lvl)
        if fn.n_pixels == 0:
            iterations.append(0)
            report.append({"level": lvl, "pixels": 0, "primitives": 0})
            continue
        cur = fn.evaluate(T, ab, jacobians=True)
        cost0 = cur["cost"]
        T, ab, cur, its, accepted, lam = _levenberg_marquardt(fn, T, ab, cur, max_it, tr_tol,
                                                              config)
        iterations.append(its)
        final, final_cost_fn = cur, fn
        dt = time.perf_counter() - t0
        timings[f"level{lvl}"] = dt
        report.append({"level": lvl, "pixels": fn.n_pixels,
                       "primitives": fn.data.n_primitives, "initial_cost": cost0,
                       "final_cost": cur["cost"], "accepted": accepted, "lambda": lam,
                       "valid_fraction": cur["valid_fraction"], "seconds": dt})
        log.debug("tracking level %d: %d px, %d its (%d accepted), cost %.4g -> %.4g",
                  lvl, fn.n_pixels, its, accepted, cost0, cur["cost"])
    return T, ab, final, final_cost_fn, iterations, levels, report


def _lost_reason(finite: bool, cost: float, vfrac: float, rel_cost: float,
                 reference_cost: Optional[float], config: TrackerConfig) -> Optional[str]:
    """Why a tracked frame is ``"lost"`` (:class:`TrackResult`), or None."""
    if not (finite and np.isfinite(cost)):
        return "diverged"
    if vfrac < config.min_valid_fraction:
        return "low_overlap"
    if not rel_cost <= config.max_relative_cost:
        return "high_cost"
    if (reference_cost is not None and np.isfinite(reference_cost)
            and cost > config.max_cost_increase * float(reference_cost)):
        return "cost_increase"
    return None
