"""Primitives that bend: log-depth slopes per primitive (``shape_model="slope"``
of :mod:`spgeo.completion`).

A primitive ``i`` with unscaled (integrated) log-depth ``l_i`` and log-scale
``s_i`` gets, where it holds ``min_points`` (>= 3) sparse points, two slopes
``(a_i, b_i)`` of its log-depth in normalised image coordinates::

    log D_i(u) = l_i(u) + s_i + a_i (x(u) - x_i) + b_i (y(u) - y_i),

``x = (u - cx) / fx``, ``y = (v - cy) / fy`` and ``(x_i, y_i)`` the
primitive's anchor.  ``(s_i, a_i, b_i)`` minimise, per primitive, the Huber
cost of the points' log residuals ``log d_k - l_i(u_k)`` (noise ``sigma``, log
units, threshold ``huber_k sigma``, times the caller's point weights) plus the
Gaussian prior ``(a^2 + b^2) / (2 sigma_slope^2)`` (iteratively reweighted least
squares, all primitives at once as batched 3x3 solves).  Primitives with fewer
points keep the caller's scale and no slope: with one or two points the model is
today's scale.  A slope is measured in log-depth per unit of normalised
coordinate: a plane at depth ``Z`` viewed at the image centre, tilted by
``theta`` about the y axis, has ``a = tan(theta)`` there.  A fit that moves the
primitive's depth by more than the factor ``max_ratio`` against the scale-only
depth anywhere in the primitive keeps the scale-only shape.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..primitives import PrimitiveSet

__all__ = ["SlopeFit", "fit_log_slopes"]


@dataclass
class SlopeFit:
    """Result of :func:`fit_log_slopes`.

    Attributes:
        log_scales: (N,) log-scales at the anchors (the caller's where no
            slope was fitted).
        slopes: (N, 2) ``(a, b)`` log-depth per unit normalised coordinate
            (0 where none was fitted).
        bent: (N,) bool, primitives with a fitted slope.
        scaled_log_depth: (M,) metric log-depth per entry of the set (log
            metres; from the caller's log-scales where those are NaN: arbitrary).
    """

    log_scales: np.ndarray
    slopes: np.ndarray
    bent: np.ndarray
    scaled_log_depth: np.ndarray


def _normalised(prims: PrimitiveSet, pix: np.ndarray) -> np.ndarray:
    """(K, 2) normalised coordinates ``((u - cx) / fx, (v - cy) / fy)`` of flat pixels."""
    cam = prims.camera
    pix = np.asarray(pix, dtype=np.int64)
    return np.stack([(pix % cam.width - cam.cx) / cam.fx, (pix // cam.width - cam.cy) / cam.fy], 1)


def _batched_irls(ids, feats, r, w0, n, lam, huber, iterations):
    """(n, 3) per group ``argmin sum w h(f . x - r) + lam (x1^2 + x2^2)``
    (Huber IRLS, threshold ``huber`` in units of the residual); rows of
    groups without data are 0."""
    x = np.zeros((n, 3))
    w = w0.copy()
    ridge = np.diag([1e-9, lam, lam])
    for _ in range(int(iterations)):
        A = np.zeros((n, 9))
        np.add.at(A, ids, (w[:, None, None] * feats[:, :, None] * feats[:, None, :]).reshape(-1, 9))
        b = np.zeros((n, 3))
        np.add.at(b, ids, w[:, None] * r[:, None] * feats)
        x = np.linalg.solve(A.reshape(n, 3, 3) + ridge[None], b[..., None])[..., 0]
        e = np.abs(np.einsum("ka,ka->k", feats, x[ids]) - r)
        w = w0 * np.minimum(1.0, huber / np.maximum(e, 1e-12))
    return x


def fit_log_slopes(prims: PrimitiveSet, point_prim: np.ndarray, point_pix: np.ndarray,
                   point_d: np.ndarray, log_scales: np.ndarray,
                   point_weights: np.ndarray = None, min_points: int = 3,
                   sigma_slope: float = 1.0, sigma: float = 0.03, huber_k: float = 1.345,
                   iterations: int = 5, max_ratio: float = 3.0) -> SlopeFit:
    """Scale and two log-depth slopes per primitive holding ``min_points`` points
    (module docstring).

    Args:
        prims: the primitives (their ``log_depth`` the unscaled shape).
        point_prim: (K,) primitive of each (point, primitive) pair.
        point_pix: (K,) flat pixel index of the point in ``prims.camera``.
        point_d: (K,) sparse depth, metres > 0.
        log_scales: (N,) the scale-only log-scales (NaN: primitive without
            depth, left so).
        point_weights: (K,) weights in [0, 1] (e.g. the graph's outlier
            weights; None: 1).
        min_points: points (pairs with weight > 0.5) a primitive needs for
            slopes (>= 3).
        sigma_slope: prior standard deviation of ``a`` and ``b`` (> 0).
        sigma: noise of the log residuals (> 0); with ``sigma_slope`` it sets
            the prior's weight ``(sigma / sigma_slope)^2`` against one point.
        huber_k: Huber threshold in units of ``sigma`` (> 0).
        iterations: IRLS iterations (>= 1).
        max_ratio: largest factor the slopes may move the depth of any pixel of
            the primitive against its scale-only depth (> 1).
    Returns:
        :class:`SlopeFit`.
    Raises:
        ValueError: bad shapes or parameters.
    """
    n = len(prims)
    s = np.asarray(log_scales, dtype=np.float64).reshape(-1)
    if s.shape != (n,):
        raise ValueError(f"log_scales must have shape ({n},), got {s.shape}")
    if int(min_points) < 3 or not (sigma_slope > 0 and sigma > 0 and huber_k > 0
                                   and max_ratio > 1 and int(iterations) >= 1):
        raise ValueError("fit_log_slopes: need min_points >= 3, sigma_slope, sigma, huber_k > 0, "
                         "max_ratio > 1, iterations >= 1")
    pp = np.asarray(point_prim, dtype=np.int64).reshape(-1)
    pix = np.asarray(point_pix, dtype=np.int64).reshape(-1)
    d = np.asarray(point_d, dtype=np.float64).reshape(-1)
    w0 = np.ones(pp.size) if point_weights is None else np.asarray(point_weights, float).reshape(-1)
    if not (pix.shape == d.shape == w0.shape == pp.shape):
        raise ValueError("fit_log_slopes: point arrays must have one entry per pair")
    L0 = prims.scaled_log_depth(np.where(np.isfinite(s), s, 0.0))
    slopes = np.zeros((n, 2))
    cnt = np.bincount(pp, weights=(w0 > 0.5).astype(float), minlength=n)
    bent = np.isfinite(s) & (cnt >= min_points)
    use = bent[pp]
    if not np.any(use):
        return SlopeFit(s.copy(), slopes, bent, L0)
    pp, pix, d, w0 = pp[use], pix[use], d[use], w0[use]
    anchor_xy = _normalised(prims, prims.anchors)
    xy = _normalised(prims, pix) - anchor_xy[pp]
    l_at = _log_depth_at(prims, pp, pix)
    feats = np.concatenate([np.ones((pp.size, 1)), xy], 1)
    x = _batched_irls(pp, feats, np.log(d) - l_at, w0, n, (sigma / sigma_slope) ** 2,
                      huber_k * sigma, iterations)
    pid = prims.primitive_ids
    exy = _normalised(prims, prims.pixels) - anchor_xy[pid]
    on = bent[pid]
    L = L0.copy()
    L[on] = prims.log_depth[on] + x[pid[on], 0] + np.einsum("ka,ka->k", exy[on], x[pid[on], 1:])
    bad = np.bincount(pid[on], weights=np.abs(L[on] - L0[on]) > np.log(max_ratio), minlength=n)
    bent &= bad == 0
    L = np.where(bent[pid], L, L0)
    s_out = s.copy()
    s_out[bent] = x[bent, 0]
    slopes[bent] = x[bent, 1:]
    return SlopeFit(s_out, slopes, bent, L)


def _log_depth_at(prims: PrimitiveSet, pp: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """(K,) unscaled log-depth of primitive ``pp`` at flat pixel ``pix`` (each pixel
    must lie in its primitive)."""
    npix = prims.camera.width * prims.camera.height
    key = prims.primitive_ids * npix + prims.pixels
    order = np.argsort(key, kind="stable")
    ent = order[np.searchsorted(key[order], pp * npix + pix)]
    return prims.log_depth[ent]
