"""Per-primitive planes from sparse depth (the ``shape_model="plane"`` option of
:mod:`spgeo.completion`).

Every primitive ``i`` has an unscaled log-depth ``l_i`` (its integrated
shape: the front-end's normals live in it) and hence an unscaled inverse depth
``rho0_i(u) = exp(-l_i(u))``.  Its metric inverse depth is modelled as

    ``rho_i(u) = alpha_i * rho0_i(u) + delta_i . r(u)``,   ``r(u) = K^-1 [u, v, 1]``,

i.e. the shape, scaled, plus a planar inverse-depth correction (a plane in
camera space is exactly ``theta . r``; a planar shape stays a plane whose
normal moves away from the shape's own as ``delta`` grows).  With the sparse
depths ``d_k`` inside the primitive:

* ``>= min_points`` points: ``(alpha, delta)`` by iteratively reweighted least
  squares (Huber on the relative inverse-depth residual
  ``(rho(u_k) d_k - 1)``) with the ridge prior ``prior * |delta / rho_bar|^2``
  (``rho_bar`` the median inverse depth of the points): it pulls the plane
  towards the shape's own orientation, so nearly collinear points fix the
  tilt along their line only.  If several normal hypotheses are given
  (``hypotheses``), each defines a planar ``rho0`` and the one with the lowest
  robust cost wins.  A fit whose inverse depth is not positive on every pixel
  of the primitive, or that moves the primitive's depth by more than
  ``max_ratio`` against the scale-only fit, is replaced by the scale-only fit.
* fewer points (but at least one): only the scale (``delta = 0``), from the
  caller's log-scales (the median of :mod:`spgeo.completion.scales`).
* no point: :func:`lend_across_weak_edges` lets an adjacent supported
  primitive whose shared boundary is a weak image edge (mean absolute colour
  difference of the pixel pairs across it below ``edge_threshold``) lend its
  depth: the empty primitive's scale is the median log-depth ratio along
  that boundary (its own shape kept).  Repeated ``rounds`` times, so depth
  spreads across several weak edges.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from ..primitives import PrimitiveSet
from .scales import grouped_median

__all__ = ["PlaneFit", "fit_primitive_planes", "apply_planes", "pixel_rays", "primitive_adjacency", "lend_across_weak_edges",
           "MODE_NONE", "MODE_SCALE", "MODE_PLANE", "MODE_LENT"]

MODE_NONE = 0    #: no depth (dropped, holes filled later)
MODE_SCALE = 1   #: scale of the shape only
MODE_PLANE = 2   #: scale + planar correction
MODE_LENT = 3    #: scale lent by a neighbour across a weak edge


@dataclass
class PlaneFit:
    """Result of :func:`fit_primitive_planes` / :func:`lend_across_weak_edges`.

    Attributes:
        scaled_log_depth: (M,) metric log-depth per entry of the set (log
            metres); arbitrary (0) for primitives with ``mode == MODE_NONE``.
        mode: (N,) int8 ``MODE_*`` code per primitive.
        hypothesis: (N,) index of the chosen normal hypothesis (-1: own shape).
    """

    scaled_log_depth: np.ndarray
    mode: np.ndarray
    hypothesis: np.ndarray


def pixel_rays(prims: PrimitiveSet, pix: np.ndarray) -> np.ndarray:
    """(K, 3) rays ``K^-1 [u, v, 1]`` of flat pixels ``pix`` of ``prims.camera``."""
    cam = prims.camera
    w = cam.width
    return np.stack([(pix % w - cam.cx) / cam.fx, (pix // w - cam.cy) / cam.fy,
                     np.ones(pix.size)], -1)


def _irls(ids, feats, w0, n, prior, huber, iterations, rho_bar):
    """Batched ridge IRLS: minimise sum_k h(f_k . x_i - 1) + prior |x_i[1:] / rho_bar_i|^2
    per group ``i`` (``h`` Huber); ``feats`` (K, 4) already divided by the
    measured inverse depth; ``w0`` (K,) starting weights.  Returns
    ``(x (n, 4), cost (n,))``."""
    wts = w0.copy()
    ridge = np.zeros((n, 4, 4))
    ridge[:, 1:, 1:] = np.eye(3)[None] * (prior / np.maximum(rho_bar, 1e-12) ** 2)[:, None, None]
    x = np.zeros((n, 4))
    for _ in range(max(1, iterations)):
        A = np.zeros((n, 4, 4))
        b = np.zeros((n, 4))
        for a in range(4):
            b[:, a] = np.bincount(ids, weights=wts * feats[:, a], minlength=n)
            for c in range(a, 4):
                A[:, a, c] = A[:, c, a] = np.bincount(ids, weights=wts * feats[:, a] * feats[:, c],
                                                      minlength=n)
        A += ridge
        A[:, 0, 0] += 1e-12
        x = np.linalg.solve(A, b[:, :, None])[:, :, 0]
        e = np.einsum("ka,ka->k", feats, x[ids]) - 1.0
        ae = np.abs(e)
        wts = np.where(ae <= huber, 1.0, huber / np.maximum(ae, 1e-300))
    e = np.einsum("ka,ka->k", feats, x[ids]) - 1.0
    ae = np.abs(e)
    rho = np.where(ae <= huber, 0.5 * e ** 2, huber * (ae - 0.5 * huber))
    cost = np.bincount(ids, weights=rho, minlength=n)
    cost += prior * np.sum((x[:, 1:] / np.maximum(rho_bar, 1e-12)[:, None]) ** 2, 1)
    return x, cost


def fit_primitive_planes(prims: PrimitiveSet, point_prim: np.ndarray, point_pix: np.ndarray,
                         point_d: np.ndarray, log_scales: np.ndarray, counts: np.ndarray,
                         min_points: int = 3, prior: float = 0.1, huber: float = 0.05,
                         iterations: int = 10, max_ratio: float = 3.0,
                         hypotheses: Optional[np.ndarray] = None) -> PlaneFit:
    """Scale-and-plane fit of every primitive from its sparse points (module docstring).

    Args:
        prims: the primitives (working resolution).
        point_prim, point_pix, point_d: per (point, containing primitive) pair:
            primitive index, flat pixel in ``prims.camera``, depth (metres > 0).
        log_scales: (N,) scale-only fits (NaN: no depth), e.g. the medians.
        counts: (N,) points per primitive.
        min_points: points needed for the planar correction (>= 3).
        prior: ridge weight on the relative tilt correction (>= 0).
        huber: Huber threshold on the relative inverse-depth residual (> 0).
        iterations: IRLS iterations (>= 1).
        max_ratio: largest allowed depth ratio between the planar and the
            scale-only fit on any pixel of the primitive (> 1).
        hypotheses: optional (N, H, 3) unit camera-frame normals per primitive
            (rows of NaN: no hypothesis); each is tried as a planar shape.
    Returns:
        :class:`PlaneFit`.
    Raises:
        ValueError: bad shapes or option values.
    """
    n = len(prims)
    log_scales = np.asarray(log_scales, dtype=np.float64).reshape(-1)
    counts = np.asarray(counts).reshape(-1)
    pp, pix, d = _checked_plane_inputs(n, log_scales, counts, min_points, prior, huber,
                                       max_ratio, point_prim, point_pix, point_d)
    has = np.isfinite(log_scales)
    L = prims.scaled_log_depth(np.where(has, log_scales, 0.0))
    mode = np.where(has, MODE_SCALE, MODE_NONE).astype(np.int8)
    hyp_choice = np.full(n, -1, np.int64)
    cand = has & (counts >= min_points)
    sel = cand[pp]
    if not np.any(sel):
        return PlaneFit(L, mode, hyp_choice)

    ids, ppix, pd = pp[sel], pix[sel], d[sel]
    r_pt = pixel_rays(prims, ppix)
    # unscaled shape at each point: entry of (primitive, pixel)
    key = prims.primitive_ids * (prims.camera.width * prims.camera.height) + prims.pixels
    order = np.argsort(key, kind="stable")
    ent = order[np.searchsorted(key[order], ids * (prims.camera.width * prims.camera.height)
                                + ppix)]
    rho_bar = np.exp(-grouped_median(ids, np.log(pd), n)[0])
    rho_bar = np.where(np.isfinite(rho_bar), rho_bar, 1.0)

    shapes, hyp, anchor_r = _point_shapes(prims, hypotheses, ids, r_pt, ent)
    best_x = _best_planes(shapes, ids, r_pt, pd, log_scales, cand, hyp_choice, prior, huber,
                          iterations, rho_bar)

    # evaluate on every pixel of the candidate primitives; guard against bad planes
    rho0_all = _pixel_shapes(prims, hyp, hyp_choice, anchor_r)
    L, good = apply_planes(prims, best_x, L, max_ratio, rho0_all)
    mode[good] = MODE_PLANE
    hyp_choice[~good] = -1
    return PlaneFit(L, mode, hyp_choice)


def _checked_plane_inputs(n, log_scales, counts, min_points, prior, huber, max_ratio,
                          point_prim, point_pix, point_d):
    """:func:`fit_primitive_planes`'s checks (its *Raises*); returns the points'
    ``(primitive, flat pixel, depth)`` as flat int64 / int64 / float64 arrays."""
    if log_scales.shape != (n,) or counts.shape != (n,):
        raise ValueError(f"log_scales and counts must have shape ({n},)")
    if int(min_points) < 3:
        raise ValueError(f"min_points must be >= 3 (a plane), got {min_points}")
    if not (prior >= 0 and np.isfinite(prior)) or not (huber > 0 and np.isfinite(huber)):
        raise ValueError(f"prior must be >= 0 and huber > 0, got {prior}, {huber}")
    if not max_ratio > 1:
        raise ValueError(f"max_ratio must be > 1, got {max_ratio}")
    pp = np.asarray(point_prim, dtype=np.int64).reshape(-1)
    pix = np.asarray(point_pix, dtype=np.int64).reshape(-1)
    d = np.asarray(point_d, dtype=np.float64).reshape(-1)
    if not (pp.size == pix.size == d.size):
        raise ValueError("point_prim, point_pix and point_d must have the same length")
    if np.any(~np.isfinite(d) | (d <= 0)):
        raise ValueError("point_d must be finite and > 0")
    return pp, pix, d


def _point_shapes(prims: PrimitiveSet, hypotheses: Optional[np.ndarray], ids: np.ndarray,
                  r_pt: np.ndarray, ent: np.ndarray):
    """Unscaled inverse-depth shapes at the points (entries ``ent`` of primitives
    ``ids``, rays ``r_pt``): the own shape first, then one planar shape per
    normal hypothesis.  Returns ``(shapes, hypotheses as float array or None,
    anchor rays)``; ``ValueError`` for hypotheses of the wrong shape."""
    n = len(prims)
    shapes = [np.exp(-prims.log_depth[ent])]          # own shape, rho0 at the points
    anchor_r = pixel_rays(prims, prims.anchors)
    hyp = None
    if hypotheses is not None:
        hyp = np.asarray(hypotheses, dtype=np.float64)
        if hyp.ndim != 3 or hyp.shape[0] != n or hyp.shape[2] != 3:
            raise ValueError(f"hypotheses must be (N={n}, H, 3), got {hyp.shape}")
        for h in range(hyp.shape[1]):
            nh = hyp[:, h]
            den = np.einsum("na,na->n", nh, anchor_r)  # planar rho0 = n.r / n.r(anchor)
            with np.errstate(invalid="ignore", divide="ignore"):
                shapes.append(np.einsum("ka,ka->k", nh[ids], r_pt) / den[ids])
    return shapes, hyp, anchor_r


def _best_planes(shapes, ids, r_pt, pd, log_scales, cand, hyp_choice, prior, huber, iterations,
                 rho_bar) -> np.ndarray:
    """(N, 4) scale-and-plane unknowns of the lowest robust cost over ``shapes``
    per candidate primitive (NaN where none fits); ``hyp_choice`` gets the
    chosen shape's index minus one (-1: own shape)."""
    n = cand.size
    best_x = np.full((n, 4), np.nan)
    best_cost = np.full(n, np.inf)
    for h, rho0 in enumerate(shapes):
        okh = np.isfinite(rho0) & (rho0 > 0)
        g = np.bincount(ids[okh], minlength=n) == np.bincount(ids, minlength=n)
        use = g[ids]
        if not np.any(use):
            continue
        feats = np.concatenate([rho0[use, None], r_pt[use]], 1) * pd[use, None]
        e0 = np.abs(np.exp(-log_scales[ids[use]]) * feats[:, 0] - 1.0)  # scale-only residual
        w0 = np.where(e0 <= huber, 1.0, huber / np.maximum(e0, 1e-300))
        x, cost = _irls(ids[use], feats, w0, n, prior, huber, iterations, rho_bar)
        better = g & cand & (cost < best_cost) & np.all(np.isfinite(x), 1)
        best_x[better] = x[better]
        best_cost[better] = cost[better]
        hyp_choice[better] = h - 1
    return best_x


def _pixel_shapes(prims: PrimitiveSet, hyp: Optional[np.ndarray], hyp_choice: np.ndarray,
                  anchor_r: np.ndarray) -> np.ndarray:
    """(M,) unscaled inverse depth on every entry of the set: the own shape, or
    the chosen hypothesis' plane where one was chosen."""
    rho0_all = np.exp(-prims.log_depth)
    ch = hyp_choice[prims.primitive_ids]
    if hyp is not None and np.any(ch >= 0):
        j = np.flatnonzero(ch >= 0)
        pj = prims.primitive_ids[j]
        rho0_all[j] = (np.einsum("ka,ka->k", hyp[pj, ch[j]], pixel_rays(prims, prims.pixels[j]))
                       / np.einsum("ka,ka->k", hyp[pj, ch[j]], anchor_r[pj]))
    return rho0_all


def apply_planes(prims: PrimitiveSet, x: np.ndarray, L_ref: np.ndarray, max_ratio: float = 3.0,
                 rho0: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Per-entry log-depth of the model ``rho = x0 rho0 + x[1:] . r`` (module
    docstring) for primitives with finite ``x`` (N, 4).

    ``L_ref`` (M,) is the reference (scale-only) log-depth; a primitive whose
    model is not positive on all its pixels or departs from ``L_ref`` by more
    than ``max_ratio`` anywhere keeps ``L_ref``.  ``rho0`` (M,) defaults to
    ``exp(-log_depth)``.  Returns ``(L (M,), replaced (N,) bool)``.
    """
    n = len(prims)
    pid = prims.primitive_ids
    fit = np.all(np.isfinite(x), 1)
    on = fit[pid]
    r0 = np.exp(-prims.log_depth[on]) if rho0 is None else rho0[on]
    xe = x[pid[on]]
    rho = xe[:, 0] * r0 + np.einsum("ka,ka->k", xe[:, 1:], pixel_rays(prims, prims.pixels[on]))
    with np.errstate(invalid="ignore", divide="ignore"):
        Lp = -np.log(rho)
        bad = ~np.isfinite(Lp) | ~(np.abs(Lp - L_ref[on]) <= np.log(max_ratio))
    good = fit & ~(np.bincount(pid[on], weights=bad, minlength=n) > 0)
    keep = good[pid[on]]
    L = L_ref.copy()
    idx_on = np.flatnonzero(on)
    L[idx_on[keep]] = Lp[keep]
    return L, good


def primitive_adjacency(prims: PrimitiveSet, image: np.ndarray
                        ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """4-neighbour pixel pairs across primitive boundaries and their colour steps.

    Args:
        prims: the primitives (label of a pixel: :meth:`PrimitiveSet.label_image`).
        image: (H, W, C) or (H, W) float image in [0, 1] at ``prims.camera``'s size.
    Returns:
        ``(p, q, a, b)``: flat pixels ``p`` in primitive ``a`` and its 4-neighbour
        ``q`` in primitive ``b != a``; each unordered pair appears in both
        orientations.  The colour step of a pair is
        ``mean_c |image[p] - image[q]|`` (see :func:`lend_across_weak_edges`).
    """
    h, w = prims.camera.shape
    img = np.asarray(image, dtype=np.float64)
    if img.shape[:2] != (h, w):
        raise ValueError(f"image has shape {img.shape[:2]}, expected {(h, w)}")
    lab = prims.label_image().reshape(-1)
    idx = np.arange(h * w).reshape(h, w)
    p = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    q = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    a, b = lab[p], lab[q]
    cut = (a != b) & (a >= 0) & (b >= 0)
    p, q, a, b = p[cut], q[cut], a[cut], b[cut]
    return (np.concatenate([p, q]), np.concatenate([q, p]), np.concatenate([a, b]).astype(np.int64),
            np.concatenate([b, a]).astype(np.int64))


def lend_across_weak_edges(prims: PrimitiveSet, fit: PlaneFit, image: np.ndarray,
                           edge_threshold: float = 0.08, rounds: int = 3) -> PlaneFit:
    """Give primitives without depth (``MODE_NONE``) the depth of their most
    similar supported neighbour across a weak edge (module docstring).

    ``image`` (H, W[, C]) float in [0, 1] at ``prims.camera``'s size;
    ``edge_threshold`` bounds the mean absolute colour step along the shared
    boundary; ``rounds`` >= 0.  Returns a new :class:`PlaneFit` (lent
    primitives get ``MODE_LENT``).
    """
    if not (edge_threshold >= 0 and np.isfinite(edge_threshold)) or int(rounds) < 0:
        raise ValueError(f"edge_threshold must be >= 0 and rounds >= 0, got "
                         f"{edge_threshold}, {rounds}")
    n = len(prims)
    L = fit.scaled_log_depth.copy()
    mode = fit.mode.copy()
    if n == 0 or not np.any(mode == MODE_NONE) or not np.any(mode != MODE_NONE):
        return PlaneFit(L, mode, fit.hypothesis.copy())
    img = np.asarray(image, dtype=np.float64)
    img = img[..., None] if img.ndim == 2 else img
    p, q, a, b = primitive_adjacency(prims, img)
    if p.size == 0:
        return PlaneFit(L, mode, fit.hypothesis.copy())
    flat = img.reshape(-1, img.shape[2])
    step = np.abs(flat[p] - flat[q]).mean(1)
    pairkey = a * n + b
    uk, inv = np.unique(pairkey, return_inverse=True)
    mean_step = np.bincount(inv, weights=step) / np.bincount(inv)
    ka, kb = uk // n, uk % n
    # one (pixel -> entry) map for label-image pixels: the smallest covering primitive
    npix = prims.camera.width * prims.camera.height
    lab = prims.label_image().reshape(-1)
    ent_of = np.full(npix, -1, np.int64)
    pid = prims.primitive_ids
    own = lab[prims.pixels] == pid
    ent_of[prims.pixels[own]] = np.flatnonzero(own)
    for _ in range(int(rounds)):
        empty = mode == MODE_NONE
        ok = empty[ka] & ~empty[kb] & (mean_step < edge_threshold)
        if not np.any(ok):
            break
        # per empty primitive: the neighbour with the weakest edge
        cand_a, cand_b, cand_s = ka[ok], kb[ok], mean_step[ok]
        o = np.lexsort((cand_s, cand_a))
        first = np.concatenate([[True], cand_a[o][1:] != cand_a[o][:-1]])
        chosen = np.full(n, -1, np.int64)
        chosen[cand_a[o][first]] = cand_b[o][first]
        use = (chosen[a] == b) & (chosen[a] >= 0)
        ep, eq = ent_of[p[use]], ent_of[q[use]]
        okp = (ep >= 0) & (eq >= 0)
        s, cnt = grouped_median(a[use][okp], L[eq[okp]] - prims.log_depth[ep[okp]], n)
        got = empty & (cnt > 0) & np.isfinite(s)
        if not np.any(got):
            break
        sel = got[pid]
        L[sel] = prims.log_depth[sel] + s[pid[sel]]
        mode[got] = MODE_LENT
    return PlaneFit(L, mode, fit.hypothesis.copy())
