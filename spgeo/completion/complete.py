"""Zero-shot depth completion with SuperPrimitives (docs/design.md §5).

Input: one RGB image, a *sparse* metric depth map (e.g. the ~150 VIO points of
VOID) and the intrinsics.  The image alone is cut into SuperPrimitives
(segments with unscaled integrated log-depth, :mod:`spgeo.frontend`); the
sparse depth fixes one log-scale per primitive:

1. **scales** — for primitive ``i`` with unscaled log-depth ``l_i`` and the
   sparse points ``k`` inside its mask,
   ``s_i = median_k (log d_k - l_i(u_k))`` (``method="median"``, the paper), or
   the Huber M-estimate of the same residuals found by Levenberg–Marquardt on a
   GTSAM graph with one :class:`spgeo.factors.sparse_depth.SparseDepthFactor`
   per primitive (``method="joint"``).  The graph is block-diagonal (each
   factor touches one log-scale), so "joint" means one solve for all
   primitives; on clean data the two agree to well under the noise (tested),
   with outliers both are robust (the median has a 50 % breakdown point, the
   Huber estimate bounds each point's influence).  The joint form is the one
   that composes with photometric factors on the same keys.
   ``method="graph"`` (:mod:`spgeo.completion.graph`) solves all scales
   together with Cauchy losses and a coupling between neighbours separated by
   a weak image edge: keypoints sit on region borders and often carry the
   neighbour's depth, which this outvotes; primitives without points get a
   scale through the coupling.
   ``shape_model="plane"`` then adds a planar inverse-depth correction per
   primitive (:mod:`spgeo.completion.planes`: robust plane fits with a prior
   towards the primitive's own orientation where it holds three or more
   points, depth lent across weak edges to empty primitives; with "graph",
   one joint solve with continuity across weak edges).  ``"graph"`` with
   ``"plane"`` is the default; ``method="median", shape_model="scale"`` is the
   paper's.
2. **drop** primitives with fewer than ``min_points`` sparse points (1: any
   primitive without a point has no scale).
3. **render** — the kept primitives' depths are averaged where they overlap
   (:meth:`spgeo.primitives.PrimitiveSet.depth_map`).
4. **fill** holes by linear interpolation (Delaunay, in depth) of the depths on
   the hole borders plus the sparse points inside holes, then nearest value
   outside their convex hull.  Steps 3-4 run at the primitives' (working)
   resolution; the complete map is then resized to the input (bilinear; the
   confidence codes by nearest neighbour).
5. **fallback** — when the supported primitives cover less than
   ``min_coverage`` of the image (or none has a point), the primitives are
   ignored and the result is plain linear interpolation of the sparse points
   (``CompletionResult.fallback`` is True; a warning is logged).  The authors
   instead re-ran SAM keeping all three masks per prompt; a finer / coarser
   re-segmentation is left to the caller (pass another front-end).
6. **residual correction** (``residual_clip``) — the log-residuals of the
   complete map at the sparse points, each clipped to ``residual_clip``, are
   interpolated linearly over the image and applied as a factor
   (:func:`spgeo.completion.fill.residual_correction`) on the pixels of flat
   primitives (the front-end knew no shape: one scale or plane cannot pass
   through their points) and of holes; the map there honours its points up to
   the clip, smoothly.  Primitives shaped by normals are left as fitted (there
   the residuals are mostly rejected border points and noise).  Not applied to
   the fallback (it already passes through the points).
7. **held-out choice** (``choose="heldout"``) — the map of steps 1-6 is one
   candidate among ``config.candidates`` (linear interpolation, IP-Basic, the
   colorization fill of :mod:`spgeo.completion.baselines`, and, with a depth
   model, its metric depth aligned to the points,
   :mod:`spgeo.completion.network`); per primitive the log-linear blend of
   the candidates with the lowest error on held-out sparse points is taken,
   the candidates refitted on all points (:mod:`spgeo.completion.choose`;
   ``CompletionResult.choice`` records the blend weights per region).

**Monocular + sparse only.**  The sparse depth is never given to the
front-end.  Front-ends whose normal estimator reads dense depth (``"depth"``,
oracles) are refused unless the caller passes ``frontend_depth=`` explicitly;
the result then carries ``uses_depth=True`` and must be labelled an oracle /
RGB-D ablation.  The default front-end is ``make_frontend("classical")``
(superpixels + fronto-parallel normals: constant depth per primitive), the
learned one ``"onnx"`` (models via ``spgeo models``).

Sparse depth maps are (H, W) metres with 0 or NaN = missing (VOID uses 0).
More valid points than ``CompletionConfig.max_sparse_points`` (dense depth
passed as sparse; the time grows with the number of points) are subsampled
to that many with a warning (``CompletionResult.sparse_subsampled``).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Dict, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..images import to_float_image
from ..primitives import PrimitiveSet
from ..validation import check_camera, check_sparse_depth
from .choose import Candidate, HeldoutChoice, choose_by_heldout
from .config import CompletionConfig
from .fill import fill_holes, resample_sparse, residual_correction, upsample
from .graph import solve_log_scales_graph, solve_planes_graph
from .planes import MODE_NONE, MODE_SCALE, fit_primitive_planes, lend_across_weak_edges
from .scales import (flat_primitives, grouped_median, solve_log_scales_joint,
                     sparse_point_assignments, working_pixels)

if TYPE_CHECKING:  # pragma: no cover
    from ..frontend import PrimitiveFrontEnd

__all__ = ["CompletionResult", "complete_depth", "working_size_for", "candidate_fits"]

log = logging.getLogger(__name__)


# ----------------------------------------------------------------- result
@dataclass
class CompletionResult:
    """Output of :func:`complete_depth`.

    Attributes:
        depth: (H, W) float64 dense depth (metres) at the input resolution,
            finite and > 0 everywhere.
        confidence: (H, W) uint8 coverage code of the primitive completion
            (steps 1-6): 2 = a primitive with sparse support, 1 = linear
            interpolation, 0 = nearest value; where the held-out choice
            blended in other candidates, ``choice.region_weights`` says how.
        primitives: the kept primitives with their fitted ``log_scales`` (at
            the front-end's working resolution).
        log_scales: (N_kept,) fitted log-scales (log metres at each anchor).
        n_points: (N_kept,) sparse points supporting each kept primitive.
        kept: (N_kept,) indices of the kept primitives in the front-end's set.
        n_primitives: primitives the front-end produced.
        n_sparse: valid sparse points used (after subsampling).
        n_sparse_given: valid sparse points given; more than
            ``config.max_sparse_points`` (dense depth given as sparse) were
            subsampled to that many (``sparse_subsampled``, a logged warning).
        coverage: fraction of image pixels covered by kept primitives (at the
            primitives' resolution; reported even when ``fallback`` ignored them).
        method: ``"median"`` or ``"joint"``.
        frontend: name of the front-end (``"primitives"`` when a set was given).
        uses_depth: True when the front-end read dense depth (oracle / RGB-D
            ablation: not monocular completion).
        fallback: True when the primitives were ignored (low coverage) and the
            depth is plain linear interpolation of the sparse points.
        timings: seconds per stage (``frontend``, ``scales``, ``render``,
            ``fill``: holes and the residual correction, ``total``).
        solver: ``"joint"``: LM report (iterations, initial / final error).
        modes: (N_kept,) how each kept primitive got its depth
            (:data:`spgeo.completion.planes.MODE_SCALE` / ``MODE_PLANE`` /
            ``MODE_LENT``); all ``MODE_SCALE`` for ``shape_model="scale"``.
        choice: ``choose="heldout"``: the held-out choice (the blend of each
            region, the candidate it weighs most per pixel, their held-out
            errors); None otherwise
            (or when there were too few points to hold any out).
    """

    depth: np.ndarray
    confidence: np.ndarray
    primitives: PrimitiveSet
    log_scales: np.ndarray
    n_points: np.ndarray
    kept: np.ndarray
    n_primitives: int
    n_sparse: int
    coverage: float
    method: str
    frontend: str
    uses_depth: bool
    fallback: bool
    timings: Dict[str, float] = field(default_factory=dict)
    solver: Dict[str, float] = field(default_factory=dict)
    modes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    choice: Optional[HeldoutChoice] = None
    n_sparse_given: int = 0

    @property
    def sparse_subsampled(self) -> bool:
        """True when more points were given than used (``max_sparse_points``)."""
        return self.n_sparse_given > self.n_sparse

    def __repr__(self) -> str:
        """One line: :meth:`summary` and the depth map's size and range (metres)."""
        h, w = self.depth.shape
        lo, hi = (np.nanmin(self.depth), np.nanmax(self.depth)) if self.depth.size else (0, 0)
        return f"CompletionResult({self.summary()}; depth {w}x{h}, {lo:.2f}-{hi:.2f} m)"

    def summary(self) -> str:
        """One line for logs."""
        tag = " [uses depth: oracle/RGB-D]" if self.uses_depth else ""
        fb = " FALLBACK(linear)" if self.fallback else ""
        given = (f" (subsampled from {self.n_sparse_given})" if self.sparse_subsampled
                 else "")
        if self.choice is not None:
            fb += " chosen " + ",".join(f"{k}:{v}" for k, v in
                                        self.choice.region_counts().items())
        return (f"completion[{self.method}, {self.frontend}{tag}]{fb}: {len(self.kept)}/"
                f"{self.n_primitives} primitives with support from {self.n_sparse} points"
                f"{given}, "
                f"coverage {self.coverage:.2f}, {1e3 * self.timings.get('total', 0):.0f} ms")


# ----------------------------------------------------------------- front-end handling
def working_size_for(camera: PinholeCamera, working_width: Optional[int]
                     ) -> Optional[Tuple[int, int]]:
    """``FrontEndConfig.working_size`` for ``camera``: ``(working_width, h')``
    keeping the aspect when the image is wider, else None (input size)."""
    if working_width is None or camera.width <= working_width:
        return None
    ww = int(working_width)
    return ww, max(1, int(round(camera.height * ww / camera.width)))


def _check_primitive_camera(prims: PrimitiveSet, camera: PinholeCamera) -> None:
    pc = prims.camera
    expect = camera if pc.size == camera.size else camera.resized(pc.width, pc.height)
    a = np.array([pc.fx, pc.fy, pc.cx, pc.cy])
    b = np.array([expect.fx, expect.fy, expect.cx, expect.cy])
    if not np.allclose(a, b, rtol=1e-4, atol=1e-3):
        raise ValueError(f"primitives were built for a camera {pc} that is not a resize of the "
                         f"input camera {camera}")


def _primitives(image, camera, frontend, frontend_depth, config):
    """(PrimitiveSet, front-end name, uses_depth)."""
    from ..frontend import FrontEndConfig, make_frontend

    if isinstance(frontend, PrimitiveSet):
        if frontend_depth is not None:
            raise ValueError("frontend_depth is only used when a front-end is run here; "
                             "a PrimitiveSet was given")
        _check_primitive_camera(frontend, camera)
        uses = bool(frontend.meta.get("uses_depth", False))
        return frontend, str(frontend.meta.get("frontend", "primitives")), uses
    if frontend is None or isinstance(frontend, str):
        name = "classical" if frontend is None else frontend
        frontend = make_frontend(name, FrontEndConfig(
            working_size=working_size_for(camera, config.working_width)))
    if not hasattr(frontend, "primify"):
        raise TypeError(f"frontend must be None, a front-end name, a PrimitiveFrontEnd or a "
                        f"PrimitiveSet, got {type(frontend).__name__}")
    uses = bool(getattr(frontend, "uses_depth", False))
    name = getattr(frontend, "name", type(frontend).__name__)
    if uses and frontend_depth is None:
        raise ValueError(
            f"front-end {name!r} reads dense depth, but depth completion is monocular + sparse: "
            "use the 'classical' or 'onnx' front-end, or pass frontend_depth= explicitly for an "
            "oracle / RGB-D ablation (the sparse depth is never given to the front-end)")
    if not uses and frontend_depth is not None:
        log.warning("frontend_depth given but front-end %r does not read depth; ignored", name)
    dep = frontend_depth if uses else None
    prims = frontend.primify(image, camera, dep)
    return prims, name, uses


def _working_image(image: np.ndarray, prims: PrimitiveSet) -> np.ndarray:
    """``image`` as float in [0, 1] at the primitives' resolution."""
    import cv2

    img = to_float_image(image)
    if img.shape[:2] != prims.camera.shape:
        img = cv2.resize(img, prims.camera.size, interpolation=cv2.INTER_AREA)
    return img


def _plane_model(work, prims, uv, camera, point, prim, point_d, s, counts, kept, config,
                 point_w):
    """``shape_model="plane"``: (kept subset with fitted shapes, kept indices, modes);
    ``work`` is :func:`_working_image`."""
    n = len(prims)
    s_ok = np.full(n, np.nan)
    s_ok[kept] = s[kept]
    pix = working_pixels(uv, camera, prims.camera)[point]
    if config.method == "graph":
        fit = solve_planes_graph(prims, work, prim, pix, point_d, s_ok,
                                 point_w, prior=config.plane_prior,
                                 coupling=config.plane_coupling,
                                 prior_flat=config.plane_prior_flat)
        kept = np.flatnonzero(fit.mode != MODE_NONE)
        sub = prims.with_scaled_log_depth(fit.scaled_log_depth).subset(kept)
        return sub, kept, fit.mode[kept]
    hyp = prims.meta.get("normal_hypotheses")
    if hyp is not None and np.shape(hyp)[:1] != (n,):
        log.debug("completion: normal_hypotheses of shape %s do not match %d primitives; "
                  "ignored", np.shape(hyp), n)
        hyp = None
    fit = fit_primitive_planes(prims, prim, pix, point_d, s_ok, counts, config.plane_min_points,
                               config.plane_prior, config.plane_huber, hypotheses=hyp)
    if config.lend_edge_threshold is not None and config.lend_rounds > 0:
        fit = lend_across_weak_edges(prims, fit, work,
                                     config.lend_edge_threshold,
                                     config.lend_rounds)
    kept = np.flatnonzero(fit.mode != MODE_NONE)
    sub = prims.with_scaled_log_depth(fit.scaled_log_depth).subset(kept)
    return sub, kept, fit.mode[kept]


def _shapeless_weight(prims: PrimitiveSet, camera: PinholeCamera) -> np.ndarray:
    """(H, W) of ``camera``: 0 on pixels of primitives with a front-end shape
    (not flat), 1 elsewhere (flat primitives, no primitive)."""
    import cv2

    npix = prims.camera.width * prims.camera.height
    shaped = np.zeros(npix, np.float32)
    keep = ~flat_primitives(prims)
    shaped[prims.pixels[keep[prims.primitive_ids]]] = 1.0
    w = 1.0 - shaped.reshape(prims.camera.shape)
    if w.shape != camera.shape:
        w = cv2.resize(w, camera.size, interpolation=cv2.INTER_LINEAR)
    return w.astype(np.float64)


# ----------------------------------------------------------------- main entry point
def complete_depth(image: np.ndarray, sparse_depth: np.ndarray, camera: PinholeCamera,
                   frontend: Union[None, str, "PrimitiveFrontEnd", PrimitiveSet] = None,
                   config: CompletionConfig = CompletionConfig(),
                   frontend_depth: Optional[np.ndarray] = None,
                   depth_model=None) -> CompletionResult:
    """Dense metric depth from one image and sparse metric depth (module docstring).

    Args:
        image: (H, W, 3) RGB or (H, W) grey; uint8 / uint16 / float in [0, 1].
        sparse_depth: (H, W) metres, 0 or NaN = missing; at least one point.
        camera: intrinsics of ``image`` (undistorted), size (W, H).
        frontend: None (``make_frontend("classical")`` at
            ``config.working_width``), a front-end name (``"classical"``,
            ``"onnx"``), a :class:`~spgeo.frontend.PrimitiveFrontEnd`, or a
            ready :class:`~spgeo.primitives.PrimitiveSet` of this image (its
            log-scales are ignored).
        config: :class:`CompletionConfig`.
        frontend_depth: dense depth for front-ends that read depth (oracle /
            RGB-D ablations only; flagged ``uses_depth`` in the result).  Never
            the sparse input.
        depth_model: metric-depth network for the ``"network:*"`` candidates of
            ``choose="heldout"``: a registry name or path
            (:func:`spgeo.frontend.metric_depth_from_cache`) or an object with
            ``predict_metric(image) -> (H, W)`` metres; None:
            ``config.depth_model``.  Ignored (with a warning) for ``choose="none"``.
    Returns:
        :class:`CompletionResult`.
    Raises:
        TypeError: ``camera`` / ``config`` of another type.
        InputError: (a ``ValueError``) an image whose size differs from the
            camera's, of another dtype, with NaN / inf or values outside [0, 1];
            sparse depth failing :func:`spgeo.validation.check_sparse_depth`
            (shape other than the image's, integer / bool dtype, millimetres,
            inf, negative, no point).
        ValueError: a depth-reading front-end without ``frontend_depth``,
            primitives of another camera, a depth model that does not fit its
            preset (the message names the file).
        FileNotFoundError: a depth model that is not there.
    """
    t0 = time.perf_counter()
    image, sparse, uv, sd, n_given = _checked_inputs(image, sparse_depth, camera, config)
    model = _depth_model(depth_model if depth_model is not None else config.depth_model, config)
    prims, fe_name, uses_depth = _primitives(image, camera, frontend, frontend_depth, config)
    t_fe = time.perf_counter()
    work = _working_image(image, prims)
    done = _primitive_completion(image, prims, uv, sd, camera, config, work=work)
    t_fi = time.perf_counter()
    choice = None
    if config.choose == "heldout":
        choice = _heldout_choice(image, prims, uv, sd, camera, config, model, done.depth,
                                 work)
    fit = done.fit
    res = CompletionResult(
        depth=choice.depth if choice is not None else done.depth, confidence=done.confidence,
        primitives=fit.sub, log_scales=fit.sub.log_scales.copy(),
        n_points=fit.counts[fit.kept].copy(), kept=fit.kept, n_primitives=len(prims),
        n_sparse=int(sd.size), coverage=done.coverage, method=config.method, frontend=fe_name,
        uses_depth=uses_depth, fallback=done.fallback,
        timings={"frontend": t_fe - t0, **done.timings, "choose": time.perf_counter() - t_fi,
                 "total": time.perf_counter() - t0},
        solver=fit.solver, modes=fit.modes, choice=choice, n_sparse_given=n_given)
    log.info("%s", res.summary())
    return res


@dataclass
class _Completed:
    """Output of :func:`_primitive_completion` (steps 1-6)."""

    depth: np.ndarray
    confidence: np.ndarray
    fit: "_ScaleFit"
    coverage: float
    fallback: bool
    timings: Dict[str, float]


def _primitive_completion(image: np.ndarray, prims: PrimitiveSet, uv: np.ndarray, sd: np.ndarray,
                          camera: PinholeCamera, config: CompletionConfig,
                          quiet: bool = False, work: Optional[np.ndarray] = None) -> _Completed:
    """Steps 1-6 of the module docstring from the points ``uv`` (P, 2) / ``sd`` (P,)
    metres; ``quiet`` logs the fallback at debug level (held-out folds); ``work``:
    :func:`_working_image` of ``image`` when already made (the folds share it)."""
    t0 = time.perf_counter()
    work = _working_image(image, prims) if work is None else work
    fit = _fit_scales(work, prims, uv, sd, camera, config)
    t_sc = time.perf_counter()
    dmap = fit.sub.depth_map() if fit.kept.size else np.full(prims.camera.shape, np.nan)
    covered = np.isfinite(dmap)
    coverage = float(covered.mean())
    fallback = coverage < config.min_coverage or fit.kept.size == 0
    t_re = time.perf_counter()
    if fallback:
        (log.debug if quiet else log.warning)(
            "completion: supported primitives cover %.3f of the image (< %.3f); falling back "
            "to linear interpolation of the %d sparse points", coverage, config.min_coverage,
            sd.size)
        depth, conf = fill_holes(np.full(camera.shape, np.nan), np.zeros(camera.shape, bool),
                                 _sparse_map(uv, sd, camera))
    else:
        depth, conf = _filled_map(dmap, covered, prims, uv, sd, camera, config)
    timings = {"scales": t_sc - t0, "render": t_re - t_sc, "fill": time.perf_counter() - t_re}
    return _Completed(depth, conf, fit, coverage, fallback, timings)


def _sparse_map(uv: np.ndarray, sd: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """(H, W) of ``camera``: ``sd`` at the pixels ``uv``, 0 elsewhere."""
    out = np.zeros(camera.shape)
    out[uv[:, 1].astype(np.int64), uv[:, 0].astype(np.int64)] = sd
    return out


def _depth_model(spec, config: CompletionConfig):
    """The metric-depth model of ``spec`` (None, name / path, or an object with
    ``predict_metric``); None when unused (``choose="none"``, or no
    ``"network:*"`` candidate)."""
    if spec is None:
        return None
    if config.choose != "heldout" or not any(c.startswith("network:")
                                             for c in config.candidates):
        log.warning("completion: depth model %s given but unused (choose=%r, candidates %s)",
                    spec, config.choose, config.candidates)
        return None
    if hasattr(spec, "predict_metric"):
        return spec
    from ..frontend import metric_depth_from_cache

    return metric_depth_from_cache(spec)


def _heldout_choice(image, prims, uv, sd, camera, config, model, primitive_depth, work):
    """Step 7: :func:`spgeo.completion.choose.choose_by_heldout` over
    ``config.candidates``; None when there are fewer than two points per fold.
    ``work`` is :func:`_working_image`."""
    import cv2

    from .network import network_depth

    if sd.size < 2 * config.heldout.folds:
        log.info("completion: %d points are too few for %d held-out folds; no choice",
                 sd.size, config.heldout.folds)
        return None
    labels = prims.label_image()
    if labels.shape != camera.shape:
        labels = cv2.resize(labels, camera.size, interpolation=cv2.INTER_NEAREST)
    net = network_depth(model, image) if model is not None else None
    fits = candidate_fits(image, prims, camera, config, work, labels, net)
    cands = {name: fits[name] for name in config.candidates if name in fits}
    return choose_by_heldout(cands, uv, sd, labels, config.heldout,
                             fitted={"primitives": primitive_depth})


def candidate_fits(image: np.ndarray, prims: PrimitiveSet, camera: PinholeCamera,
                   config: CompletionConfig, work: np.ndarray, labels: np.ndarray,
                   net: Optional[np.ndarray] = None) -> Dict[str, Candidate]:
    """Every candidate of :data:`~spgeo.completion.config.CANDIDATES` that can
    run, as :data:`spgeo.completion.choose.Candidate` s ``fit(uv, depth) ->
    (H, W)`` metres at ``camera``'s size: ``"primitives"`` (steps 1-6 with
    ``config``), ``"linear"``, ``"ip_basic"``, ``"colorization"``, and with
    ``net`` ((H, W) metres, :func:`spgeo.completion.network.network_depth`) one
    ``"network:<alignment>"`` per alignment, those of ``"primitive"`` per
    region of ``labels`` ((H, W) int).  ``work`` is :func:`_working_image`."""
    from .baselines import colorization_completion, ip_basic_completion, \
        linear_interpolation_completion
    from .network import ALIGNMENTS, align_network_depth

    fits = {
        "primitives": lambda p, d: _primitive_completion(image, prims, p, d, camera, config,
                                                         quiet=True, work=work).depth,
        "linear": lambda p, d: linear_interpolation_completion(_sparse_map(p, d, camera)),
        "ip_basic": lambda p, d: ip_basic_completion(_sparse_map(p, d, camera)),
        "colorization": lambda p, d: colorization_completion(image, _sparse_map(p, d, camera)),
    }
    if net is not None:
        for mode in ALIGNMENTS:
            fits[f"network:{mode}"] = (lambda p, d, m=mode: align_network_depth(
                net, p, d, m, labels, config.network_min_points))
    return fits


def _checked_inputs(image, sparse_depth, camera, config):
    """:func:`complete_depth`'s input checks (its *Raises*); returns ``(image,
    sparse depth map, (P, 2) pixel coordinates of the P sparse points, their depths,
    the number of points given)``: more than ``config.max_sparse_points`` are
    subsampled to that many (:func:`_subsampled`)."""
    check_camera(camera, "complete_depth: camera")
    if not isinstance(config, CompletionConfig):
        raise TypeError(f"config must be a CompletionConfig, got {type(config).__name__}")
    image = camera.check_image(image)
    to_float_image(image)  # validates dtype, NaN / inf and range
    sparse = check_sparse_depth(sparse_depth, "complete_depth: sparse depth", camera.shape)
    n_given = int(np.count_nonzero(sparse > 0))
    sparse = _subsampled(sparse, n_given, config.max_sparse_points)
    sv, su = np.nonzero(sparse > 0)
    sd = sparse[sv, su]
    uv = np.stack([su, sv], 1).astype(np.float64)
    return image, sparse, uv, sd, n_given


def _subsampled(sparse: np.ndarray, n_given: int, max_points: int) -> np.ndarray:
    """``sparse`` itself, or with more than ``max_points`` valid points (dense depth
    given as sparse: the cost grows with the points, ``CompletionConfig.max_sparse_points``)
    ``max_points`` of them drawn uniformly with a fixed seed
    (:func:`~spgeo.completion.sparse_points.uniform_sparse_depth`), with a warning."""
    if n_given <= max_points:
        return sparse
    from .sparse_points import uniform_sparse_depth

    log.warning("completion: the sparse depth has %d valid points (%.0f%% of the pixels: "
                "dense depth?); %d of them kept, drawn uniformly with a fixed seed "
                "(CompletionConfig.max_sparse_points; the time grows with the points)",
                n_given, 100.0 * n_given / sparse.size, max_points)
    return uniform_sparse_depth(sparse, max_points, rel_noise=0.0, seed=0)


@dataclass
class _ScaleFit:
    """Output of :func:`_fit_scales`: the kept primitives with their fitted
    depths (``sub``), their indices in the front-end's set, how each got its
    depth (``MODE_*``), sparse points per primitive of the set, solver report."""

    sub: PrimitiveSet
    kept: np.ndarray
    modes: np.ndarray
    counts: np.ndarray
    solver: Dict[str, float]


def _fit_scales(work: np.ndarray, prims: PrimitiveSet, uv: np.ndarray, sd: np.ndarray,
                camera: PinholeCamera, config: CompletionConfig) -> _ScaleFit:
    """Steps 1-2 of the module docstring: log-scales by ``config.method`` (median,
    joint or graph), primitives without support dropped, then the planar shapes
    of ``shape_model="plane"``; ``work`` is :func:`_working_image`."""
    n = len(prims)
    point, prim, ldep = sparse_point_assignments(prims, uv, camera) if n else (
        np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    resid = np.log(sd[point]) - ldep
    s_med, counts = grouped_median(prim, resid, n)
    solver: Dict[str, float] = {}
    s = s_med
    if config.method == "joint" and point.size:
        s, solver = solve_log_scales_joint(prim, ldep, sd[point], n, s_med, config.sigma,
                                           config.huber_k, config.max_iterations)
    point_w = np.ones(point.size)
    if config.method == "graph" and point.size:
        g = solve_log_scales_graph(prims, work, prim, ldep, sd[point],
                                   s_med, coupling=config.graph_coupling)
        s, point_w = g.log_scales, g.point_weights
        solver = {"coupled_pairs": float(g.n_edges)}
        kept = np.flatnonzero(np.isfinite(s))
    else:
        kept = np.flatnonzero((counts >= config.min_points) & np.isfinite(s))
    modes = np.full(kept.size, MODE_SCALE, np.int8)
    if config.shape_model == "plane" and n:
        sub, kept, modes = _plane_model(work, prims, uv, camera, point, prim, sd[point], s,
                                        counts, kept, config, point_w)
    else:
        sub = prims.subset(kept).with_log_scales(s[kept])
    return _ScaleFit(sub, kept, modes, counts, solver)


def _filled_map(dmap: np.ndarray, covered: np.ndarray, prims: PrimitiveSet, uv: np.ndarray,
                sd: np.ndarray, camera: PinholeCamera, config: CompletionConfig):
    """Steps 4 and 6 of the module docstring: ``(depth, confidence)`` at the
    input resolution from the rendered map ``dmap`` (finite where ``covered``):
    holes filled at the primitives' resolution, resized, residual correction."""
    # holes are filled at the primitives' resolution, then the map is resized
    depth_w, conf_w = fill_holes(dmap, covered, resample_sparse(uv, sd, camera, prims.camera))
    depth, conf = upsample(depth_w, conf_w, camera)
    if config.residual_clip:
        depth = residual_correction(depth, uv, sd, config.residual_clip,
                                    _shapeless_weight(prims, camera))
    return depth, conf
