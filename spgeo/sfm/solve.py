"""Few-view structure from motion on SuperPrimitives (docs/design.md §4, §5).

A reference image is primified; its primitives' log-scales and the poses of
1..n *unposed* supporting views (plus an affine brightness per view) are
estimated by photometric alignment: one :class:`PrimitivePhotometricFactor`
per (primitive, view) in a GTSAM graph (evaluated in chunks of primitives by
:class:`PhotometricFactorGroup`: the same cost), solved by Levenberg-Marquardt
coarse-to-fine over a Gaussian pyramid (geometry stays at the reference's
resolution; factors are rebuilt per level).  By default (``SfMConfig.init =
"features"``) the solve starts at a landmark bundle adjustment of all views
(:class:`~spgeo.sfm.landmarks.LandmarkStage`), which then keeps or rejects each
view's photometric pose by its held-out feature matches.

Gauge: a tight prior on the reference pose (identity) and a weak prior on
every log-scale (the paper's 1e-5) that fixes the global scale, which
monocular images cannot observe: depths are in metres *up to one unknown
global scale* (exactly so when all scales start at 0, the paper's default).
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.photometric import PlanarShape
from ..factors.photometric_group import PhotometricFactorGroup, release_groups
from ..factors.priors import pose_gauge_prior
from ..frontend import FrontEndConfig, PrimitiveFrontEnd, make_frontend
from ..graph.builders import build_level_graph, gtsam_error_line, hold_translation_and_shape
from ..graph.keys import brightness_key, pose_key, scale_key
from ..images import gaussian_pyramid, to_float_image, to_gray
from ..primitives import PrimitiveSet
from ..validation import InputError, check_camera
from .config import SfMConfig
from .init import twoview_initialisation
from .landmarks import LandmarkStage
from .orientation import choose_planar_orientations
from .result import SfMResult, assess_result

__all__ = ["few_view_sfm", "SFM_WORKING_SIZE"]

#: ``(width, height)`` of the primitives of a front-end given by name
SFM_WORKING_SIZE = (320, 240)


log = logging.getLogger(__name__)


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


@dataclass
class _Problem:
    """What every stage of :func:`few_view_sfm` reads: the reference primitives
    (replaced once by the two-view initialisation), their working camera, the
    grey pyramids of the reference and the views, and the primitives' pixel rays."""

    prims: PrimitiveSet
    cam: PinholeCamera
    ref_pyr: list
    view_pyrs: list
    rays_all: np.ndarray

    @property
    def n_levels(self) -> int:
        return len(self.ref_pyr)

    @property
    def n_views(self) -> int:
        return len(self.view_pyrs)


def _reference_primitives(ref_image, camera, frontend, config, ref_depth) -> PrimitiveSet:
    """The reference's primitives: ``frontend`` itself when it is a set, else
    the front-end's (``"classical"`` at :data:`SFM_WORKING_SIZE` by default).  ``ValueError``
    when there is none."""
    if isinstance(frontend, PrimitiveSet):
        prims = frontend
    else:
        fe = frontend if isinstance(frontend, PrimitiveFrontEnd) else make_frontend(
            frontend or "classical", FrontEndConfig(working_size=SFM_WORKING_SIZE))
        prims = fe.primify(ref_image, camera, ref_depth if fe.uses_depth else None)
    if len(prims) == 0:
        raise ValueError("the front-end produced no primitive")
    return prims


def _problem(ref_image, views, camera, prims, cam, config) -> _Problem:
    """:class:`_Problem` of ``prims`` (working camera ``cam``): images made grey at
    ``cam``'s size, ``config.levels`` pyramid levels."""
    ref_grey = _prepare_image(ref_image, camera, cam, "reference image")
    view_greys = [_prepare_image(im, camera, cam, f"view {j + 1}") for j, im in enumerate(views)]
    ref_pyr = gaussian_pyramid(ref_grey, cam, config.levels)
    view_pyrs = [gaussian_pyramid(g, cam, config.levels) for g in view_greys]
    rays_all = cam.rays().reshape(-1, 3)[prims.pixels]
    return _Problem(prims, cam, ref_pyr, view_pyrs, rays_all)


def _initial_values(prims: PrimitiveSet, n_views: int, init_T_ref_view, config) -> gtsam.Values:
    """Start values: reference at identity, each view at its initial pose (identity
    when none), brightness 0, log-scales (or fronto-parallel planes) from ``prims``."""
    values = gtsam.Values()
    values.insert(pose_key(0), gtsam.Pose3())
    for j in range(n_views):
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
    return values


def _solve_stage(graph, values: gtsam.Values, config: SfMConfig, lvl: int, n_levels: int,
                 rotation_only: bool, report: dict) -> gtsam.Values:
    """One Levenberg-Marquardt solve of ``graph`` at pyramid level ``lvl`` from
    ``values``; appends the level's entry to ``report["levels"]``."""
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
    return values


def _coarse_to_fine(pb: _Problem, values: gtsam.Values, config: SfMConfig, init_T_ref_view,
                    report: dict, stage: Optional[LandmarkStage] = None
                    ) -> Tuple[gtsam.Values, List[PhotometricFactorGroup]]:
    """Solve level by level, coarsest first: a rotation-only stage first when a
    view starts at identity (``config.rotation_first``), and once more at the
    finest level after the planar orientation choice.  With an active landmark
    ``stage`` (the solve started at its bundle) each registered view keeps the
    photometric pose only where its held-out matches fit it at least as well as the
    bundle's (:meth:`LandmarkStage.choose_poses`); otherwise it takes the bundle's,
    and the finest level solves the scales once more with the poses held.  With
    the 1-DoF model and ``config.depth_stage`` the last stage is
    :func:`_depth_stage`.  Returns the solved values and the factor groups of the
    last stage."""
    builders: List[PhotometricFactorGroup] = []
    n_levels = pb.n_levels
    stages = [(lvl, False) for lvl in reversed(range(n_levels))]
    any_identity = init_T_ref_view is None or any(
        np.allclose(T, np.eye(4)) for T in init_T_ref_view)
    if config.rotation_first and any_identity:
        stages.insert(0, (n_levels - 1, True))
    orientations = None     # planar slope priors: fronto-parallel until a choice is made
    for lvl, rotation_only in stages:
        release_groups(builders)      # the previous stage's (else never freed)
        graph, builders = build_level_graph(pb.prims, pb.rays_all, pb.ref_pyr, pb.view_pyrs, lvl,
                                      values, config, orientations)
        if rotation_only:
            hold_translation_and_shape(graph, values, pb.n_views, len(pb.prims))
        values = _solve_stage(graph, values, config, lvl, n_levels, rotation_only, report)
        if (lvl == 0 and not rotation_only and orientations is None
                and config.shape_model == "planar" and config.orientation_choice):
            values, orientations = choose_planar_orientations(pb.prims, builders, values, report)
            if orientations is not None:
                stages.append((0, False))      # refine once more with the chosen planes
    if stage is not None and stage.active:
        values, held = stage.choose_poses(values, report)
        if held:       # the scales once more at the chosen poses
            release_groups(builders)
            graph, builders = build_level_graph(pb.prims, pb.rays_all, pb.ref_pyr,
                                                pb.view_pyrs, 0, values, config, orientations)
            stage.hold_poses(graph, values)
            values = _solve_stage(graph, values, config, 0, n_levels, False, report)
    if config.shape_model == "scaled" and config.depth_stage:
        release_groups(builders)
        values, builders = _depth_stage(pb, values, config, report)
    return values, builders


def _depth_stage(pb: _Problem, values: gtsam.Values, config: SfMConfig, report: dict
                 ) -> Tuple[gtsam.Values, List[PhotometricFactorGroup]]:
    """The scales once more at the finest level with every pose held, adding the
    :func:`~spgeo.graph.builders.continuity_factors` of the reference's primitives:
    a primitive the views barely constrain takes its neighbours' depth, and the
    poses stay those of the photometric and landmark solve (docs/design.md §5,
    "Depth stage").  Its report entry has ``"depth_stage": True``."""
    graph, builders = build_level_graph(pb.prims, pb.rays_all, pb.ref_pyr, pb.view_pyrs, 0,
                                        values, config, continuity=True)
    for j in range(pb.n_views):
        graph.add(pose_gauge_prior(pose_key(j + 1), values.atPose3(pose_key(j + 1)).matrix()))
    values = _solve_stage(graph, values, config, 0, pb.n_levels, False, report)
    report["levels"][-1]["depth_stage"] = True
    return values, builders


def _solved_primitives(pb: _Problem, values: gtsam.Values, config: SfMConfig) -> PrimitiveSet:
    """The reference primitives at the solved log-scales; planar model: the
    planes' depths baked into ``log_depth`` (a plane behind the camera keeps
    its primitive's median depth there)."""
    prims, cam, rays_all = pb.prims, pb.cam, pb.rays_all
    if config.shape_model == "scaled":
        s = np.array([values.atVector(scale_key(i))[0] for i in range(len(prims))])
        return prims.with_log_scales(s)
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
    return solved


@dataclass
class _Marginals:
    """Output of :func:`_marginals`: per-primitive gauge-free log-scale stds and
    whether only the prior constrains each scale, per-view pose covariances."""

    log_std: np.ndarray
    prior_only: np.ndarray
    covs: List[Optional[np.ndarray]]


def gauge_free_scale_std(marg: "gtsam.Marginals", n: int, prior_sigma: float):
    """Std of each log-scale with the global-scale gauge removed, and a mask of
    the scales constrained by nothing but their prior.

    The joint marginal ``C`` of all log-scales carries the global scale (fixed
    only by the weak prior) as one large shared mode.  Scales whose own std is
    over half the prior's are constrained by the prior alone (returned in the
    mask, raw std kept).  The others are conditioned on their mean log-scale:
    ``diag(C - C 1 1^T C / (1^T C 1))`` over that set.
    """
    keys = gtsam.KeyVector([scale_key(i) for i in range(n)])
    C = marg.jointMarginalCovariance(keys).fullMatrix()
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    con = np.flatnonzero(std <= 0.5 * prior_sigma)
    if con.size >= 2:
        Cc = C[np.ix_(con, con)]
        c1 = Cc.sum(axis=1)
        std[con] = np.sqrt(np.maximum(np.diag(Cc) - c1 ** 2 / c1.sum(), 0.0))
    prior_only = np.ones(n, dtype=bool)
    prior_only[con] = False
    return std, prior_only


def _marginals(pb: _Problem, values: gtsam.Values, builders: Sequence[PhotometricFactorGroup],
               config: SfMConfig, status: str, report: dict,
               stage: Optional[LandmarkStage] = None) -> _Marginals:
    """Marginal uncertainties at the solution (``config.marginals``, not when
    diverged) with a per-pixel noise model whose sigma is the residuals' robust
    std (``report["pixel_sigma"]``); a failure is reported in
    ``report["marginals_error"]``, not raised."""
    prims = pb.prims
    log_std = np.full(len(prims), np.nan)
    prior_only = np.zeros(len(prims), dtype=bool)
    covs: List[Optional[np.ndarray]] = [None] * pb.n_views
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
            mgraph, mgroups = build_level_graph(prims, pb.rays_all, pb.ref_pyr, pb.view_pyrs, 0,
                                          values, pix_cfg)
            marg = gtsam.Marginals(mgraph, values)
            release_groups(mgroups)
            covs = stage.covariances() if stage is not None else [
                marg.marginalCovariance(pose_key(j + 1)) for j in range(pb.n_views)]
            if config.shape_model == "scaled":
                log_std, prior_only = gauge_free_scale_std(marg, len(prims),
                                                            1.0 / np.sqrt(prior_w))
        except RuntimeError as exc:  # indeterminant system: report, do not crash
            report["marginals_error"] = gtsam_error_line(exc)
            log.warning("marginals failed: %s", report["marginals_error"])
    return _Marginals(log_std, prior_only, covs)


def _unconstrained(solved: PrimitiveSet, marg: _Marginals, status: str,
                   view_status: List[str], config: SfMConfig, report: dict) -> np.ndarray:
    """Indices of the primitives whose depth the views do not support
    (:attr:`SfMResult.unconstrained`)."""
    unconstrained = np.flatnonzero(marg.prior_only | (marg.log_std > config.max_log_scale_std))
    no_parallax = all(v in ("low_parallax", "diverged") for v in view_status)
    if no_parallax or (status != "ok" and "marginals_error" in report):
        unconstrained = np.arange(len(solved))    # the views support no depth
    return unconstrained


def _supported_depth(solved: PrimitiveSet, unconstrained: np.ndarray, status: str,
                     config: SfMConfig) -> np.ndarray:
    """Depth map of ``solved`` without the ``unconstrained`` primitives (NaN there)."""
    keep = np.setdiff1d(np.arange(len(solved)), unconstrained)
    depth = solved.subset(keep).depth_map() if keep.size else np.full(solved.camera.shape, np.nan)
    log.info("%d of %d primitives unconstrained by the views (%s): not in the depth map",
             unconstrained.size, len(solved), "status " + status if keep.size == 0
             else f"log-scale std > {config.max_log_scale_std:.2f}")
    return depth


def _start(ref_image, views, camera, pb: _Problem, config: SfMConfig, init_T_ref_view,
           init_report: dict):
    """The start of the solve by ``config.init`` unless poses are given: ``(landmark
    stage or None, initial poses or None, per view True where the features could
    not verify it)``; ``pb.prims`` takes the initial log-scales."""
    unverified = [False] * len(views)
    if init_T_ref_view is not None or config.init == "identity":
        return None, init_T_ref_view, unverified
    if config.init == "twoview":
        init_T_ref_view, pb.prims = twoview_initialisation(ref_image, views, camera, pb.prims,
                                                           init_report)
        return None, init_T_ref_view, [s in ("too_few_matches", "degenerate")
                                       for s in init_report["twoview_status"]]
    stage = LandmarkStage([ref_image] + list(views), camera, config.features)
    pb.prims = stage.scaled_primitives(pb.prims, init_report)
    init_report.update(stage.bundle.report, view_status=stage.bundle.view_status[1:],
                       pixel_sigma=stage.bundle.pixel_sigma)
    return stage, stage.initial_poses(), stage.unverified()


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
    prims = _reference_primitives(ref_image, camera, frontend, config, ref_depth)
    cam = prims.camera
    if config.reset_scales:
        prims = prims.with_log_scales(np.zeros(len(prims)))
    t_front = time.perf_counter()
    pb = _problem(ref_image, views, camera, prims, cam, config)

    init_report: Dict[str, object] = {"method": "given" if init_T_ref_view is not None
                                      else config.init}
    stage, init_T_ref_view, unverified = _start(ref_image, views, camera, pb, config,
                                                init_T_ref_view, init_report)
    values = _initial_values(pb.prims, len(views), init_T_ref_view, config)
    report: Dict[str, object] = {"levels": [], "n_primitives": len(pb.prims),
                                 "n_views": len(views), "shape_model": config.shape_model,
                                 "init": init_report}
    values, builders = _coarse_to_fine(pb, values, config, init_T_ref_view, report, stage)
    t_opt = time.perf_counter()

    # ---- results
    T_ref_view = [values.atPose3(pose_key(j + 1)).matrix() for j in range(len(views))]
    brightness = [values.atVector(brightness_key(j + 1)) if config.brightness else np.zeros(2)
                  for j in range(len(views))]
    solved = _solved_primitives(pb, values, config)
    depth = solved.depth_map()

    status, view_status, valid_frac = assess_result(solved, T_ref_view, config, report,
                                                    unverified)
    marg = _marginals(pb, values, builders, config, status, report, stage)
    release_groups(builders)
    unconstrained = _unconstrained(solved, marg, status, view_status, config, report)
    if unconstrained.size:
        depth = _supported_depth(solved, unconstrained, status, config)
    report["n_unconstrained"] = int(unconstrained.size)
    report.update({"valid_fraction": valid_frac, "seconds_frontend": t_front - t_start,
                   "seconds_optimise": t_opt - t_front,
                   "seconds_total": time.perf_counter() - t_start,
                   "final_cost": report["levels"][-1]["final_cost"] if report["levels"] else None})
    return SfMResult(status, view_status, T_ref_view, solved, depth, cam, marg.log_std, marg.covs,
                     brightness, report, unconstrained)
