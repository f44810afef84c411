"""Per-primitive log-scale fitting of :mod:`spgeo.completion`.

A primitive with unscaled log-depth ``l`` gets the log-scale ``s`` that best
explains the sparse depths ``d`` inside its mask: ``log d ~ s + l``, either
as a per-primitive median (:func:`grouped_median`) or as a robust joint
GTSAM solve (:func:`solve_log_scales_joint`).
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..primitives import PrimitiveSet

__all__ = ["working_pixels", "sparse_point_assignments", "grouped_median",
           "solve_log_scales_joint", "flat_primitives"]


def working_pixels(uv: np.ndarray, camera: PinholeCamera, target: PinholeCamera) -> np.ndarray:
    """(K,) flat pixel index ``v * width + u`` in ``target`` (a resize of
    ``camera``) of the pixels ``uv`` (K, 2) of ``camera``: ``cv2.resize``
    convention, rounded and clipped to the image."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    sx, sy = target.width / camera.width, target.height / camera.height
    u = np.clip(np.rint((uv[:, 0] + 0.5) * sx - 0.5), 0, target.width - 1).astype(np.int64)
    v = np.clip(np.rint((uv[:, 1] + 0.5) * sy - 0.5), 0, target.height - 1).astype(np.int64)
    return v * target.width + u


def sparse_point_assignments(primitives: PrimitiveSet, uv: np.ndarray, camera: PinholeCamera):
    """Which primitives contain each sparse point.

    ``uv`` (K, 2) are pixel coordinates in ``camera`` (the input image); they
    are mapped to the primitives' (possibly resized) camera with the
    ``cv2.resize`` convention and rounded.  Returns ``(point, prim, l)``: one
    entry per (point, containing primitive) pair — overlapping primitives each
    get the point — with ``l`` the primitive's unscaled log-depth there.
    """
    flat = working_pixels(uv, camera, primitives.camera)
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
    that has points (keys :func:`spgeo.graph.keys.scale_key` ``(i)``).

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

    from ..factors.sparse_depth import SparseDepthFactor
    from ..graph.keys import scale_key

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
        key = scale_key(i)
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


def flat_primitives(prims: PrimitiveSet, tol: float = 1e-9) -> np.ndarray:
    """(N,) bool: primitives whose unscaled log-depth spans at most ``tol``
    (fronto-parallel patches: the front-end knew no shape for them)."""
    n = len(prims)
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, prims.primitive_ids, prims.log_depth)
    np.maximum.at(hi, prims.primitive_ids, prims.log_depth)
    return hi - lo <= tol
