"""Window mapping of the VO: the GTSAM ``BatchFixedLagSmoother`` over keyframes.

A :class:`WindowMapper` owns the smoother (Levenberg-Marquardt), its keys, the
photometric factor groups alive in it and the supporting frames' smoothed
poses.  Variables: keyframe poses, per-keyframe primitive shape variables
(log-scales, or inverse-depth planes with ``primitive_model="planar"``),
supporting-frame poses and an affine brightness per directed (reference,
target) pair.  Each new keyframe is linked to the previous one by photometric
factors in both directions, and the previous keyframe to up to ``n_support``
supporting non-keyframes tracked against it (evenly spaced; paper: 4), whose
poses are optimised too.  One
:class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` per primitive
and pair, built at pyramid level ``mapping.level``; the factors of a pair are
evaluated together (:class:`~spgeo.factors.photometric_group.PhotometricFactorGroup`,
identical values, one vectorised pass).  The first keyframe's pose has a tight
gauge prior (each of a saved map's keyframes a segment starts with, too:
:mod:`spgeo.vo.map_entry`); every shape variable a weak prior (weight ``scale_prior_weight``)
to its initial value; a new keyframe's primitives whose scale was rendered
from the map (or, with a depth-using front-end, all of them) get the stronger
``render_prior_weight``: the render is a measurement of their scale (after a
pure rotation the photometric factors between the two keyframes carry no
parallax).
Smoother timestamps are keyframe indices (a supporting frame carries its
keyframe's) and the lag keeps ``window`` keyframes: older keys are
*marginalised* (their information stays as a linear prior), not dropped.
After each update the window's :class:`~spgeo.vo.tracking.Keyframe` objects
are rebuilt from the smoother's estimate.

With ``OdometryConfig.pixel_budget`` the keyframes entering the window take
the tracker's pixel selection (:mod:`spgeo.vo.pixels`); the factors use every
pixel of ``mapping.level`` (``Keyframe.level_data`` without selection), or with
``mapping.pixel_fraction < 1`` the strongest-gradient ones.  Primitives left
without pixels have no photometric factor, are held by their priors and are
counted in the report (``primitives_without_pixels``).

The smoother's solver constants (``MAP_*``) are module constants, its prior sigmas
those of :mod:`spgeo.graph.builders` (``GAUGE_SIGMA``, ``PLANAR_SLOPE_SIGMA``,
``BRIGHTNESS_PRIOR_SIGMA``): nothing overrides them.  Keys: :mod:`spgeo.graph.keys`;
the keyframe variables and factor groups come from :mod:`spgeo.graph.builders`.

A failed update (a gtsam ``RuntimeError``, e.g. an indeterminant system)
restarts the window from the last two keyframes once; if the restarted
two-keyframe window fails too, the keyframe poses stay as tracked.
"""
from __future__ import annotations

import logging
import time
from typing import Dict, List, Optional, Sequence

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.photometric_group import PhotometricFactorGroup, release_groups
from ..factors.priors import pose_gauge_prior
from ..graph.builders import (GAUGE_SIGMA, FactorBatch, add_factor_group, add_keyframe_variables,
                              gtsam_error_line, link_keyframe_pair, mapping_pixels,
                              pair_factor_group)
from ..graph.keys import pose_key, scale_key, support_brightness_key, support_pose_key
from .config import OdometryConfig
from .keyframe import Keyframe, with_shape_values
from .landmarks import LandmarkMap, add_landmark_factors, read_landmarks
from .map import MapKeyframe, SupportCandidate

__all__ = ["WindowMapper", "adopt_selection", "choose_support", "MAP_RELATIVE_TOL",
           "MAP_LAMBDA_MAX", "MAP_LAMBDA_INITIAL"]

log = logging.getLogger(__name__)

#: an update stops when an LM iteration lowers the window's cost by less than this
#: fraction (1e-2: every keyframe stays in ``window`` updates; 1e-3 doubled the
#: mapping time for the same ATE, docs/results.md)
MAP_RELATIVE_TOL = 1e-2
#: an LM iteration gives up when its damping exceeds this (each rejected trial costs a
#: solve and a cost evaluation of the whole window, and near convergence gtsam keeps
#: raising the damping until this bound)
MAP_LAMBDA_MAX = 1e3
#: initial LM damping of every window update (gtsam's)
MAP_LAMBDA_INITIAL = 1e-5


class WindowMapper:
    """The sliding-window smoother of one :class:`~spgeo.vo.Odometry` (module
    docstring).

    Attributes:
        smoother: the ``gtsam.BatchFixedLagSmoother`` (replaced by :meth:`reset`).
        reports: one dict per mapped keyframe (factor counts, seconds, ...).
        refreshed: what the last :meth:`map_keyframe` wrote into its keyframes:
            keyframe index -> ``(T_world_kf, shape values)``, the arguments of
            :func:`~spgeo.vo.keyframe.with_shape_values` (a copy of the
            keyframes, e.g. a mapping worker's caller, applies them to stay
            equal).
        refreshed_support: frame number -> smoothed ``T_world_frame`` of the
            supporting frames still in the window after the last
            :meth:`map_keyframe` (the caller's map keeps them,
            :meth:`spgeo.vo.map.KeyframeMap.apply_update`).
    """

    def __init__(self, config: OdometryConfig) -> None:
        self.config = config
        self.smoother = self.new_smoother()
        self._groups: List[PhotometricFactorGroup] = []     # alive while in the smoother
        self._support_frames: List[int] = []
        self.reports: List[dict] = []
        self.refreshed: Dict[int, tuple] = {}
        self.refreshed_support: Dict[int, np.ndarray] = {}
        #: sparse landmarks (:mod:`spgeo.vo.landmarks`; None: none, the default)
        self.landmarks: Optional[LandmarkMap] = None
        self._poses_in: set = set()       # keyframes whose pose is in the smoother
        self._lms_in: set = set()         # landmark ids in the smoother
        self._added: set = set()          # keyframes given to the smoother since its reset

    def new_smoother(self) -> gtsam.BatchFixedLagSmoother:
        """An empty smoother with the configured LM parameters and lag."""
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(int(self.config.mapping.iterations))
        p.setRelativeErrorTol(float(MAP_RELATIVE_TOL))
        p.setAbsoluteErrorTol(1e-9)
        p.setlambdaUpperBound(float(MAP_LAMBDA_MAX))
        p.setlambdaInitial(float(MAP_LAMBDA_INITIAL))
        return gtsam.BatchFixedLagSmoother(float(self.config.window) - 0.5, p)

    def reset(self) -> None:
        """Empty smoother and no factor group (a new map segment)."""
        self.smoother = self.new_smoother()
        release_groups(self._groups)     # else never freed: a reference cycle through gtsam
        self._groups = []
        self._poses_in, self._lms_in = set(), set()
        self._added = set()

    def estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window)."""
        return self.smoother.calculateEstimate()

    # ------------------------------------------------------------ factors
    def _group(self, ref: MapKeyframe, tgt_key: int, tgt_image: np.ndarray,
               tgt_camera: PinholeCamera, bkey: int) -> Optional[PhotometricFactorGroup]:
        """:func:`pair_factor_group` with this mapper's configuration."""
        return pair_factor_group(self.config, ref, tgt_key, tgt_image, tgt_camera, bkey)

    def _map_pixels(self, ref: MapKeyframe):
        """:func:`mapping_pixels` with this mapper's configuration."""
        return mapping_pixels(self.config, ref)

    # ------------------------------------------------------------ update
    def map_keyframe(self, segment_kfs: Sequence[MapKeyframe],
                     candidates: Sequence[SupportCandidate], segment: int) -> bool:
        """Add the newest keyframe of ``segment_kfs`` (the current segment's
        keyframes in order, at least two) and the previous keyframe's
        supporting frames (chosen among ``candidates``) to the smoother, update
        the window and refresh its keyframes (their ``keyframe`` attribute).

        Returns True when the update failed once and the window was restarted
        from the last two keyframes (the caller's segment keeps only those).
        """
        kfs = list(segment_kfs)
        for kf in kfs:
            adopt_selection(kf, self.config)
        self.refreshed, self.refreshed_support = {}, {}
        restarted = False
        while True:
            try:
                self._update(kfs, candidates, segment)
                return restarted
            except _UpdateFailed as exc:
                k = kfs[-1].index
                if len(kfs) == 2:
                    log.warning("mapping keyframe %d failed (%s); keyframe poses kept as "
                                "tracked", k, exc)
                    self.reset()
                    self.reports.append({"keyframe": k, "segment": segment, "failed": True})
                    return restarted
                # restart the window from the last two keyframes (old ones stay as they are)
                log.warning("mapping keyframe %d failed (%s); restarting the window", k, exc)
                self.reset()
                kfs, restarted = kfs[-2:], True

    def _update(self, kfs: List[MapKeyframe], candidates: Sequence[SupportCandidate],
                segment: int) -> None:
        """One smoother update with the newest keyframe ``kfs[-1]``; raises
        :class:`_UpdateFailed` when gtsam raises."""
        new, prev = kfs[-1], kfs[-2]
        batch = FactorBatch()
        for kf in kfs[:-1]:     # a segment's start: its keyframe 0, or a saved map's keyframes
            if kf.index not in self._added:
                self._add_keyframe(batch, kf)
                batch.graph.add(pose_gauge_prior(pose_key(kf.index), kf.keyframe.T_world_kf,
                                                 GAUGE_SIGMA))
        self._add_keyframe(batch, new)
        n_pair = self._link_keyframes(batch, prev, new)
        sel_new = self._map_pixels(new)
        n_empty = len(new.keyframe.primitives) - (0 if sel_new is None else sel_new[2].size)
        chosen = choose_support(candidates, self.config.n_support)
        n_sup = self._add_support(batch, prev, chosen)
        n_lm = self._add_landmarks(batch, kfs, new)
        est, secs = self._solve(batch)
        self._refresh(est, kfs)
        if self.landmarks is not None:
            self._refresh_landmarks(est, kfs)
        alive = [est.exists(g.ref_key) and est.exists(g.tgt_key) for g in self._groups]
        release_groups([g for g, a in zip(self._groups, alive) if not a])
        self._groups = [g for g, a in zip(self._groups, alive) if a]
        self.reports.append({"keyframe": new.index, "segment": segment,
                             "factors_keyframe_pairs": n_pair, "factors_support": n_sup,
                             "support_frames": [c.frame for c in chosen],
                             "primitives_without_pixels": int(n_empty),
                             "seconds": secs, "keys_in_window": int(est.size())})
        if self.landmarks is not None:
            self.reports[-1]["factors_landmarks"] = n_lm
        log.debug("mapping kf %d: %d + %d factors, %.2f s", new.index, n_pair, n_sup, secs)

    def _add_keyframe(self, batch: FactorBatch, kf: MapKeyframe) -> None:
        """A keyframe's pose and shape variables, with the shapes' priors."""
        add_keyframe_variables(batch, kf, self.config)
        self._added.add(kf.index)

    def _add_group(self, batch: FactorBatch, group: Optional[PhotometricFactorGroup],
                   bkey: int, b0, t: int) -> int:
        """A factor group with its brightness variable and prior; its factor count."""
        return add_factor_group(batch, group, bkey, b0, t, self._groups)

    def _link_keyframes(self, batch: FactorBatch, prev: MapKeyframe, new: MapKeyframe) -> int:
        """Photometric factors of the new keyframe pair, both directions."""
        return link_keyframe_pair(batch, self.config, prev, new, new.index, self._groups)

    def _add_support(self, batch: FactorBatch, prev: MapKeyframe,
                     chosen: Sequence[SupportCandidate]) -> int:
        """The supporting frames' poses and their factors from ``prev``."""
        lvl = self.config.mapping.level
        n_sup = 0
        for c in chosen:
            pkey = support_pose_key(c.frame)
            pyr = prev.keyframe.frame_pyramid(c.image, lvl + 1)
            T_w = prev.keyframe.T_world_kf @ c.T_kf_frame
            batch.insert(pkey, gtsam.Pose3(T_w), prev.index)
            bkey = support_brightness_key(c.frame)
            g = self._group(prev, pkey, pyr.images[lvl], pyr.cameras[lvl], bkey)
            n_sup += self._add_group(batch, g, bkey, c.brightness, prev.index)
            self._support_frames.append(c.frame)
        return n_sup

    def _add_landmarks(self, batch: FactorBatch, kfs: List[MapKeyframe],
                       new: MapKeyframe) -> int:
        """The new keyframe's landmark factors (none without landmarks)."""
        if self.landmarks is None:
            return 0
        poses_in = {kf.index for kf in kfs
                    if kf.index in self._poses_in or batch.values.exists(pose_key(kf.index))}
        return add_landmark_factors(batch, self.landmarks, new.index, poses_in, self._lms_in,
                                    new.keyframe.median_depth)

    def _refresh_landmarks(self, est: gtsam.Values, kfs: List[MapKeyframe]) -> None:
        """Landmark points and the keyframes in the smoother from its estimate."""
        self._poses_in = {kf.index for kf in kfs if est.exists(pose_key(kf.index))}
        for kf in kfs:
            if kf.index in self._poses_in:
                self.landmarks.set_pose(kf.index, kf.keyframe.T_world_kf)
        read_landmarks(self.landmarks, est, self._lms_in)

    def _solve(self, batch: FactorBatch):
        """``(estimate, seconds)`` of the smoother update with ``batch``."""
        t = time.perf_counter()
        try:
            self.smoother.update(batch.graph, batch.values, batch.stamps)
        except RuntimeError as exc:       # e.g. gtsam.IndeterminantLinearSystemException
            raise _UpdateFailed(gtsam_error_line(exc)) from exc
        est = self.smoother.calculateEstimate()
        return est, time.perf_counter() - t

    def _refresh(self, est: gtsam.Values, kfs: List[MapKeyframe]) -> None:
        """Window keyframes and supporting frames from the smoother's estimate."""
        for kf in kfs[-self.config.window - 1:]:
            j = kf.index
            if not est.exists(pose_key(j)):
                continue
            T = est.atPose3(pose_key(j)).matrix()
            n_s = len(kf.keyframe.primitives)
            th = np.array([est.atVector(scale_key(i, keyframe=j)) for i in range(n_s)])
            if not (np.all(np.isfinite(T)) and np.all(np.isfinite(th))):
                log.warning("mapping produced non-finite values for keyframe %d; kept", j)
                continue
            kf.keyframe = with_shape_values(kf.keyframe, th, self.config.primitive_model, T)
            self.refreshed[j] = (T, th)
        for f in self._support_frames[-(self.config.window + 1) * max(self.config.n_support, 1):]:
            key = support_pose_key(f)
            if est.exists(key):
                T = est.atPose3(key).matrix()
                if np.all(np.isfinite(T)):
                    self.refreshed_support[f] = T


def choose_support(candidates: Sequence[SupportCandidate], n_support: int
                   ) -> List[SupportCandidate]:
    """The supporting frames of the previous keyframe: ``n_support`` evenly
    spaced among its tracked frames ``candidates`` (all when fewer; choosing
    again among the chosen keeps them all)."""
    if n_support > 0 and candidates:
        pick = np.unique(np.round(np.linspace(0, len(candidates) - 1,
                                              min(n_support, len(candidates)))).astype(int))
        return [candidates[i] for i in pick]
    return []


def adopt_selection(kf: MapKeyframe, config: OdometryConfig) -> None:
    """Give a keyframe ``config``'s pixel selection (its :class:`Keyframe`
    rebuilt when it has another one; its cached mapping pixels dropped then)."""
    sel = config.selection
    if kf.keyframe.selection != sel:
        k = kf.keyframe
        kf.keyframe = Keyframe.build(kf.image, k.primitives, k.T_world_kf,
                                     config.keyframe_levels, sel)
        kf.map_pixels = None


class _UpdateFailed(RuntimeError):
    """A smoother update raised (message: :func:`~spgeo.graph.builders.gtsam_error_line`)."""
