"""Robust log-scales with neighbour coupling (``method="graph"`` of
:mod:`spgeo.completion`).

Sparse points from a keypoint tracker sit on image corners, i.e. mostly on
region borders, where the depth may belong to the neighbouring surface; a
primitive with one or two such points then gets a wrong scale.  Here all
log-scales ``s`` are solved together from

* one **data** term per (point ``k``, containing primitive ``i``):
  ``(log d_k - l_i(u_k) - s_i) / sigma``;
* one **coupling** term per pair of adjacent primitives ``(i, j)`` whose shared
  boundary is a weak image edge: the mean log-depth step across the boundary,
  ``(s_i - s_j + c_ij) / sigma_c`` with ``c_ij`` the mean of
  ``l_i(p) - l_j(q)`` over the boundary pixel pairs ``(p, q)``, weighted by
  ``coupling * exp(-(step_ij / edge_scale)^2)`` (``step_ij`` the mean
  absolute colour difference across the boundary; pairs with
  ``step_ij > 2 edge_scale`` are not coupled);

with Cauchy (Lorentzian) losses by iteratively reweighted least squares on one
sparse ``N x N`` system.  A point that disagrees with its primitive's
neighbours is down-weighted; primitives without points take their scale
through the coupling.  Primitives in a connected component (of the coupling
graph) without any point stay NaN.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve

from ..primitives import PrimitiveSet
from .planes import (MODE_NONE, MODE_PLANE, MODE_SCALE, PlaneFit, apply_planes, pixel_rays,
                     primitive_adjacency)
from .scales import flat_primitives

__all__ = ["GraphScales", "WeakEdges", "weak_edges", "solve_log_scales_graph",
           "solve_planes_graph"]


@dataclass
class GraphScales:
    """Result of :func:`solve_log_scales_graph`.

    Attributes:
        log_scales: (N,) log-scales (NaN: no point reaches the primitive).
        point_weights: (K,) final IRLS weight of each (point, primitive)
            pair in [0, 1] (small: an outlier).
        n_edges: coupled primitive pairs.
    """

    log_scales: np.ndarray
    point_weights: np.ndarray
    n_edges: int


@dataclass
class WeakEdges:
    """Weakly separated neighbours: per coupled pair of primitives (``edge_*``,
    ``edge_a < edge_b``) and per boundary pixel pair (entries ``ent_p`` of
    ``edge_a``'s primitive, ``ent_q`` of ``edge_b``'s, ``pair_edge``)."""

    edge_a: np.ndarray
    edge_b: np.ndarray
    edge_weight: np.ndarray
    edge_pairs: np.ndarray
    ent_p: np.ndarray
    ent_q: np.ndarray
    pair_edge: np.ndarray


def weak_edges(prims: PrimitiveSet, image: np.ndarray, edge_scale: float) -> WeakEdges:
    """Adjacent primitive pairs with mean colour step ``<= 2 edge_scale`` and
    weight ``exp(-(step / edge_scale)^2)`` (:class:`WeakEdges`; the completion's
    coupling and the few-view SfM's continuity factors).  ``image``: (H, W[, C])
    float in [0, 1] at ``prims.camera``'s size (else ``ValueError``);
    ``edge_scale`` (intensity units) > 0."""
    n = len(prims)
    img = np.asarray(image, dtype=np.float64)
    img = img[..., None] if img.ndim == 2 else img
    p, q, a, b = primitive_adjacency(prims, img)
    one = a < b
    p, q, a, b = p[one], q[one], a[one], b[one]
    flat = img.reshape(-1, img.shape[2])
    step = np.abs(flat[p] - flat[q]).mean(1)
    lab_ent = np.full(prims.camera.width * prims.camera.height, -1, np.int64)
    own = prims.label_image().reshape(-1)[prims.pixels] == prims.primitive_ids
    lab_ent[prims.pixels[own]] = np.flatnonzero(own)
    uk, inv = np.unique(a * n + b, return_inverse=True)
    cnt = np.bincount(inv, minlength=uk.size)
    mstep = np.bincount(inv, weights=step, minlength=uk.size) / np.maximum(cnt, 1)
    keep = mstep <= 2 * edge_scale
    new_id = np.cumsum(keep) - 1
    sel = keep[inv]
    return WeakEdges((uk // n)[keep], (uk % n)[keep], np.exp(-(mstep[keep] / edge_scale) ** 2),
                  cnt[keep], lab_ent[p[sel]], lab_ent[q[sel]], new_id[inv[sel]])


def _cauchy(r: np.ndarray, c: float) -> np.ndarray:
    return 1.0 / (1.0 + (r / c) ** 2)


def solve_log_scales_graph(prims: PrimitiveSet, image: np.ndarray, point_prim: np.ndarray,
                           point_l: np.ndarray, point_d: np.ndarray,
                           initial: Optional[np.ndarray] = None, sigma: float = 0.03,
                           sigma_c: float = 0.05, coupling: float = 1.0,
                           edge_scale: float = 0.08, iterations: int = 10) -> GraphScales:
    """Robust coupled log-scales (module docstring).

    Args:
        prims: the primitives (working resolution).
        image: (H, W[, C]) float image in [0, 1] at ``prims.camera``'s size.
        point_prim, point_l, point_d: per (point, containing primitive) pair:
            primitive index, unscaled log-depth there, depth (metres > 0).
        initial: (N,) starting log-scales (NaN allowed), e.g. the medians.
        sigma, sigma_c: Cauchy scales of the data / coupling residuals (log
            units, > 0).
        coupling: weight of a coupling term relative to one point (>= 0).
        edge_scale: colour-step scale of the coupling weight (> 0).
        iterations: IRLS iterations (>= 1).
    Returns:
        :class:`GraphScales`.
    """
    for name, v in (("sigma", sigma), ("sigma_c", sigma_c), ("edge_scale", edge_scale)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v}")
    if not (np.isfinite(coupling) and coupling >= 0) or int(iterations) < 1:
        raise ValueError(f"coupling must be >= 0 and iterations >= 1, got {coupling}, "
                         f"{iterations}")
    n = len(prims)
    pp = np.asarray(point_prim, dtype=np.int64).reshape(-1)
    y = np.log(np.asarray(point_d, dtype=np.float64).reshape(-1)) - np.asarray(
        point_l, dtype=np.float64).reshape(-1)
    out = np.full(n, np.nan)
    if n == 0 or pp.size == 0:
        return GraphScales(out, np.ones(pp.size), 0)
    e = weak_edges(prims, image, edge_scale) if coupling > 0 else None
    ei = ej = np.zeros(0, np.int64)
    ec = ew = np.zeros(0)
    if e is not None and e.edge_a.size:
        dl = prims.log_depth[e.ent_p] - prims.log_depth[e.ent_q]
        ei, ej = e.edge_a, e.edge_b
        ec = np.bincount(e.pair_edge, weights=dl, minlength=ei.size) / e.edge_pairs
        ew = coupling * e.edge_weight

    # components without points stay NaN; pin each component's gauge by its points
    G = sp.coo_matrix((np.ones(ei.size), (ei, ej)), shape=(n, n))
    ncomp, comp = connected_components(G, directed=False)
    has_pt = np.bincount(comp[pp], minlength=ncomp) > 0
    active = has_pt[comp]

    s0 = np.zeros(n) if initial is None else np.nan_to_num(np.asarray(initial, float), nan=0.0)
    s = s0.copy()
    wd = _cauchy(y - s0[pp], sigma) if initial is not None else np.ones(pp.size)
    we = np.ones(ei.size)
    for _ in range(int(iterations)):
        dw = wd / sigma ** 2
        cw = ew * we / sigma_c ** 2
        diag = np.bincount(pp, weights=dw, minlength=n) + np.bincount(
            ei, weights=cw, minlength=n) + np.bincount(ej, weights=cw, minlength=n)
        rhs = np.bincount(pp, weights=dw * y, minlength=n) - np.bincount(
            ei, weights=cw * ec, minlength=n) + np.bincount(ej, weights=cw * ec, minlength=n)
        diag += 1e-9 + (~active) * 1.0
        H = sp.coo_matrix((np.concatenate([diag, -cw, -cw]),
                           (np.concatenate([np.arange(n), ei, ej]),
                            np.concatenate([np.arange(n), ej, ei]))), shape=(n, n)).tocsc()
        s = spsolve(H, rhs)
        wd = _cauchy(y - s[pp], sigma)
        we = _cauchy(s[ei] - s[ej] + ec, sigma_c)
    out[active] = s[active]
    return GraphScales(out, wd, int(ei.size))


def solve_planes_graph(prims: PrimitiveSet, image: np.ndarray, point_prim: np.ndarray,
                       point_pix: np.ndarray, point_d: np.ndarray, log_scales: np.ndarray,
                       point_weights: Optional[np.ndarray] = None, prior: float = 0.1,
                       coupling: float = 0.03, prior_flat: Optional[float] = None, sigma: float = 0.03, edge_scale: float = 0.08,
                       iterations: int = 5, max_ratio: float = 3.0) -> PlaneFit:
    """Scale-and-plane models of all primitives solved together (``method="graph"``
    with ``shape_model="plane"``).

    Each primitive has ``rho_i(u) = alpha_i rho0_i(u) + delta_i . r(u)``
    (:mod:`spgeo.completion.planes`).  Terms, all relative inverse-depth
    residuals with Cauchy losses (scale ``sigma``), IRLS on one sparse
    ``4N x 4N`` system:

    * data: ``rho_i(u_k) d_k - 1`` per (point, primitive), starting from the
      caller's ``point_weights`` (e.g. :func:`solve_log_scales_graph`'s);
    * continuity: ``(rho_a(p) - rho_b(q)) / rho_ref`` per boundary pixel pair
      of weakly separated neighbours (see :func:`solve_log_scales_graph`),
      weight ``coupling * exp(-(step / edge_scale)^2)``; ``rho_ref`` from
      ``log_scales``;
    * prior: ``prior * |delta_i / rho_ref_i|^2`` (the shape's own orientation);
      primitives whose shape is constant (fronto-parallel: their front-end
      knew no normal) use ``prior_flat`` instead when given.

    Primitives with NaN ``log_scales`` are left out (``MODE_NONE``); a model
    failing :func:`spgeo.completion.planes.apply_planes`'s checks keeps the
    scale-only shape (``MODE_SCALE``).  Returns a
    :class:`~spgeo.completion.planes.PlaneFit`.
    """
    for name, v in (("sigma", sigma), ("edge_scale", edge_scale)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v}")
    if not (prior >= 0 and coupling >= 0 and (prior_flat is None or prior_flat >= 0)) \
            or int(iterations) < 1:
        raise ValueError(f"prior and coupling must be >= 0 and iterations >= 1, got {prior}, "
                         f"{coupling}, {iterations}")
    n = len(prims)
    s = np.asarray(log_scales, dtype=np.float64).reshape(-1)
    if s.shape != (n,):
        raise ValueError(f"log_scales must have shape ({n},), got {s.shape}")
    act = np.isfinite(s)
    L1 = prims.scaled_log_depth(np.where(act, s, 0.0))
    mode = np.where(act, MODE_SCALE, MODE_NONE).astype(np.int8)
    hyp = np.full(n, -1, np.int64)
    pp = np.asarray(point_prim, dtype=np.int64).reshape(-1)
    if not np.any(act) or pp.size == 0:
        return PlaneFit(L1, mode, hyp)
    rho0 = np.exp(-prims.log_depth)
    pp, fd, wd0 = _data_rows(prims, act, rho0, pp, point_pix, point_d, point_weights)
    cont = _continuity_rows(prims, image, act, L1, rho0, coupling, edge_scale)
    ridge = _plane_ridge(prims, act, s, prior, prior_flat)
    J, b = _plane_system(n, pp, fd, cont)
    x = _plane_irls(n, J, b, pp.size, wd0, cont, ridge, L1, sigma, iterations)
    X = x.reshape(n, 4)
    X[~act] = np.nan
    L, good = apply_planes(prims, X, L1, max_ratio)
    mode[good] = MODE_PLANE
    return PlaneFit(L, mode, hyp)


@dataclass
class _Continuity:
    """Continuity rows of :func:`solve_planes_graph`, one per boundary pixel pair
    of weakly separated active neighbours: the pair's primitives ``ca``, ``cb``,
    entries ``ep``, ``eq``, reference inverse depth ``rref``, features ``gp``,
    ``gq`` (M, 4) on each primitive's unknowns and base weight ``cw0``."""

    ca: np.ndarray
    cb: np.ndarray
    ep: np.ndarray
    eq: np.ndarray
    rref: np.ndarray
    gp: np.ndarray
    gq: np.ndarray
    cw0: np.ndarray


def _data_rows(prims: PrimitiveSet, act: np.ndarray, rho0: np.ndarray, pp: np.ndarray,
               point_pix: np.ndarray, point_d: np.ndarray, point_weights: Optional[np.ndarray]):
    """Data rows of :func:`solve_planes_graph` for the points of active primitives:
    ``(their primitives (K,), features (K, 4) on the primitive's 4 unknowns,
    start weights (K,))``."""
    pix = np.asarray(point_pix, dtype=np.int64).reshape(-1)
    d = np.asarray(point_d, dtype=np.float64).reshape(-1)
    wd0 = np.ones(pp.size) if point_weights is None else np.asarray(point_weights, float)
    use = act[pp]
    pp, pix, d, wd0 = pp[use], pix[use], d[use], wd0[use]
    npix = prims.camera.width * prims.camera.height
    key = prims.primitive_ids * npix + prims.pixels
    order = np.argsort(key, kind="stable")
    ent = order[np.searchsorted(key[order], pp * npix + pix)]
    # data rows: (K, 4) features on the 4 unknowns of primitive pp
    fd = np.concatenate([rho0[ent, None], pixel_rays(prims, pix)], 1) * d[:, None]
    return pp, fd, wd0


def _continuity_rows(prims: PrimitiveSet, image: np.ndarray, act: np.ndarray, L1: np.ndarray,
                     rho0: np.ndarray, coupling: float, edge_scale: float) -> _Continuity:
    """:class:`_Continuity` (empty when ``coupling`` is 0 or no edge is weak)."""
    e = weak_edges(prims, image, edge_scale) if coupling > 0 else None
    if e is not None and e.edge_a.size:
        ok = act[e.edge_a[e.pair_edge]] & act[e.edge_b[e.pair_edge]]
        ep, eq, pe = e.ent_p[ok], e.ent_q[ok], e.pair_edge[ok]
        ca, cb = e.edge_a[pe], e.edge_b[pe]
        rref = np.exp(-0.5 * (L1[ep] + L1[eq]))
        gp = np.concatenate([rho0[ep, None], pixel_rays(prims, prims.pixels[ep])], 1) / rref[:, None]
        gq = np.concatenate([rho0[eq, None], pixel_rays(prims, prims.pixels[eq])], 1) / rref[:, None]
        cw0 = coupling * e.edge_weight[pe]
    else:
        ca = cb = ep = eq = np.zeros(0, np.int64)
        rref = np.ones(0)
        gp = gq = np.zeros((0, 4))
        cw0 = np.zeros(0)
    return _Continuity(ca, cb, ep, eq, rref, gp, gq, cw0)


def _plane_ridge(prims: PrimitiveSet, act: np.ndarray, s: np.ndarray, prior: float,
                 prior_flat: Optional[float]) -> np.ndarray:
    """(4N,) diagonal regulariser of :func:`solve_planes_graph`: the orientation
    prior on active primitives' planar unknowns, a tiny ridge on their scales,
    and ones on inactive primitives (decoupled, solved to zero)."""
    n = len(prims)
    rho_ref = np.exp(-s[act])
    ridge = np.zeros(4 * n)
    ridge_idx = (4 * np.flatnonzero(act)[:, None] + np.arange(1, 4)[None]).ravel()
    pr = np.full(n, float(prior))
    if prior_flat is not None:
        pr[flat_primitives(prims)] = prior_flat
    ridge[ridge_idx] = np.repeat(pr[act] / rho_ref ** 2, 3)
    ridge[4 * np.flatnonzero(~act)] = 1.0   # inactive primitives: decoupled, zero
    ridge[(4 * np.flatnonzero(~act)[:, None] + np.arange(1, 4)[None]).ravel()] = 1.0
    ridge[4 * np.flatnonzero(act)] = 1e-12
    return ridge


def _plane_system(n: int, pp: np.ndarray, fd: np.ndarray, c: _Continuity):
    """Sparse Jacobian ``J`` ((K + M) x 4N: data rows, then continuity rows) and
    right-hand side ``b`` (1 per data row, 0 per continuity row)."""
    cols4 = np.arange(4)
    rows_d = np.repeat(np.arange(pp.size), 4)
    cols_d = (4 * pp[:, None] + cols4).ravel()
    m = c.ca.size
    rows_c = np.repeat(np.arange(pp.size, pp.size + m), 8)
    cols_c = np.concatenate([4 * c.ca[:, None] + cols4, 4 * c.cb[:, None] + cols4], 1).ravel()
    vals_c = np.concatenate([c.gp, -c.gq], 1).ravel()
    J = sp.csr_matrix((np.concatenate([fd.ravel(), vals_c]),
                       (np.concatenate([rows_d, rows_c]), np.concatenate([cols_d, cols_c]))),
                      shape=(pp.size + m, 4 * n))
    b = np.concatenate([np.ones(pp.size), np.zeros(m)])
    return J, b


def _plane_irls(n: int, J, b: np.ndarray, k: int, wd0: np.ndarray, c: _Continuity,
                ridge: np.ndarray, L1: np.ndarray, sigma: float, iterations: int) -> np.ndarray:
    """(4N,) unknowns by Cauchy IRLS on ``J x = b`` (``k`` data rows first),
    data weights starting at ``wd0``, continuity weights at the scale-only
    solution's steps."""
    m = c.ca.size
    wd = wd0.copy()
    # continuity weights start from the scale-only solution's steps across each boundary
    wc = _cauchy((np.exp(-L1[c.ep]) - np.exp(-L1[c.eq])) / c.rref, sigma) if m else np.ones(0)
    x = np.zeros(4 * n)
    for _ in range(int(iterations)):
        W = sp.diags(np.concatenate([wd, c.cw0 * wc]))
        H = (J.T @ W @ J + sp.diags(ridge)).tocsc()
        x = spsolve(H, J.T @ (W @ b))
        r = J @ x - b
        wd = _cauchy(r[:k], sigma)
        wc = _cauchy(r[k:], sigma)
    return x
