"""Zero-shot depth completion with SuperPrimitives (DESIGN.md §5).

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

**Monocular + sparse only.**  The sparse depth is never given to the
front-end.  Front-ends whose normal estimator reads dense depth (``"depth"``,
oracles) are refused unless the caller passes ``frontend_depth=`` explicitly;
the result then carries ``uses_depth=True`` and must be labelled an oracle /
RGB-D ablation.  The default front-end is ``make_frontend("classical")``
(superpixels + fronto-parallel normals: constant depth per primitive), the
learned one ``"onnx"`` (models via ``spgeo models``).

Sparse depth maps are (H, W) metres with 0 or NaN = missing (VOID uses 0).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Dict, Optional, Tuple, Union

import cv2
import numpy as np
from scipy import ndimage

from .camera import PinholeCamera
from .images import to_float_image
from .primitives import PrimitiveSet

if TYPE_CHECKING:  # pragma: no cover
    from .frontend import PrimitiveFrontEnd

__all__ = [
    "CompletionConfig", "CompletionResult", "complete_depth", "check_sparse_depth",
    "nearest_fill", "linear_fill", "sparse_point_assignments", "grouped_median",
    "solve_log_scales_joint", "working_size_for", "CONFIDENCE_PRIMITIVE", "CONFIDENCE_LINEAR",
    "CONFIDENCE_NEAREST",
]

log = logging.getLogger(__name__)

#: Confidence / coverage codes of :attr:`CompletionResult.confidence`.
CONFIDENCE_PRIMITIVE = 2   #: depth of a primitive with sparse support
CONFIDENCE_LINEAR = 1      #: filled by linear interpolation
CONFIDENCE_NEAREST = 0     #: filled with the nearest value (outside the hull)

METHODS = ("median", "joint")


# ----------------------------------------------------------------- config / result
@dataclass(frozen=True)
class CompletionConfig:
    """Options of :func:`complete_depth`.

    Attributes:
        method: ``"median"`` (default; the paper's per-primitive median of the
            log-depth ratios) or ``"joint"`` (GTSAM Levenberg–Marquardt over
            all log-scales with robust :class:`SparseDepthFactor` s).
        working_width: when the front-end is built here (``frontend`` None or
            a name), primitives are computed on a copy resized to this width
            (aspect kept) if the image is wider; None keeps the input size.
            Default 320 (the authors integrated at 320x240; 640x480 costs
            about 6x the time).  A front-end object passed in keeps its own
            ``FrontEndConfig.working_size``.
        min_points: primitives with fewer sparse points are dropped.  Default 1.
        sigma: ``"joint"``: sparse-depth noise in log units.  Default 0.01 (1 %).
        huber_k: ``"joint"``: Huber threshold in units of ``sigma`` (None: least
            squares).  Default 1.345.
        max_iterations: ``"joint"``: Levenberg–Marquardt iteration limit.  Default 50.
        min_coverage: below this fraction of the image covered by supported
            primitives, fall back to plain linear interpolation.  Default 0.05.
    """

    method: str = "median"
    working_width: Optional[int] = 320
    min_points: int = 1
    sigma: float = 0.01
    huber_k: Optional[float] = 1.345
    max_iterations: int = 50
    min_coverage: float = 0.05

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"CompletionConfig: method must be one of {METHODS}, "
                             f"got {self.method!r}")
        if self.working_width is not None and int(self.working_width) < 8:
            raise ValueError("CompletionConfig: working_width must be >= 8 or None")
        if int(self.min_points) != self.min_points or self.min_points < 1:
            raise ValueError(f"CompletionConfig: min_points must be an integer >= 1, "
                             f"got {self.min_points}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"CompletionConfig: sigma must be finite and > 0, got {self.sigma}")
        if self.huber_k is not None and not (np.isfinite(self.huber_k) and self.huber_k > 0):
            raise ValueError(f"CompletionConfig: huber_k must be > 0 or None, got {self.huber_k}")
        if int(self.max_iterations) < 1:
            raise ValueError("CompletionConfig: max_iterations must be >= 1")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError(f"CompletionConfig: min_coverage must be in [0, 1], "
                             f"got {self.min_coverage}")


@dataclass
class CompletionResult:
    """Output of :func:`complete_depth`.

    Attributes:
        depth: (H, W) float64 dense depth (metres) at the input resolution,
            finite and > 0 everywhere.
        confidence: (H, W) uint8 coverage code: 2 = a primitive with sparse
            support, 1 = linear interpolation, 0 = nearest value.
        primitives: the kept primitives with their fitted ``log_scales`` (at
            the front-end's working resolution).
        log_scales: (N_kept,) fitted log-scales (log metres at each anchor).
        n_points: (N_kept,) sparse points supporting each kept primitive.
        kept: (N_kept,) indices of the kept primitives in the front-end's set.
        n_primitives: primitives the front-end produced.
        n_sparse: valid sparse points given.
        coverage: fraction of image pixels covered by kept primitives (at the
            primitives' resolution; reported even when ``fallback`` ignored them).
        method: ``"median"`` or ``"joint"``.
        frontend: name of the front-end (``"primitives"`` when a set was given).
        uses_depth: True when the front-end read dense depth (oracle / RGB-D
            ablation: not monocular completion).
        fallback: True when the primitives were ignored (low coverage) and the
            depth is plain linear interpolation of the sparse points.
        timings: seconds per stage (``frontend``, ``scales``, ``render``,
            ``fill``, ``total``).
        solver: ``"joint"``: LM report (iterations, initial / final error).
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

    def summary(self) -> str:
        """One line for logs."""
        tag = " [uses depth: oracle/RGB-D]" if self.uses_depth else ""
        fb = " FALLBACK(linear)" if self.fallback else ""
        return (f"completion[{self.method}, {self.frontend}{tag}]{fb}: {len(self.kept)}/"
                f"{self.n_primitives} primitives with support from {self.n_sparse} points, "
                f"coverage {self.coverage:.2f}, {1e3 * self.timings.get('total', 0):.0f} ms")


# ----------------------------------------------------------------- input helpers
def check_sparse_depth(sparse_depth: np.ndarray, shape: Optional[Tuple[int, int]] = None,
                       name: str = "sparse depth") -> np.ndarray:
    """Validate an (H, W) sparse depth map; return float64 with NaN -> 0.

    Raises ``ValueError`` for a wrong shape (not 2-D, or not ``shape``), a
    non-numeric dtype, infinite or negative values, or no valid (> 0) point.
    """
    d = np.asarray(sparse_depth)
    if d.ndim != 2 or d.size == 0:
        raise ValueError(f"{name} must be a non-empty (H, W) array, got shape {d.shape}")
    if shape is not None and d.shape != tuple(shape):
        raise ValueError(f"{name} has shape {d.shape}, expected {tuple(shape)} (the image size)")
    if d.dtype == bool or not np.issubdtype(d.dtype, np.number) \
            or np.issubdtype(d.dtype, np.complexfloating):
        raise ValueError(f"{name} must be a real numeric array, got dtype {d.dtype}")
    d = d.astype(np.float64)
    if np.any(np.isinf(d)):
        raise ValueError(f"{name} contains inf")
    d = np.nan_to_num(d, nan=0.0)
    if np.any(d < 0):
        raise ValueError(f"{name} contains negative depths")
    if not np.any(d > 0):
        raise ValueError(f"{name} has no valid point (all zero / NaN): nothing to complete from")
    return d


def nearest_fill(values: np.ndarray, known: Optional[np.ndarray] = None) -> np.ndarray:
    """Copy of ``values`` with every pixel where ``known`` is False replaced by
    the value of the nearest known pixel (Euclidean; one distance transform).
    ``known`` defaults to finite and > 0."""
    values = np.asarray(values, dtype=np.float64)
    if known is None:
        known = np.isfinite(values) & (values > 0)
    if not np.any(known):
        raise ValueError("nearest_fill: no known pixel")
    if np.all(known):
        return values.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return values[iy, ix]


def linear_fill(uv: np.ndarray, values: np.ndarray, shape: Tuple[int, int],
                query: Optional[np.ndarray] = None) -> np.ndarray:
    """Linear interpolation (Delaunay, ``scipy.interpolate.LinearNDInterpolator``)
    of scattered ``values`` at pixels ``uv`` (K, 2) (u = column, v = row).

    Returns an (H, W) map holding the interpolant at the pixels of ``query``
    ((H, W) bool; default all) and NaN elsewhere, including query pixels
    outside the convex hull.  Fewer than 3 or collinear points give all NaN.
    """
    from scipy.interpolate import LinearNDInterpolator

    h, w = shape
    out = np.full(h * w, np.nan)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    q = np.flatnonzero(np.ones(h * w, bool) if query is None else np.asarray(query, bool).ravel())
    if uv.shape[0] < 3 or q.size == 0:
        return out.reshape(h, w)
    try:
        interp = LinearNDInterpolator(uv, values)
    except Exception as exc:  # qhull errors: all points collinear / coincident
        log.debug("linear_fill: triangulation failed (%s)", exc)
        return out.reshape(h, w)
    out[q] = interp(np.stack([q % w, q // w], 1).astype(np.float64))
    return out.reshape(h, w)


# ----------------------------------------------------------------- scale fitting
def sparse_point_assignments(primitives: PrimitiveSet, uv: np.ndarray, camera: PinholeCamera):
    """Which primitives contain each sparse point.

    ``uv`` (K, 2) are pixel coordinates in ``camera`` (the input image); they
    are mapped to the primitives' (possibly resized) camera with the
    ``cv2.resize`` convention and rounded.  Returns ``(point, prim, l)``: one
    entry per (point, containing primitive) pair — overlapping primitives each
    get the point — with ``l`` the primitive's unscaled log-depth there.
    """
    pc = primitives.camera
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    sx, sy = pc.width / camera.width, pc.height / camera.height
    u = np.clip(np.rint((uv[:, 0] + 0.5) * sx - 0.5), 0, pc.width - 1).astype(np.int64)
    v = np.clip(np.rint((uv[:, 1] + 0.5) * sy - 0.5), 0, pc.height - 1).astype(np.int64)
    flat = v * pc.width + u
    order = np.argsort(primitives.pixels, kind="stable")
    spix = primitives.pixels[order]
    lo = np.searchsorted(spix, flat, "left")
    hi = np.searchsorted(spix, flat, "right")
    cnt = hi - lo
    point = np.repeat(np.arange(flat.size), cnt)
    start = np.repeat(lo, cnt)
    within = np.arange(point.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    entry = order[start + within]
    return point, primitives.primitive_ids[entry], primitives.log_depth[entry]



def grouped_median(ids: np.ndarray, values: np.ndarray, n: int) -> Tuple[np.ndarray, np.ndarray]:
    """Median of ``values`` per group id in ``[0, n)``; ``(medians (n,) NaN for
    empty groups, counts (n,))``.  Vectorised (one lexsort)."""
    ids = np.asarray(ids, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64)
    counts = np.bincount(ids, minlength=n)[:n] if ids.size else np.zeros(n, np.int64)
    med = np.full(n, np.nan)
    if ids.size:
        order = np.lexsort((values, ids))
        vs = values[order]
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        has = counts > 0
        lo = starts + (counts - 1) // 2
        hi = starts + counts // 2
        med[has] = 0.5 * (vs[lo[has]] + vs[hi[has]])
    return med, counts


def solve_log_scales_joint(point_prim: np.ndarray, point_l: np.ndarray, point_d: np.ndarray,
                           n_primitives: int, initial: np.ndarray, sigma: float = 0.01,
                           huber_k: Optional[float] = 1.345, max_iterations: int = 50
                           ) -> Tuple[np.ndarray, Dict[str, float]]:
    """Log-scales of all primitives by Levenberg–Marquardt on a GTSAM graph with
    one :class:`~spgeo.factors.sparse_depth.SparseDepthFactor` per primitive
    that has points (keys ``gtsam.symbol('s', i)``).

    Args:
        point_prim, point_l, point_d: per (point, primitive) pair: primitive
            index, unscaled log-depth there, measured depth (metres).
        initial: (n_primitives,) starting values (NaN: primitive without points,
            left NaN in the output).
    Returns:
        ``(log_scales (n,), report)`` with ``iterations``, ``initial_error``,
        ``final_error``.
    """
    import gtsam

    from .factors.sparse_depth import SparseDepthFactor

    point_prim = np.asarray(point_prim, dtype=np.int64)
    out = np.full(n_primitives, np.nan)
    if point_prim.size == 0:
        return out, {"iterations": 0, "initial_error": 0.0, "final_error": 0.0}
    order = np.argsort(point_prim, kind="stable")
    pp, ll, dd = point_prim[order], np.asarray(point_l)[order], np.asarray(point_d)[order]
    bounds = np.flatnonzero(np.diff(pp)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [pp.size]])
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    keys = []
    for a, b in zip(starts, ends):  # one factor per primitive (vectorised inside)
        i = int(pp[a])
        key = gtsam.symbol("s", i)
        s0 = (float(initial[i]) if np.isfinite(initial[i])
              else float(np.median(np.log(dd[a:b]) - ll[a:b])))
        graph.add(SparseDepthFactor(key, ll[a:b], dd[a:b], sigma, huber_k).factor)
        values.insert(key, np.array([s0]))
        keys.append((i, key))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    e0 = float(graph.error(values))
    res = opt.optimize()
    for i, key in keys:
        out[i] = float(res.atVector(key)[0])
    return out, {"iterations": int(opt.iterations()), "initial_error": e0,
                 "final_error": float(graph.error(res))}


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
    from .frontend import FrontEndConfig, make_frontend

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


def _upsample(depth_w: np.ndarray, conf_w: np.ndarray, camera: PinholeCamera
              ) -> Tuple[np.ndarray, np.ndarray]:
    """Bring a complete working-resolution depth map (bilinear) and its
    confidence codes (nearest) to ``camera``'s size."""
    if depth_w.shape == camera.shape:
        return depth_w, conf_w
    depth = cv2.resize(depth_w.astype(np.float64), camera.size, interpolation=cv2.INTER_LINEAR)
    conf = cv2.resize(conf_w, camera.size, interpolation=cv2.INTER_NEAREST)
    return depth, conf


def _resample_sparse(uv: np.ndarray, d: np.ndarray, camera: PinholeCamera,
                     target: PinholeCamera) -> np.ndarray:
    """Sparse points of ``camera`` as a sparse map of ``target`` (rounded pixel;
    points sharing a pixel keep the mean)."""
    if target.size == camera.size:
        out = np.zeros(camera.shape)
        out[uv[:, 1].astype(np.int64), uv[:, 0].astype(np.int64)] = d
        return out
    sx, sy = target.width / camera.width, target.height / camera.height
    u = np.clip(np.rint((uv[:, 0] + 0.5) * sx - 0.5), 0, target.width - 1).astype(np.int64)
    v = np.clip(np.rint((uv[:, 1] + 0.5) * sy - 0.5), 0, target.height - 1).astype(np.int64)
    flat = v * target.width + u
    npix = target.width * target.height
    tot = np.bincount(flat, weights=d, minlength=npix)
    cnt = np.bincount(flat, minlength=npix)
    return np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0).reshape(target.shape)


def _fill_holes(depth: np.ndarray, covered: np.ndarray, sparse: np.ndarray
                ) -> Tuple[np.ndarray, np.ndarray]:
    """Fill ``~covered`` pixels: linear interpolation of hole-border depths and
    sparse points inside holes, then nearest.  Returns ``(depth, confidence)``."""
    h, w = depth.shape
    conf = np.full((h, w), CONFIDENCE_NEAREST, np.uint8)
    conf[covered] = CONFIDENCE_PRIMITIVE
    holes = ~covered
    if not holes.any():
        return depth, conf
    border = covered & cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    in_hole = holes & (sparse > 0)
    known = border | in_hole
    vals = np.where(covered, depth, sparse)
    kv, ku = np.nonzero(known)
    lin = linear_fill(np.stack([ku, kv], 1), vals[kv, ku], (h, w), holes)
    out = depth.copy()
    lin_ok = holes & np.isfinite(lin)
    out[lin_ok] = lin[lin_ok]
    out[in_hole] = sparse[in_hole]
    conf[lin_ok | in_hole] = CONFIDENCE_LINEAR
    rest = holes & ~(lin_ok | in_hole)
    if rest.any():
        filled = nearest_fill(np.where(rest, np.nan, out), ~rest)
        out[rest] = filled[rest]
    return out, conf


# ----------------------------------------------------------------- main entry point
def complete_depth(image: np.ndarray, sparse_depth: np.ndarray, camera: PinholeCamera,
                   frontend: Union[None, str, "PrimitiveFrontEnd", PrimitiveSet] = None,
                   config: CompletionConfig = CompletionConfig(),
                   frontend_depth: Optional[np.ndarray] = None) -> CompletionResult:
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
    Returns:
        :class:`CompletionResult`.
    Raises:
        ValueError: wrong shapes, NaN/inf in the image, inf / negative sparse
            depths, an empty sparse set, a depth-reading front-end without
            ``frontend_depth``, primitives of another camera.
    """
    t0 = time.perf_counter()
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    if not isinstance(config, CompletionConfig):
        raise TypeError(f"config must be a CompletionConfig, got {type(config).__name__}")
    image = camera.check_image(image)
    to_float_image(image)  # validates dtype, NaN / inf and range
    sparse = check_sparse_depth(sparse_depth, camera.shape)
    sv, su = np.nonzero(sparse > 0)
    sd = sparse[sv, su]
    uv = np.stack([su, sv], 1).astype(np.float64)

    prims, fe_name, uses_depth = _primitives(image, camera, frontend, frontend_depth, config)
    t_fe = time.perf_counter()

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
    kept = np.flatnonzero((counts >= config.min_points) & np.isfinite(s))
    t_sc = time.perf_counter()

    sub = prims.subset(kept).with_log_scales(s[kept])
    dmap = sub.depth_map() if kept.size else np.full(prims.camera.shape, np.nan)
    covered = np.isfinite(dmap)
    coverage = float(covered.mean())
    fallback = coverage < config.min_coverage or kept.size == 0
    t_re = time.perf_counter()
    if fallback:
        log.warning("completion: supported primitives cover %.3f of the image (< %.3f); falling "
                    "back to linear interpolation of the %d sparse points", coverage,
                    config.min_coverage, sd.size)
        depth, conf = _fill_holes(np.full(camera.shape, np.nan), np.zeros(camera.shape, bool),
                                  sparse)
    else:
        # holes are filled at the primitives' resolution, then the map is resized
        depth_w, conf_w = _fill_holes(dmap, covered, _resample_sparse(uv, sd, camera,
                                                                      prims.camera))
        depth, conf = _upsample(depth_w, conf_w, camera)
    t_fi = time.perf_counter()
    res = CompletionResult(
        depth=depth, confidence=conf, primitives=sub, log_scales=s[kept].copy(),
        n_points=counts[kept].copy(), kept=kept, n_primitives=n, n_sparse=int(sd.size),
        coverage=coverage, method=config.method, frontend=fe_name,
        uses_depth=uses_depth, fallback=fallback,
        timings={"frontend": t_fe - t0, "scales": t_sc - t_fe, "render": t_re - t_sc,
                 "fill": t_fi - t_re, "total": time.perf_counter() - t0},
        solver=solver)
    log.info("%s", res.summary())
    return res
