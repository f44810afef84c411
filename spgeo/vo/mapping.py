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
and pair, built at pyramid level ``map_level``; the factors of a pair are
evaluated together (:class:`~spgeo.factors.photometric_group.PhotometricFactorGroup`,
identical values, one vectorised pass).  The first keyframe's pose has a tight
gauge prior; every shape variable a weak prior (weight ``scale_prior_weight``)
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
pixel of ``map_level`` (``Keyframe.level_data`` without selection), or with
``map_pixel_fraction < 1`` the strongest-gradient ones.  Primitives left
without pixels have no photometric factor, are held by their priors and are
counted in the report (``primitives_without_pixels``).

The smoother's solver constants (``MAP_*``, ``GAUGE_SIGMA``,
``PLANAR_SLOPE_SIGMA``, ``BRIGHTNESS_PRIOR_SIGMA``) are module constants:
nothing overrides them.

A failed update (a gtsam ``RuntimeError``, e.g. an indeterminant system)
restarts the window from the last two keyframes once; if the restarted
two-keyframe window fails too, the keyframe poses stay as tracked.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.photometric import PlanarShape, ScaledShape
from ..factors.photometric_group import PhotometricFactorGroup, release_groups
from ..factors.priors import brightness_prior, log_scale_prior, planar_slope_prior, pose_gauge_prior
from ..primitives import PrimitiveSet
from ..sfm.graph import gtsam_error_line
from .config import PRIMITIVE_MODELS, OdometryConfig
from .tracking import Keyframe

__all__ = ["WindowMapper", "MapKeyframe", "SupportCandidate", "kf_pose_key", "kf_scale_key",
           "kf_brightness_key", "support_pose_key", "apply_primitive_model", "FactorBatch",
           "shape_values", "with_shape_values", "mapping_pixels", "pair_factor_group",
           "add_keyframe_variables", "add_factor_group", "link_keyframe_pair"]

log = logging.getLogger(__name__)

_MAX_PRIMS = 1_000_000

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
#: sigma of the first keyframe's pose prior (the gauge)
GAUGE_SIGMA = 1e-6
#: sigma of the planar model's slope prior (towards fronto-parallel; weak)
PLANAR_SLOPE_SIGMA = 2.0
#: sigmas of the priors of the brightness ``(a, b)`` variables (as the SfM graph's
#: default ``SfMConfig.brightness_prior_sigma``)
BRIGHTNESS_PRIOR_SIGMA: Tuple[float, float] = (0.3, 0.3)


def kf_pose_key(k: int) -> int:
    """Smoother key of keyframe ``k``'s pose ``T_world_kf``."""
    return gtsam.symbol("x", int(k))


def kf_scale_key(k: int, i: int) -> int:
    """Smoother key of primitive ``i``'s shape variable (log-scale, or plane
    with the planar model) in keyframe ``k``."""
    return gtsam.symbol("s", int(k) * _MAX_PRIMS + int(i))


def kf_brightness_key(ref: int, tgt: int) -> int:
    """Smoother key of the affine brightness of keyframe ``tgt`` seen from
    ``ref`` (any two keyframes; consecutive ones use the symbols ``b``/``c``
    indexed by the later keyframe, others ``e``/``g``)."""
    hi, lo = int(max(ref, tgt)), int(min(ref, tgt))
    if hi - lo == 1:
        return gtsam.symbol("b" if tgt > ref else "c", hi)
    return gtsam.symbol("e" if tgt > ref else "g", hi * _MAX_PRIMS + lo)


def support_pose_key(frame: int) -> int:
    """Smoother key of supporting frame ``frame``'s pose (frame number)."""
    return gtsam.symbol("f", int(frame))


def _support_brightness_key(frame: int) -> int:
    return gtsam.symbol("d", int(frame))


def apply_primitive_model(primitives: PrimitiveSet, model: str) -> PrimitiveSet:
    """The shapes of an ablation (:data:`PRIMITIVE_MODELS`): ``"integrated"``
    unchanged; ``"constant_depth"``: each primitive fronto-parallel at its
    anchor depth; ``"constant_normal"`` / ``"planar"``: each primitive the
    least-squares inverse-depth plane of its integrated shape.  Raises
    ``ValueError`` for another name."""
    if model == "integrated":
        return primitives
    if model == "constant_depth":
        return primitives.with_scaled_log_depth(np.repeat(primitives.log_scales, primitives.sizes))
    if model in ("constant_normal", "planar"):
        return primitives.with_planes(primitives.fit_planes())[0]
    raise ValueError(f"unknown primitive model {model!r}; expected one of {PRIMITIVE_MODELS}")


@dataclass
class MapKeyframe:
    """A keyframe of the map: numbers, input image and its current
    :class:`~spgeo.vo.tracking.Keyframe` (pose and primitives).

    A *retired* keyframe (:meth:`retire`: it left the window, its state is
    final) holds only its numbers, pose and median depth: ``image`` and
    ``keyframe`` are None, its image and primitives are in a
    :class:`~spgeo.vo.keyframe_store.KeyframeStore` (:meth:`restore`).
    """

    index: int          # keyframe number
    frame: int          # frame number
    image: Optional[np.ndarray]
    keyframe: Optional[Keyframe]
    segment: int = 0
    map_pixels: Optional[tuple] = None   # cached mapping pixels (pixels and image never change)
    prior_weights: Optional[np.ndarray] = None   # (N,) weights of the shape priors
    _final: Optional[tuple] = None   # retired: (T_world_kf, median depth, selection)
    _log_scale_shift: float = 0.0    # retired: added to the stored log-scales (loop closure)

    @property
    def retired(self) -> bool:
        return self._final is not None

    @property
    def T_world_kf(self) -> np.ndarray:
        """4x4 camera-to-world pose (the keyframe's current one)."""
        return self._final[0] if self._final is not None else self.keyframe.T_world_kf

    @property
    def median_depth(self) -> float:
        """Median depth of the keyframe's points (current scales)."""
        return self._final[1] if self._final is not None else self.keyframe.median_depth

    def retire(self, store) -> None:
        """Put image and primitives into ``store`` (a
        :class:`~spgeo.vo.keyframe_store.KeyframeStore`) and drop everything
        else but the pose and median depth; no-op when already retired."""
        if self._final is not None:
            return
        kf = self.keyframe
        store.put(self.index, self.image, kf.primitives)
        self._final = (kf.T_world_kf.copy(), float(kf.median_depth), kf.selection)
        self.image = self.keyframe = None
        self.map_pixels = self.prior_weights = None

    def input_image(self, store) -> np.ndarray:
        """The input image (for a retired keyframe read from ``store``, without
        building the :class:`Keyframe` as :meth:`restore` does)."""
        return self.image if self._final is None else store.get(self.index)[0]

    def restore(self, store, levels: int) -> Tuple[np.ndarray, Keyframe]:
        """``(input image, Keyframe)``: the live ones, or for a retired keyframe
        the stored image and primitives at its final pose (the
        :class:`Keyframe` built again with ``levels`` pyramid levels: equal to
        the one it had)."""
        if self._final is None:
            return self.image, self.keyframe
        image, prims = store.get(self.index)
        if self._log_scale_shift != 0.0:
            prims = prims.with_log_scales(prims.log_scales + self._log_scale_shift)
        return image, Keyframe.build(image, prims, self._final[0], levels, self._final[2])

    def correct(self, T_world_kf: np.ndarray, scale: float) -> None:
        """Apply a loop correction (:class:`spgeo.loop.LoopCorrection`): the new
        rigid pose and every depth multiplied by ``scale`` (log-scales ``+= log
        scale``).  A retired keyframe keeps the shift and applies it when read
        back (:meth:`restore`); its stored file is not rewritten."""
        shift = float(np.log(scale))
        T = np.array(T_world_kf, dtype=float)
        if self._final is not None:
            self._final = (T, self._final[1] * float(scale), self._final[2])
            self._log_scale_shift += shift
            return
        prims = self.keyframe.primitives
        self.keyframe = self.keyframe.rebuilt(prims.with_log_scales(prims.log_scales + shift), T)

    def replace_state(self, keyframe: Keyframe, store) -> None:
        """Take the pose and primitives of ``keyframe`` (this keyframe rebuilt
        with new shapes and pose, e.g. by the global bundle adjustment: same
        image and primitive pixels).  A live keyframe keeps it as its
        ``keyframe``; a retired one rewrites its primitives in ``store`` (a
        :class:`~spgeo.vo.keyframe_store.KeyframeStore`; any loop-closure shift
        is then part of them) and keeps the new pose and median depth."""
        if self._final is None:
            self.keyframe = keyframe
            return
        image, _ = store.get(self.index)
        store.put(self.index, image, keyframe.primitives)
        self._final = (np.array(keyframe.T_world_kf, dtype=float), float(keyframe.median_depth),
                       self._final[2])
        self._log_scale_shift = 0.0


@dataclass
class SupportCandidate:
    """A frame tracked against the latest keyframe (supporting-frame candidate):
    its image, ``T_kf_frame`` (4x4) and affine brightness ``(a, b)``."""

    frame: int
    image: np.ndarray
    T_kf_frame: np.ndarray
    brightness: np.ndarray


# ------------------------------------------------------------ shared graph building
# The window smoother and the global bundle adjustment (spgeo.vo.global_ba) build
# keyframe variables and photometric factor groups with these functions only.
def shape_values(keyframe: Keyframe, primitive_model: str) -> np.ndarray:
    """``(N, dim)`` shape variables of a keyframe's primitives: ``(N, 1)``
    log-scales, or with ``primitive_model == "planar"`` the ``(N, 3)``
    inverse-depth planes ``(a, b, c)`` of :meth:`PrimitiveSet.fit_planes`."""
    prims = keyframe.primitives
    if primitive_model == "planar":
        return prims.fit_planes()
    return prims.log_scales.reshape(-1, 1)


def with_shape_values(keyframe: Keyframe, thetas: np.ndarray, primitive_model: str,
                      T_world_kf: np.ndarray) -> Keyframe:
    """The keyframe rebuilt at pose ``T_world_kf`` (4x4 camera-to-world) with
    the shape variables ``thetas`` (as :func:`shape_values` returns them)."""
    prims = keyframe.primitives
    if primitive_model == "planar":
        prims = prims.with_planes(thetas)[0]
    else:
        prims = prims.with_log_scales(np.asarray(thetas)[:, 0])
    return keyframe.rebuilt(prims, T_world_kf)


def mapping_pixels(config: OdometryConfig, ref: MapKeyframe):
    """Mapping pixels of a (live) keyframe: ``(entries, compact ids, primitive
    index, reference intensities)`` or None when no primitive has enough
    pixels: the pixels of level ``map_level``; with ``map_pixel_fraction < 1``
    its highest-gradient fraction (at least ``min_level_pixels`` per
    primitive).  Cached in ``ref.map_pixels`` (mapping changes scales and pose,
    never pixels or image)."""
    cfg = config
    if ref.map_pixels is not None:
        return ref.map_pixels[0]
    data = ref.keyframe.level_data(cfg.map_level, 1, cfg.tracker.min_level_pixels, None)
    out = None
    if data.prim_index.size:
        entries, ids, ref_int = data.entries, data.ids, data.ref_intensity
        if cfg.map_pixel_fraction < 1.0:
            # central differences, as the factors' bilinear image derivatives
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
            keep = (g >= thr) | (rank < cfg.tracker.min_level_pixels)
            entries, ids, ref_int = entries[keep], ids[keep], ref_int[keep]
        out = (entries, ids, data.prim_index, ref_int)
    ref.map_pixels = (out,)
    return out


def pair_factor_group(config: OdometryConfig, ref: MapKeyframe, tgt_key: int,
                      tgt_image: np.ndarray, tgt_camera: PinholeCamera,
                      bkey: int) -> Optional[PhotometricFactorGroup]:
    """The photometric factors of ``ref``'s primitives (its :func:`mapping_pixels`)
    observed in a target: pose key ``tgt_key``, grey image ``tgt_image`` (H, W)
    of camera ``tgt_camera`` (level ``map_level``), brightness key ``bkey``.
    None when ``ref`` has no mapping pixel."""
    sel = mapping_pixels(config, ref)
    if sel is None:
        return None
    entries, ids, prim_index, ref_int = sel
    prims = ref.keyframe.primitives
    rays = prims.camera.rays().reshape(-1, 3)[prims.pixels[entries]]
    shape = (PlanarShape(rays) if config.primitive_model == "planar"
             else ScaledShape(rays, prims.log_depth[entries]))
    counts = np.bincount(ids, minlength=prim_index.size)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    keys = [kf_scale_key(ref.index, i) for i in prim_index]
    return PhotometricFactorGroup(kf_pose_key(ref.index), tgt_key, keys, shape, offsets,
                                  ref_int, tgt_image, tgt_camera, bkey,
                                  config.tracker.photometric, n_pixels=counts.astype(float),
                                  chunk=max(1, config.map_chunk // shape.dim))


def add_keyframe_variables(batch: "FactorBatch", kf: MapKeyframe, config: OdometryConfig,
                           prior_weights: Optional[np.ndarray] = None) -> None:
    """A (live) keyframe's pose and shape variables at their current values,
    with the shapes' priors (weights ``prior_weights`` (N,), default
    ``kf.prior_weights``, else ``scale_prior_weight``; planar: the slope prior
    too); timestamps ``kf.index``."""
    batch.insert(kf_pose_key(kf.index), gtsam.Pose3(kf.keyframe.T_world_kf), kf.index)
    th = shape_values(kf.keyframe, config.primitive_model)
    pw = prior_weights if prior_weights is not None else kf.prior_weights
    if pw is None:
        pw = np.full(th.shape[0], config.scale_prior_weight)
    for i in range(th.shape[0]):
        key = kf_scale_key(kf.index, i)
        batch.insert(key, th[i].copy(), kf.index)
        if config.primitive_model == "planar":
            batch.graph.add(planar_slope_prior(key, float(th[i, 2]), PLANAR_SLOPE_SIGMA,
                                               1.0 / np.sqrt(pw[i]), slope=th[i, :2]))
        else:
            batch.graph.add(log_scale_prior(key, float(th[i, 0]), pw[i]))


def add_factor_group(batch: "FactorBatch", group: Optional[PhotometricFactorGroup], bkey: int,
                     b0, t: int, groups: List[PhotometricFactorGroup]) -> int:
    """A factor group (None: nothing) with its brightness variable (initial
    ``b0``, timestamp ``t``) and prior, appended to ``groups``; its factor count."""
    if group is None:
        return 0
    for f in group.factors:
        batch.graph.add(f)
    groups.append(group)
    batch.insert(bkey, np.asarray(b0, dtype=float), t)
    batch.graph.add(brightness_prior(bkey, BRIGHTNESS_PRIOR_SIGMA))
    return len(group)


def link_keyframe_pair(batch: "FactorBatch", config: OdometryConfig, a: MapKeyframe,
                       b: MapKeyframe, t: int, groups: List[PhotometricFactorGroup]) -> int:
    """Photometric factors between two live keyframes in both directions (a's
    primitives in b's image and b's in a's, level ``map_level``), each
    direction with its brightness (:func:`kf_brightness_key`, initial 0,
    timestamp ``t``); the groups go to ``groups``.  Returns the factor count."""
    lvl = config.map_level
    n = 0
    for ref, tgt in ((a, b), (b, a)):
        bkey = kf_brightness_key(ref.index, tgt.index)
        g = pair_factor_group(config, ref, kf_pose_key(tgt.index),
                              tgt.keyframe.pyramid.images[lvl],
                              tgt.keyframe.pyramid.cameras[lvl], bkey)
        n += add_factor_group(batch, g, bkey, np.zeros(2), t, groups)
    return n


class WindowMapper:
    """The sliding-window smoother of one :class:`~spgeo.vo.Odometry` (module
    docstring).

    Attributes:
        smoother: the ``gtsam.BatchFixedLagSmoother`` (replaced by :meth:`reset`).
        support_pose: frame number -> smoothed ``T_world_frame`` of a
            supporting frame.
        reports: one dict per mapped keyframe (factor counts, seconds, ...).
    """

    def __init__(self, config: OdometryConfig) -> None:
        self.config = config
        self.smoother = self.new_smoother()
        self._groups: List[PhotometricFactorGroup] = []     # alive while in the smoother
        self._support_frames: List[int] = []
        self.support_pose: Dict[int, np.ndarray] = {}
        self.reports: List[dict] = []

    def new_smoother(self) -> gtsam.BatchFixedLagSmoother:
        """An empty smoother with the configured LM parameters and lag."""
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(int(self.config.map_iterations))
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
            self._adopt(kf)
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

    def _adopt(self, kf: MapKeyframe) -> None:
        """Give a keyframe the configured pixel selection (rebuilt when it
        has another one; its cached mapping pixels are dropped then)."""
        sel = self.config.selection
        if kf.keyframe.selection != sel:
            k = kf.keyframe
            kf.keyframe = Keyframe.build(kf.image, k.primitives, k.T_world_kf,
                                         self.config.keyframe_levels, sel)
            kf.map_pixels = None

    def _update(self, kfs: List[MapKeyframe], candidates: Sequence[SupportCandidate],
                segment: int) -> None:
        """One smoother update with the newest keyframe ``kfs[-1]``; raises
        :class:`_UpdateFailed` when gtsam raises."""
        new, prev = kfs[-1], kfs[-2]
        batch = FactorBatch()
        if len(kfs) == 2:
            self._add_keyframe(batch, prev)
            batch.graph.add(pose_gauge_prior(kf_pose_key(prev.index), prev.keyframe.T_world_kf,
                                             GAUGE_SIGMA))
        self._add_keyframe(batch, new)
        n_pair = self._link_keyframes(batch, prev, new)
        sel_new = self._map_pixels(new)
        n_empty = len(new.keyframe.primitives) - (0 if sel_new is None else sel_new[2].size)
        chosen = self._choose_support(candidates)
        n_sup = self._add_support(batch, prev, chosen)
        est, secs = self._solve(batch)
        self._refresh(est, kfs)
        alive = [est.exists(g.ref_key) and est.exists(g.tgt_key) for g in self._groups]
        release_groups([g for g, a in zip(self._groups, alive) if not a])
        self._groups = [g for g, a in zip(self._groups, alive) if a]
        self.reports.append({"keyframe": new.index, "segment": segment,
                             "factors_keyframe_pairs": n_pair, "factors_support": n_sup,
                             "support_frames": [c.frame for c in chosen],
                             "primitives_without_pixels": int(n_empty),
                             "seconds": secs, "keys_in_window": int(est.size())})
        log.debug("mapping kf %d: %d + %d factors, %.2f s", new.index, n_pair, n_sup, secs)

    def _add_keyframe(self, batch: "FactorBatch", kf: MapKeyframe) -> None:
        """A keyframe's pose and shape variables, with the shapes' priors."""
        add_keyframe_variables(batch, kf, self.config)

    def _add_group(self, batch: "FactorBatch", group: Optional[PhotometricFactorGroup],
                   bkey: int, b0, t: int) -> int:
        """A factor group with its brightness variable and prior; its factor count."""
        return add_factor_group(batch, group, bkey, b0, t, self._groups)

    def _link_keyframes(self, batch: "FactorBatch", prev: MapKeyframe, new: MapKeyframe) -> int:
        """Photometric factors of the new keyframe pair, both directions."""
        return link_keyframe_pair(batch, self.config, prev, new, new.index, self._groups)

    def _choose_support(self, candidates: Sequence[SupportCandidate]) -> List[SupportCandidate]:
        """Supporting frames of the previous keyframe: evenly spaced among its tracked frames."""
        n_support = self.config.n_support
        if n_support > 0 and candidates:
            pick = np.unique(np.round(np.linspace(0, len(candidates) - 1,
                                                  min(n_support, len(candidates)))).astype(int))
            return [candidates[i] for i in pick]
        return []

    def _add_support(self, batch: "FactorBatch", prev: MapKeyframe,
                     chosen: Sequence[SupportCandidate]) -> int:
        """The supporting frames' poses and their factors from ``prev``."""
        lvl = self.config.map_level
        n_sup = 0
        for c in chosen:
            pkey = support_pose_key(c.frame)
            pyr = prev.keyframe.frame_pyramid(c.image, lvl + 1)
            T_w = prev.keyframe.T_world_kf @ c.T_kf_frame
            batch.insert(pkey, gtsam.Pose3(T_w), prev.index)
            bkey = _support_brightness_key(c.frame)
            g = self._group(prev, pkey, pyr.images[lvl], pyr.cameras[lvl], bkey)
            n_sup += self._add_group(batch, g, bkey, c.brightness, prev.index)
            self._support_frames.append(c.frame)
        return n_sup

    def _solve(self, batch: "FactorBatch"):
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
            if not est.exists(kf_pose_key(j)):
                continue
            T = est.atPose3(kf_pose_key(j)).matrix()
            n_s = len(kf.keyframe.primitives)
            th = np.array([est.atVector(kf_scale_key(j, i)) for i in range(n_s)])
            if not (np.all(np.isfinite(T)) and np.all(np.isfinite(th))):
                log.warning("mapping produced non-finite values for keyframe %d; kept", j)
                continue
            kf.keyframe = with_shape_values(kf.keyframe, th, self.config.primitive_model, T)
        for f in self._support_frames[-(self.config.window + 1) * max(self.config.n_support, 1):]:
            key = support_pose_key(f)
            if est.exists(key):
                T = est.atPose3(key).matrix()
                if np.all(np.isfinite(T)):
                    self.support_pose[f] = T


class FactorBatch:
    """New factors, values and key timestamps: of one smoother update, or (the
    timestamps unused) a whole graph (:mod:`spgeo.vo.global_ba`)."""

    def __init__(self) -> None:
        self.graph = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.stamps = gtsam.FixedLagSmootherKeyTimestampMap()

    def insert(self, key: int, value, t: int) -> None:
        """A new variable and its smoother timestamp ``t`` (a keyframe index)."""
        self.values.insert(key, value)
        self.stamps.insert((key, float(t)))


class _UpdateFailed(RuntimeError):
    """A smoother update raised (message: :func:`~spgeo.sfm.graph.gtsam_error_line`)."""
