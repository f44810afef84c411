"""Window mapping of the VO: the GTSAM ``BatchFixedLagSmoother`` over keyframes.

A :class:`WindowMapper` owns the smoother (Levenberg-Marquardt), its keys, the
photometric factor groups alive in it and the supporting frames' smoothed
poses.  Variables: keyframe poses, per-keyframe primitive shape variables
(log-scales, or inverse-depth planes with ``primitive_model="planar"``),
supporting-frame poses and an affine brightness per directed (reference,
target) pair.  Each new keyframe is linked to the previous one by photometric
factors in both directions (and to up to ``covisible_links`` older window
keyframes that share enough of its view), and the previous keyframe to up to ``n_support``
supporting non-keyframes tracked against it (evenly spaced; paper: 4), whose
poses are optimised too.  One
:class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` per primitive
and pair, built at pyramid level ``map_level``; the factors of a pair are
evaluated together (:class:`~spgeo.factors.photometric.PhotometricFactorGroup`,
identical values, one vectorised pass).  The first keyframe's pose has a tight
gauge prior; every shape variable a weak prior (weight ``scale_prior_weight``)
to its initial value; a new keyframe's primitives whose scale was rendered
from the map (or, with a depth-using front-end, all of them) get the stronger
``render_prior_weight``: the render is a measurement of their scale (after a
pure rotation the photometric factors between the two keyframes carry no
parallax).  Optionally (``kf_depth_link_sigma``) a
:class:`~spgeo.factors.depth_consistency.DepthConsistencyFactor` also ties the
new keyframe's mean depth to where the previous keyframe's surface is.
Smoother timestamps are keyframe indices (a supporting frame carries its
keyframe's) and the lag keeps ``window`` keyframes: older keys are
*marginalised* (their information stays as a linear prior), not dropped.
After each update the window's :class:`~spgeo.vo.tracking.Keyframe` objects
are rebuilt from the smoother's estimate.

With ``OdometryConfig.pixel_budget`` the keyframes entering the window take
the tracker's pixel selection (:mod:`spgeo.vo.pixels`); with
``map_pixel_budget`` the factors use the pixels of ``map_level`` selected
with that budget (``Keyframe.level_data``, as the tracker's).  Primitives left
without pixels have no photometric factor, are held by their priors and are
counted in the report (``primitives_without_pixels``).

A failed update (a gtsam ``RuntimeError``, e.g. an indeterminant system)
restarts the window from the last two keyframes once; if the restarted
two-keyframe window fails too, the keyframe poses stay as tracked.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.depth_consistency import DepthConsistencyFactor
from ..factors.photometric import PhotometricFactorGroup, PlanarShape, ScaledShape
from ..factors.priors import brightness_prior, log_scale_prior, planar_slope_prior, pose_gauge_prior
from ..geometry import invert_pose
from ..primitives import PrimitiveSet
from ..sfm.graph import gtsam_error_line
from .config import PRIMITIVE_MODELS, OdometryConfig
from .tracking import Keyframe, decision_stride, valid_fraction

__all__ = ["WindowMapper", "MapKeyframe", "SupportCandidate", "kf_pose_key", "kf_scale_key",
           "kf_brightness_key", "support_pose_key", "apply_primitive_model"]

log = logging.getLogger(__name__)

_MAX_PRIMS = 1_000_000


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
    :class:`~spgeo.vo.tracking.Keyframe` (pose and primitives)."""

    index: int          # keyframe number
    frame: int          # frame number
    image: np.ndarray
    keyframe: Keyframe
    segment: int = 0
    map_pixels: Optional[tuple] = None   # cached mapping pixels (pixels and image never change)
    prior_weights: Optional[np.ndarray] = None   # (N,) weights of the shape priors


@dataclass
class SupportCandidate:
    """A frame tracked against the latest keyframe (supporting-frame candidate):
    its image, ``T_kf_frame`` (4x4) and affine brightness ``(a, b)``."""

    frame: int
    image: np.ndarray
    T_kf_frame: np.ndarray
    brightness: np.ndarray


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
        p.setRelativeErrorTol(float(self.config.map_relative_tol))
        p.setAbsoluteErrorTol(1e-9)
        p.setlambdaUpperBound(float(self.config.map_lambda_max))
        p.setlambdaInitial(float(self.config.map_lambda_initial))
        return gtsam.BatchFixedLagSmoother(float(self.config.window) - 0.5, p)

    def reset(self) -> None:
        """Empty smoother and no factor group (a new map segment)."""
        self.smoother = self.new_smoother()
        self._groups = []

    def estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window)."""
        return self.smoother.calculateEstimate()

    # ------------------------------------------------------------ factors
    @property
    def _planar(self) -> bool:
        return self.config.primitive_model == "planar"

    def _shape_values(self, kf: MapKeyframe) -> np.ndarray:
        """(N, dim) initial shape variables of a keyframe's primitives."""
        prims = kf.keyframe.primitives
        if self._planar:
            return prims.fit_planes()
        return prims.log_scales.reshape(-1, 1)

    def _shape_model(self, prims: PrimitiveSet, entries: np.ndarray, rays: np.ndarray):
        return PlanarShape(rays) if self._planar else ScaledShape(rays, prims.log_depth[entries])

    def depth_link(self, ref: MapKeyframe, tgt: MapKeyframe) -> Optional[DepthConsistencyFactor]:
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

    def _group(self, ref: MapKeyframe, tgt_key: int, tgt_image: np.ndarray,
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
                                      chunk=max(1, cfg.map_chunk // shape.dim))

    def _covisible(self, older: Sequence[MapKeyframe], new: MapKeyframe) -> List[MapKeyframe]:
        """Up to ``covisible_links`` of the ``older`` keyframes still in the
        window whose primitive pixels project into ``new``'s image for at
        least ``covisible_min_overlap`` of them, the largest overlap first."""
        cfg = self.config
        if cfg.covisible_links <= 0 or not older:
            return []
        est = self.estimate()
        stride = decision_stride(new.keyframe.camera.width, cfg.tracker.decision_width)
        scored = []
        for kf in older[-cfg.window:]:
            if not est.exists(kf_pose_key(kf.index)):
                continue
            frac = valid_fraction(kf.keyframe, new.keyframe.T_world_kf,
                                  cfg.photometric.min_depth, stride)
            if frac >= cfg.covisible_min_overlap:
                scored.append((frac, kf.index, kf))
        scored.sort(key=lambda x: (-x[0], -x[1]))
        return [kf for _, _, kf in scored[:cfg.covisible_links]]

    def _map_pixels(self, ref: MapKeyframe):
        """Mapping pixels of a keyframe: ``(entries, compact ids, primitive
        index, reference intensities)``: the map level's pixels (with
        ``map_pixel_budget`` the selected ones); with ``map_pixel_fraction < 1`` the
        highest-gradient fraction of the map level's pixels (at least
        ``min_level_pixels`` per primitive).  Cached per keyframe (mapping
        changes its scales and pose, never its pixels or image)."""
        cfg = self.config
        if ref.map_pixels is not None:
            return ref.map_pixels[0]
        data = ref.keyframe.level_data(cfg.map_level, cfg.map_stride, cfg.min_level_pixels,
                                       cfg.map_selection)
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
                keep = (g >= thr) | (rank < cfg.min_level_pixels)
                entries, ids, ref_int = entries[keep], ids[keep], ref_int[keep]
            out = (entries, ids, data.prim_index, ref_int)
        ref.map_pixels = (out,)
        return out

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
                    self.smoother = self.new_smoother()
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
                                         self.config.levels, sel)
            kf.map_pixels = None

    def _update(self, kfs: List[MapKeyframe], candidates: Sequence[SupportCandidate],
                segment: int) -> None:
        """One smoother update with the newest keyframe ``kfs[-1]``; raises
        :class:`_UpdateFailed` when gtsam raises."""
        cfg = self.config
        lvl = cfg.map_level
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()

        def stamp(key: int, t: int) -> None:
            stamps.insert((key, float(t)))

        def add_kf(kf: MapKeyframe) -> None:
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
                                                 1.0 / np.sqrt(pw[i]), slope=th[i, :2]))
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

        new, prev = kfs[-1], kfs[-2]
        k = new.index
        if len(kfs) == 2:
            add_kf(prev)
            graph.add(pose_gauge_prior(kf_pose_key(prev.index), prev.keyframe.T_world_kf,
                                       cfg.gauge_sigma))
        add_kf(new)
        n_pair = n_cov = 0
        for ref, tgt in ((prev, new), (new, prev)):
            bkey = kf_brightness_key(ref.index, tgt.index)
            g = self._group(ref, kf_pose_key(tgt.index), tgt.keyframe.pyramid.images[lvl],
                            tgt.keyframe.pyramid.cameras[lvl], bkey)
            n_pair += add_group(g, bkey, np.zeros(2), k)
        for old in self._covisible(kfs[:-2], new):
            for ref, tgt in ((old, new), (new, old)):
                bkey = kf_brightness_key(ref.index, tgt.index)
                g = self._group(ref, kf_pose_key(tgt.index), tgt.keyframe.pyramid.images[lvl],
                                tgt.keyframe.pyramid.cameras[lvl], bkey)
                n_cov += add_group(g, bkey, np.zeros(2), k)
        sel_new = self._map_pixels(new)
        n_empty = len(new.keyframe.primitives) - (0 if sel_new is None else sel_new[2].size)
        link = self.depth_link(prev, new)
        if link is not None:
            graph.add(link.factor)
        # supporting frames of the previous keyframe: evenly spaced among its tracked frames
        chosen = []
        if cfg.n_support > 0 and candidates:
            pick = np.unique(np.round(np.linspace(0, len(candidates) - 1,
                                                  min(cfg.n_support, len(candidates)))).astype(int))
            chosen = [candidates[i] for i in pick]
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
            raise _UpdateFailed(gtsam_error_line(exc)) from exc
        est = self.smoother.calculateEstimate()
        secs = time.perf_counter() - t
        self._refresh(est, kfs)
        self._groups = [g for g in self._groups if est.exists(g.ref_key) and est.exists(g.tgt_key)]
        self.reports.append({"keyframe": k, "segment": segment,
                             "factors_keyframe_pairs": n_pair, "factors_covisible": n_cov,
                             "factors_support": n_sup,
                             "depth_link_correspondences": 0 if link is None else link.n,
                             "support_frames": [c.frame for c in chosen],
                             "primitives_without_pixels": int(n_empty),
                             "seconds": secs, "keys_in_window": int(est.size())})
        log.debug("mapping kf %d: %d + %d factors, %.2f s", k, n_pair, n_sup, secs)

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
            prims = kf.keyframe.primitives
            if self._planar:
                prims = prims.with_planes(th)[0]
            else:
                prims = prims.with_log_scales(th[:, 0])
            kf.keyframe = kf.keyframe.rebuilt(prims, T)
        for f in self._support_frames[-(self.config.window + 1) * max(self.config.n_support, 1):]:
            key = support_pose_key(f)
            if est.exists(key):
                T = est.atPose3(key).matrix()
                if np.all(np.isfinite(T)):
                    self.support_pose[f] = T


class _UpdateFailed(RuntimeError):
    """A smoother update raised (message: :func:`~spgeo.sfm.graph.gtsam_error_line`)."""
