"""Few-view structure from motion on SuperPrimitives (docs/design.md §4, §5).

A reference image is primified; its primitives' log-scales and the poses of
1..n *unposed* supporting views (plus an affine brightness per view) are
estimated by photometric alignment: one :class:`PrimitivePhotometricFactor`
per (primitive, view) in a GTSAM graph (evaluated in chunks of primitives by
:class:`PhotometricFactorGroup`: the same cost), solved by Levenberg-Marquardt
coarse-to-fine over a Gaussian pyramid (geometry stays at the reference's
resolution; factors are rebuilt per level).

Gauge: a tight prior on the reference pose (identity) and a weak prior on
every log-scale (the paper's 1e-5) that fixes the global scale, which
monocular images cannot observe: depths are in metres *up to one unknown
global scale* (exactly so when all scales start at 0, the paper's default).
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Union

import cv2
import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.photometric import PlanarShape
from ..factors.photometric_group import PhotometricFactorGroup
from ..frontend import FrontEndConfig, PrimitiveFrontEnd, make_frontend
from ..geometry import invert_pose, rotation_angle_deg
from ..images import gaussian_pyramid, to_float_image, to_gray
from ..primitives import PointCloud, PrimitiveSet
from ..validation import InputError, check_camera
from .config import SfMConfig
from .graph import (brightness_key, build_graph, gauge_free_scale_std, gtsam_error_line,
                    hold_translation_and_shape, pose_key, scale_key)
from .init import twoview_initialisation
from .orientation import choose_planar_orientations

__all__ = ["SfMResult", "few_view_sfm"]


log = logging.getLogger(__name__)


@dataclass
class SfMResult:
    """Output of :func:`few_view_sfm`.

    Attributes:
        status: ``"ok"`` or the first problem found, in this order:
            ``"diverged"`` (non-finite result), ``"unverified"`` (the two-view
            feature check found too few matches or a degenerate geometry for a
            view, which then started at identity: often no overlap, and the
            photometric result is not trusted), ``"low_parallax"``,
            ``"low_overlap"``.
        view_status: status per supporting view.
        T_ref_view: 4x4 pose of each supporting view in the reference camera
            (camera-to-reference), translation in the map's (unknown) scale.
        primitives: the reference primitives with solved log-scales (planar
            model: the planes' depths are baked into ``log_depth``).
        depth: (H, W) reference depth (metres up to the global scale), NaN where
            no reported primitive covers the pixel (see ``unconstrained``).
        camera: the reference camera at the working resolution.
        log_scale_std: (N,) gauge-free marginal std of each primitive's
            log-scale: conditioned on the mean log-scale, since the global scale
            is fixed only by the weak prior and its (large) variance is shared by
            every primitive (scaled model; NaN otherwise or when marginals are
            off/failed).
        unconstrained: indices of primitives whose depth the views do not
            support; they are in neither ``depth`` nor :meth:`point_cloud`.
            These are: every primitive when no view has parallax (each
            ``view_status`` is ``"low_parallax"`` or ``"diverged"``: the
            structure is not observable), or when the status is not ``"ok"``
            and the marginals failed (an indeterminate system:
            ``report["marginals_error"]``); otherwise those whose log-scale
            only the prior constrains (marginal std over half the prior's: no
            view sees them usefully) or whose ``log_scale_std`` exceeds
            ``config.max_log_scale_std`` (needs ``config.marginals``).
            ``primitives`` keeps every primitive at its solved (for these:
            unsupported) log-scale.
        pose_covariances: 6x6 marginal covariance per view (rotation first,
            gtsam tangent at the estimate), conditioned on the gauge priors.
            Marginals use a per-pixel noise model whose sigma is the robust
            (MAD) std of the photometric residuals at the solution
            (``report["pixel_sigma"]``); pixels are treated as independent, so
            the uncertainties are optimistic where residuals are correlated.
        report: per-level iterations, costs, valid fractions, timings.
    """

    status: str
    view_status: List[str]
    T_ref_view: List[np.ndarray]
    primitives: PrimitiveSet
    depth: np.ndarray
    camera: PinholeCamera
    log_scale_std: np.ndarray
    pose_covariances: List[Optional[np.ndarray]]
    brightness: List[np.ndarray]
    report: dict
    unconstrained: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def supported_primitives(self) -> PrimitiveSet:
        """The primitives that ``depth`` reports (all but ``unconstrained``, in
        order): what a point cloud or a model export of this result may show."""
        keep = np.setdiff1d(np.arange(len(self.primitives)), self.unconstrained)
        return self.primitives.subset(keep)

    def point_cloud(self, image: Optional[np.ndarray] = None) -> PointCloud:
        """Reference-frame point cloud of the solved primitives that ``depth``
        reports: those in ``unconstrained`` and non-finite points are left out
        (an empty cloud when nothing is supported).  ``image``: colours, at
        ``camera``'s size."""
        cloud = self.primitives.point_cloud(image)
        keep = np.all(np.isfinite(cloud.points), axis=1)
        if self.unconstrained.size:
            keep &= ~np.isin(cloud.primitive_ids, self.unconstrained)
        return PointCloud(cloud.points[keep], None if cloud.colors is None else cloud.colors[keep],
                          cloud.primitive_ids[keep], cloud.pixels[keep])


def _checked_image(image: np.ndarray, camera: PinholeCamera, name: str) -> np.ndarray:
    """``image`` as float [0, 1]; :class:`InputError` naming ``name`` unless it is a
    finite image of ``camera``'s size (:func:`~spgeo.images.to_float_image`)."""
    if image is None:
        raise InputError(f"{name} is None, expected an image of {camera.width}x{camera.height}")
    try:
        return to_float_image(camera.check_image(image, name))
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(name) else f"{name}: {msg}") from None


def _check_inputs(ref_image, view_images, camera, init_T_ref_view) -> List[np.ndarray]:
    """The supporting images as a list, after checking every input of
    :func:`few_view_sfm` (its *Raises*)."""
    check_camera(camera, "few_view_sfm camera")
    if isinstance(view_images, np.ndarray) and (view_images.ndim == 2 or (
            view_images.ndim == 3 and view_images.shape[:2] == camera.shape)):
        raise InputError(f"few_view_sfm: view_images is one image array of shape "
                         f"{view_images.shape}; expected a sequence of images, e.g. [image]")
    views = list(view_images)
    if not views:
        raise InputError("few_view_sfm needs at least one supporting view (view_images is empty)")
    _checked_image(ref_image, camera, "reference image")
    for j, im in enumerate(views):
        _checked_image(im, camera, f"view {j + 1}")
    if init_T_ref_view is not None:
        if len(init_T_ref_view) != len(views):
            raise InputError(f"few_view_sfm: init_T_ref_view has {len(init_T_ref_view)} poses "
                             f"for {len(views)} views")
        for j, T in enumerate(init_T_ref_view):
            T = np.asarray(T)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise InputError(f"few_view_sfm: init_T_ref_view[{j}] must be a finite 4x4 "
                                 f"pose, got shape {T.shape}"
                                 + ("" if T.shape != (4, 4) else " with NaN or inf"))
    return views


def _prepare_image(image: np.ndarray, camera: PinholeCamera, work_cam: PinholeCamera,
                   name: str) -> np.ndarray:
    img = _checked_image(image, camera, name)
    grey = to_gray(img)
    if work_cam.shape != camera.shape:
        grey = cv2.resize(grey, work_cam.size, interpolation=cv2.INTER_AREA)
    return grey.astype(np.float32)


def few_view_sfm(ref_image: np.ndarray, view_images: Sequence[np.ndarray], camera: PinholeCamera,
                 frontend: Union[None, str, PrimitiveFrontEnd, PrimitiveSet] = None,
                 config: SfMConfig = SfMConfig(), ref_depth: Optional[np.ndarray] = None,
                 init_T_ref_view: Optional[Sequence[np.ndarray]] = None) -> SfMResult:
    """Estimate the poses of unposed views and the reference's dense depth.

    Args:
        ref_image: reference image (H, W[, 3]), uint8 or float [0, 1].
        view_images: 1..n supporting images of the same size and camera.
        camera: intrinsics of all images (undistorted).
        frontend: a :class:`PrimitiveFrontEnd`, a front-end name (default
            ``"classical"`` at 320x240), or ready :class:`PrimitiveSet` of the
            reference image.
        config: :class:`SfMConfig`.
        ref_depth: depth of the reference, only for depth-using (oracle /
            RGB-D) front-ends; its scales are discarded unless
            ``config.reset_scales`` is False.
        init_T_ref_view: optional initial poses (e.g. from
            :func:`spgeo.twoview.estimate_relative_pose`), one finite 4x4 per
            view; identity by default.
    Returns:
        :class:`SfMResult` (check ``status``; a flagged result reports no depth
        the views do not support: ``SfMResult.unconstrained``).
    Raises:
        InputError: (a ``ValueError``) naming the input: no supporting view,
            one image array passed as ``view_images``, an image (``"reference
            image"``, ``"view j"``) of another size than ``camera``, with NaN /
            inf, out-of-range values or an unsupported dtype, or
            ``init_T_ref_view`` of the wrong length, shape or with NaN.
        TypeError: ``camera`` is not a :class:`PinholeCamera`.
    """
    t_start = time.perf_counter()
    views = _check_inputs(ref_image, view_images, camera, init_T_ref_view)
    # ---- primitives of the reference
    if isinstance(frontend, PrimitiveSet):
        prims = frontend
    else:
        fe = frontend if isinstance(frontend, PrimitiveFrontEnd) else make_frontend(
            frontend or "classical", FrontEndConfig(working_size=(320, 240)))
        prims = fe.primify(ref_image, camera, ref_depth if fe.uses_depth else None)
    if len(prims) == 0:
        raise ValueError("the front-end produced no primitive")
    cam = prims.camera
    if config.reset_scales:
        prims = prims.with_log_scales(np.zeros(len(prims)))
    t_front = time.perf_counter()
    ref_grey = _prepare_image(ref_image, camera, cam, "reference image")
    view_greys = [_prepare_image(im, camera, cam, f"view {j + 1}") for j, im in enumerate(views)]
    ref_pyr = gaussian_pyramid(ref_grey, cam, config.levels)
    view_pyrs = [gaussian_pyramid(g, cam, config.levels) for g in view_greys]
    n_levels = len(ref_pyr)
    rays_all = cam.rays().reshape(-1, 3)[prims.pixels]

    # ---- initial values
    init_report: Dict[str, object] = {"method": "given" if init_T_ref_view is not None
                                      else config.init}
    if init_T_ref_view is None and config.init == "twoview":
        init_T_ref_view, prims = twoview_initialisation(ref_image, views, camera, prims, init_report)
    values = gtsam.Values()
    values.insert(pose_key(0), gtsam.Pose3())
    for j in range(len(views)):
        T0 = np.eye(4) if init_T_ref_view is None else np.asarray(init_T_ref_view[j], float)
        values.insert(pose_key(j + 1), gtsam.Pose3(T0))
        if config.brightness:
            values.insert(brightness_key(j + 1), np.zeros(2))
    if config.shape_model == "scaled":
        for i in range(len(prims)):
            values.insert(scale_key(i), np.array([prims.log_scales[i]]))
    else:
        for i in range(len(prims)):
            values.insert(scale_key(i), PlanarShape.fronto_parallel(np.exp(prims.log_scales[i])))

    report: Dict[str, object] = {"levels": [], "n_primitives": len(prims),
                                 "n_views": len(views), "shape_model": config.shape_model,
                                 "init": init_report}
    builders: List[PhotometricFactorGroup] = []
    stages = [(lvl, False) for lvl in reversed(range(n_levels))]
    any_identity = init_T_ref_view is None or any(
        np.allclose(T, np.eye(4)) for T in init_T_ref_view)
    if config.rotation_first and any_identity:
        stages.insert(0, (n_levels - 1, True))
    orientations = None     # planar slope priors: fronto-parallel until a choice is made
    for lvl, rotation_only in stages:
        graph, builders = build_graph(prims, rays_all, ref_pyr, view_pyrs, lvl, values, config,
                                      orientations)
        if rotation_only:
            hold_translation_and_shape(graph, values, len(views), len(prims))
        params = gtsam.LevenbergMarquardtParams()
        iters = config.max_iterations[min(n_levels - 1 - lvl, len(config.max_iterations) - 1)]
        params.setMaxIterations(int(iters))
        params.setlambdaInitial(config.lm_lambda_initial)
        params.setRelativeErrorTol(config.relative_error_tol)
        params.setAbsoluteErrorTol(1e-9)
        t0 = time.perf_counter()
        err0 = graph.error(values)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        values = opt.optimize()
        err1 = graph.error(values)
        report["levels"].append({"level": lvl, "rotation_only": rotation_only,
                                 "factors": graph.size(), "iterations": opt.iterations(),
                                 "initial_cost": err0, "final_cost": err1,
                                 "seconds": time.perf_counter() - t0})
        log.debug("level %d%s: %d factors, %d its, cost %.4g -> %.4g", lvl,
                  " (rotation only)" if rotation_only else "", graph.size(),
                  opt.iterations(), err0, err1)
        if (lvl == 0 and not rotation_only and orientations is None
                and config.shape_model == "planar" and config.orientation_choice):
            values, orientations = choose_planar_orientations(prims, builders, values, report)
            if orientations is not None:
                stages.append((0, False))      # refine once more with the chosen planes
    t_opt = time.perf_counter()

    # ---- results
    T_ref_view = [values.atPose3(pose_key(j + 1)).matrix() for j in range(len(views))]
    brightness = [values.atVector(brightness_key(j + 1)) if config.brightness else np.zeros(2)
                  for j in range(len(views))]
    if config.shape_model == "scaled":
        s = np.array([values.atVector(scale_key(i))[0] for i in range(len(prims))])
        solved = prims.with_log_scales(s)
    else:
        thetas = np.array([values.atVector(scale_key(i)) for i in range(len(prims))])
        rho = np.einsum("kj,kj->k", rays_all, thetas[prims.primitive_ids])
        bad = ~(rho > 1e-9)
        rho = np.where(bad, np.nan, rho)
        logz = -np.log(rho)
        # primitives whose plane goes behind the camera keep their median depth there
        med = np.array([np.nanmedian(logz[a:b]) if np.any(np.isfinite(logz[a:b])) else 0.0
                        for a, b in zip(prims.offsets[:-1], prims.offsets[1:])])
        logz = np.where(np.isfinite(logz), logz, med[prims.primitive_ids])
        solved = PrimitiveSet(cam, prims.pixels, prims.offsets, logz, prims.anchors,
                              scores=prims.scores, normals=prims.normals, meta=prims.meta)
        anchor_ld = logz[np.searchsorted(prims.primitive_ids * cam.width * cam.height + prims.pixels,
                                         np.arange(len(prims)) * cam.width * cam.height + prims.anchors)]
        solved.log_scales = anchor_ld
    depth = solved.depth_map()

    status, view_status, valid_frac = _assess(solved, T_ref_view, config, report,
                                              init_report.get("twoview_status"))
    log_std = np.full(len(prims), np.nan)
    prior_only = np.zeros(len(prims), dtype=bool)
    covs: List[Optional[np.ndarray]] = [None] * len(views)
    if config.marginals and status != "diverged":
        try:
            # per-pixel noise model with sigma from the residuals at the solution
            # (robust MAD), so covariances are in physical units
            res_pix = np.concatenate([g.evaluate_at(values)["r"] for g in builders]
                                     ) if builders else np.zeros(0)
            res_pix = res_pix[res_pix != 0]
            sigma = float(1.4826 * np.median(np.abs(res_pix))) if res_pix.size else 0.02
            sigma = max(sigma, 1e-3)
            report["pixel_sigma"] = sigma
            # the gauge prior keeps its strength relative to a median primitive
            prior_w = config.scale_prior_weight * float(np.median(prims.sizes)) / sigma ** 2
            pix_cfg = dataclasses.replace(config, scale_prior_weight=prior_w,
                                          photometric=dataclasses.replace(
                                              config.photometric, normalise="none",
                                              pixel_sigma=sigma))
            mgraph, _ = build_graph(prims, rays_all, ref_pyr, view_pyrs, 0, values, pix_cfg)
            marg = gtsam.Marginals(mgraph, values)
            for j in range(len(views)):
                covs[j] = marg.marginalCovariance(pose_key(j + 1))
            if config.shape_model == "scaled":
                log_std, prior_only = gauge_free_scale_std(marg, len(prims),
                                                            1.0 / np.sqrt(prior_w))
        except RuntimeError as exc:  # indeterminant system: report, do not crash
            report["marginals_error"] = gtsam_error_line(exc)
            log.warning("marginals failed: %s", report["marginals_error"])
    unconstrained = np.flatnonzero(prior_only | (log_std > config.max_log_scale_std))
    no_parallax = all(v in ("low_parallax", "diverged") for v in view_status)
    if no_parallax or (status != "ok" and "marginals_error" in report):
        unconstrained = np.arange(len(solved))    # the views support no depth
    if unconstrained.size:
        keep = np.setdiff1d(np.arange(len(solved)), unconstrained)
        depth = solved.subset(keep).depth_map() if keep.size else np.full(cam.shape, np.nan)
        log.info("%d of %d primitives unconstrained by the views (%s): not in the depth map",
                 unconstrained.size, len(solved), "status " + status if keep.size == 0
                 else f"log-scale std > {config.max_log_scale_std:.2f}")
    report["n_unconstrained"] = int(unconstrained.size)
    report.update({"valid_fraction": valid_frac, "seconds_frontend": t_front - t_start,
                   "seconds_optimise": t_opt - t_front,
                   "seconds_total": time.perf_counter() - t_start,
                   "final_cost": report["levels"][-1]["final_cost"] if report["levels"] else None})
    return SfMResult(status, view_status, T_ref_view, solved, depth, cam, log_std, covs,
                     brightness, report, unconstrained)


def _assess(solved: PrimitiveSet, T_ref_view: List[np.ndarray], config: SfMConfig,
            report: dict, twoview_status: Optional[Sequence[str]] = None):
    """Status flags: diverged (non-finite), unverified, low parallax, low overlap.

    A view the two-view feature check could not pose (too few matches /
    degenerate) most likely shares little with the reference: photometric
    alignment from identity can then "converge" to a wrong pose, so it is
    ``unverified`` rather than ``ok``.
    """
    finite = all(np.all(np.isfinite(T)) for T in T_ref_view) and np.all(
        np.isfinite(solved.log_scales))
    cam = solved.camera
    w = cam.width
    uv = np.stack([solved.pixels % w, solved.pixels // w], -1).astype(float)
    X = cam.unproject(uv, np.exp(solved.scaled_log_depth()))
    med_depth = float(np.median(X[:, 2])) if finite else np.nan
    view_status, valid_frac = [], []
    for j, T in enumerate(T_ref_view):
        if not finite:
            view_status.append("diverged")
            valid_frac.append(0.0)
            continue
        T_v_r = invert_pose(T)
        Y = X @ T_v_r[:3, :3].T + T_v_r[:3, 3]
        uvv, z = cam.project(Y)
        frac = float(np.mean(cam.in_image(uvv) & (z > 0)))
        valid_frac.append(frac)
        parallax = np.linalg.norm(T[:3, 3]) / max(med_depth, 1e-12)
        if twoview_status is not None and twoview_status[j] in ("too_few_matches",
                                                                 "degenerate"):
            view_status.append("unverified")
        elif parallax < config.min_parallax:
            view_status.append("low_parallax")
        elif frac < config.min_valid_fraction:
            view_status.append("low_overlap")
        else:
            view_status.append("ok")
    report["parallax"] = [float(np.linalg.norm(T[:3, 3]) / max(med_depth, 1e-12)) if finite
                          else None for T in T_ref_view]
    report["rotation_deg"] = [rotation_angle_deg(T) if finite else None for T in T_ref_view]
    order = ("diverged", "unverified", "low_parallax", "low_overlap")
    status = next((s for s in order if s in view_status), "ok")
    return status, view_status, valid_frac
