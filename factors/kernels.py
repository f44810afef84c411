"""Compiled (numba) kernels of the photometric hot path (docs/design.md §4).

One fused pass per evaluation shared by the photometric factors
(:func:`spgeo.factors.photometric.photometric_rows`, hence
:class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` and
:class:`~spgeo.factors.photometric_group.PhotometricFactorGroup`) and the
tracker (:class:`spgeo.vo.tracking.TrackingCost`), so both compute the same cost:

* :func:`residual_pass`: warp ``Y = R X + t``, projection, bilinear sample with
  its exact derivatives, photometric error, per-primitive normalisation,
  Huber IRLS weight, residual row and ``g = de/dY``;
* :func:`jacobian_rows`: the factor's Jacobian rows (both poses, shape,
  brightness) from ``g``;
* :func:`pose_normal_equations`: the tracker's rows (target pose, brightness)
  with ``J^T J`` and ``J^T e`` accumulated in the same loop.

The formulas, validity rules and outputs are those of the numpy reference
:func:`spgeo.factors.photometric.photometric_rows_numpy` (tested to 1e-6,
values and Jacobians).  Every kernel writes into preallocated outputs and is
compiled with ``cache=True`` (the machine code is stored next to this file
and loaded by later processes).  Without numba, :data:`AVAILABLE` is False,
:func:`resolve_backend` answers ``"numpy"`` and a warning is logged once.
"""
from __future__ import annotations

import logging

import numpy as np

__all__ = ["AVAILABLE", "BACKENDS", "NORMALISE_CODES", "resolve_backend",
           "residual_pass", "jacobian_rows", "pose_normal_equations", "chunk_grams"]

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numba", "numpy")
# PhotometricConfig.normalise -> the kernels' integer code
NORMALISE_CODES = {"valid": 0, "all": 1, "none": 2}

try:
    import numba
    AVAILABLE = True
except ImportError:   # pragma: no cover - numba is an install requirement
    numba = None
    AVAILABLE = False
    log.warning("numba is not importable: the photometric kernels fall back to numpy")


def resolve_backend(name: str) -> str:
    """``"numba"`` or ``"numpy"`` for a configured backend name (``"auto"``:
    numba when importable); asking for numba without it gives numpy."""
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    if name == "numpy" or not AVAILABLE:
        return "numpy"
    return "numba"


def _njit(fn):
    return numba.njit(cache=True, nogil=True)(fn) if AVAILABLE else fn


@_njit
def _huber_weight(r, huber, delta):
    """Square-root IRLS weight of one residual (``robust_weights``)."""
    if not huber:
        return 1.0
    a = abs(r)
    if a <= delta:
        return 1.0
    return np.sqrt(delta / max(a, 1e-300))


@_njit
def _warp_and_sample(X, shape_valid, R, t, img, fx, fy, cx, cy, ref, ea, b, ids, min_depth,
                     counts, r_out, valid, behind, I_out, Y, inv_zs, gus, gvs):
    """First pass of :func:`residual_pass`: per row the target-frame point ``Y``,
    ``behind``, ``valid``, the sampled intensity ``I_out``, the photometric error
    ``r_out`` and ``1 / z`` and the image gradient (``inv_zs``, ``gus``, ``gvs``);
    ``counts`` the valid or behind rows per primitive."""
    K = X.shape[0]
    h, wd = img.shape
    has_shape_valid = shape_valid.shape[0] == K
    has_ids = ids.shape[0] == K
    for k in range(K):
        x0 = X[k, 0]
        x1 = X[k, 1]
        x2 = X[k, 2]
        y0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2 + t[0]
        y1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2 + t[1]
        y2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2 + t[2]
        Y[k, 0] = y0
        Y[k, 1] = y1
        Y[k, 2] = y2
        bh = (has_shape_valid and not shape_valid[k]) or not (y2 > min_depth)
        behind[k] = bh
        ok = False
        val = 0.0
        gu = 0.0
        gv = 0.0
        inv_z = 0.0
        if not bh:
            inv_z = 1.0 / y2
            u = fx * y0 * inv_z + cx
            v = fy * y1 * inv_z + cy
            if u >= 0 and u <= wd - 1 and v >= 0 and v <= h - 1:
                ok = True
                u0 = min(int(u), wd - 2)
                v0 = min(int(v), h - 2)
                au = u - u0
                av = v - v0
                p00 = img[v0, u0]
                p01 = img[v0, u0 + 1]
                p10 = img[v0 + 1, u0]
                p11 = img[v0 + 1, u0 + 1]
                d0 = p01 - p00
                d1 = p11 - p10
                top = p00 + d0 * au
                bot = p10 + d1 * au
                val = top + (bot - top) * av
                gu = d0 * (1 - av) + d1 * av
                gv = bot - top
        valid[k] = ok
        inv_zs[k] = inv_z
        gus[k] = gu
        gvs[k] = gv
        I_out[k] = val
        r_out[k] = ea * val + b - ref[k]
        if ok or bh:
            counts[ids[k] if has_ids else 0] += 1.0


@_njit
def _group_scales(counts, group_pixels, normalise, pixel_sigma):
    """Row scale per primitive for the ``normalise`` code (:data:`NORMALISE_CODES`)."""
    n_groups = group_pixels.shape[0]
    scales = np.empty(n_groups)
    for i in range(n_groups):
        if normalise == 0:
            scales[i] = 1.0 / np.sqrt(max(counts[i], 1.0))
        elif normalise == 2:
            scales[i] = 1.0 / pixel_sigma
        else:
            scales[i] = 1.0 / np.sqrt(group_pixels[i])
    return scales


@_njit
def _weighted_rows(K, ids, scales, ea, fx, fy, huber, delta, pen_row, r_out, valid, behind,
                   inv_zs, gus, gvs, Y, e, w_out, g):
    """Second pass of :func:`residual_pass` over its ``K`` rows: Huber-weighted rows
    ``e``, weights ``w_out`` and ``g = de/dY``; returns ``(|e|^2, number of valid rows)``."""
    has_ids = ids.shape[0] == K
    sq = 0.0
    n_valid = 0
    for k in range(K):
        s = scales[ids[k] if has_ids else 0]
        if valid[k]:
            n_valid += 1
            r = r_out[k]
            wk = s * _huber_weight(r, huber, delta)
            w_out[k] = wk
            e[k] = wk * r
            inv_z = inv_zs[k]
            wg = wk * ea * inv_z
            du = wg * gus[k] * fx
            dv = wg * gvs[k] * fy
            g[k, 0] = du
            g[k, 1] = dv
            g[k, 2] = -(du * Y[k, 0] + dv * Y[k, 1]) * inv_z
        else:
            r_out[k] = 0.0
            w_out[k] = 0.0
            e[k] = s * pen_row if behind[k] else 0.0
            g[k, 0] = 0.0
            g[k, 1] = 0.0
            g[k, 2] = 0.0
        sq += e[k] * e[k]
    return sq, n_valid


@_njit
def residual_pass(X, shape_valid, R, t, img, fx, fy, cx, cy, ref, ea, b,
                  ids, group_pixels, normalise, pixel_sigma, huber, delta, min_depth,
                  behind_penalty, e, r_out, valid, behind, w_out, I_out, Y, g):
    """Residual rows of the reference points ``X`` (K, 3) seen from the target.

    Inputs: ``shape_valid`` (K,) bool or empty (all valid); ``R``, ``t``:
    ``T_tgt_ref``; ``img`` (H, W) target image and its intrinsics; ``ref``
    (K,) reference intensities; ``ea = exp(-a)``, ``b``: brightness; ``ids``
    (K,) primitive of each row or empty (one primitive); ``group_pixels``
    (n_groups,) ``|Omega|`` per primitive; ``normalise``: code of
    :data:`NORMALISE_CODES`; Huber (``huber``, ``delta``), ``min_depth`` and
    ``behind_penalty`` as in ``PhotometricConfig``.

    Outputs (K,): ``e`` residual rows, ``r_out`` photometric error (0 where
    invalid), ``valid``, ``behind``, ``w_out`` row weights, ``I_out`` sampled
    target intensity (0 where invalid); (K, 3): ``Y`` target-frame points and
    ``g = de/dY`` (weights held fixed).  Returns ``(|e|^2, number of valid rows)``.
    """
    K = X.shape[0]
    n_groups = group_pixels.shape[0]
    counts = np.zeros(n_groups)
    inv_zs = np.empty(K)
    gus = np.empty(K)
    gvs = np.empty(K)
    _warp_and_sample(X, shape_valid, R, t, img, fx, fy, cx, cy, ref, ea, b, ids, min_depth,
                     counts, r_out, valid, behind, I_out, Y, inv_zs, gus, gvs)
    pen_row = _huber_weight(behind_penalty, huber, delta) * behind_penalty
    scales = _group_scales(counts, group_pixels, normalise, pixel_sigma)
    return _weighted_rows(K, ids, scales, ea, fx, fy, huber, delta, pen_row, r_out, valid,
                          behind, inv_zs, gus, gvs, Y, e, w_out, g)


@_njit
def jacobian_rows(X, dX, R, Y, g, w, I_t, ea, J_ref, J_tgt, J_shape, J_b):
    """The factor's Jacobian rows from :func:`residual_pass`'s ``Y``, ``g``,
    weights ``w`` and samples ``I_t``: ``J_ref = [X x R^T g, R^T g]``,
    ``J_tgt = [g x Y, -g]``, ``J_shape = (R^T g) . dX`` (``dX`` (K, 3, dim)),
    ``J_b = (-w exp(-a) I_t, w)``.  An output with 0 rows is skipped."""
    K = X.shape[0]
    do_ref = J_ref.shape[0] == K
    do_tgt = J_tgt.shape[0] == K
    do_shape = J_shape.shape[0] == K
    do_b = J_b.shape[0] == K
    dim = dX.shape[2]
    for k in range(K):
        g0 = g[k, 0]
        g1 = g[k, 1]
        g2 = g[k, 2]
        q0 = g0 * R[0, 0] + g1 * R[1, 0] + g2 * R[2, 0]      # R^T g
        q1 = g0 * R[0, 1] + g1 * R[1, 1] + g2 * R[2, 1]
        q2 = g0 * R[0, 2] + g1 * R[1, 2] + g2 * R[2, 2]
        if do_ref:
            x0 = X[k, 0]
            x1 = X[k, 1]
            x2 = X[k, 2]
            J_ref[k, 0] = x1 * q2 - x2 * q1
            J_ref[k, 1] = x2 * q0 - x0 * q2
            J_ref[k, 2] = x0 * q1 - x1 * q0
            J_ref[k, 3] = q0
            J_ref[k, 4] = q1
            J_ref[k, 5] = q2
        if do_tgt:
            y0 = Y[k, 0]
            y1 = Y[k, 1]
            y2 = Y[k, 2]
            J_tgt[k, 0] = g1 * y2 - g2 * y1
            J_tgt[k, 1] = g2 * y0 - g0 * y2
            J_tgt[k, 2] = g0 * y1 - g1 * y0
            J_tgt[k, 3] = -g0
            J_tgt[k, 4] = -g1
            J_tgt[k, 5] = -g2
        if do_shape:
            for j in range(dim):
                J_shape[k, j] = q0 * dX[k, 0, j] + q1 * dX[k, 1, j] + q2 * dX[k, 2, j]
        if do_b:
            J_b[k, 0] = -w[k] * ea * I_t[k]
            J_b[k, 1] = w[k]


def _njit_reassoc(fn):
    # reassociation only (vectorised sums): results change at rounding level
    return numba.njit(cache=True, nogil=True, fastmath={"reassoc"})(fn) if AVAILABLE else fn


@_njit_reassoc
def _gram(Jt, e, H, grad):
    """``H = Jt Jt^T``, ``grad = Jt e`` for ``Jt`` (m, K)."""
    m, K = Jt.shape
    for i in range(m):
        gi = 0.0
        for k in range(K):
            gi += Jt[i, k] * e[k]
        grad[i] = gi
        for j in range(i, m):
            s = 0.0
            for k in range(K):
                s += Jt[i, k] * Jt[j, k]
            H[i, j] = s
            H[j, i] = s


@_njit
def pose_normal_equations(Y, g, w, I_t, ea, e, Jt, H, grad):
    """The tracker's rows, transposed: ``Jt`` (6|8, K): the target-pose rows
    of :func:`jacobian_rows` then, with 8 rows, the brightness rows;
    ``H = J^T J`` and ``grad = J^T e`` (overwritten)."""
    empty = np.empty((0, Jt.shape[0]))
    J_b = Jt[6:].T if Jt.shape[0] == 8 else empty
    jacobian_rows(Y, np.empty((0, 3, 1)), np.eye(3), Y, g, w, I_t, ea, empty, Jt[:6].T,
                  empty, J_b)
    _gram(Jt, e, H, grad)


@_njit
def chunk_grams(A, J_shape, offsets, chunk_rows, G_ss, G_sa, AtA):
    """Gram blocks of a :class:`PhotometricFactorGroup`'s rows for its
    square-root chunks: ``A`` (K, m + 1) is ``[pose / brightness Jacobians |
    e]``, ``J_shape`` (K, d).  Writes, per primitive ``p`` (rows
    ``offsets[p]:offsets[p+1]``), ``G_ss[p] = S^T S`` and ``G_sa[p] = S^T A``;
    per chunk ``c`` (rows ``chunk_rows[c]:chunk_rows[c+1]``), ``AtA[c] = A^T A``."""
    m1 = A.shape[1]
    d = J_shape.shape[1]
    G_ss[:] = 0.0
    G_sa[:] = 0.0
    acc = np.zeros((m1, m1))          # local accumulators: no aliasing with the inputs
    gsa = np.zeros((d, m1))
    gss = np.zeros((d, d))
    a = np.empty(m1)
    s = np.empty(d)
    c = 0
    for p in range(offsets.shape[0] - 1):
        for k in range(offsets[p], offsets[p + 1]):
            while k >= chunk_rows[c + 1]:
                AtA[c] = acc
                acc[:] = 0.0
                c += 1
            for i in range(m1):
                a[i] = A[k, i]
            for i in range(d):
                s[i] = J_shape[k, i]
            for i in range(m1):
                ai = a[i]
                for j in range(m1):
                    acc[i, j] += ai * a[j]
            for i in range(d):
                si = s[i]
                for j in range(d):
                    gss[i, j] += si * s[j]
                for j in range(m1):
                    gsa[i, j] += si * a[j]
        G_ss[p] = gss
        G_sa[p] = gsa
        gss[:] = 0.0
        gsa[:] = 0.0
    AtA[c] = acc
