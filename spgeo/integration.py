"""Batched integration of surface normals into log-depth (docs/design.md §3).

For a surface point seen at pixel ``(u, v)`` with camera-frame unit normal ``n``
and ray ``r = K^-1 [u, v, 1]``, the tangent plane ``n . X = d`` gives
``log z = log d - log m`` with ``m = n . r``.  Differentiating,

    m * d(log z)/du + nx / fx = 0,      m * d(log z)/dv + ny / fy = 0,

which is the perspective log-depth form of Cao et al. (ECCV 2022) divided by
the focal length (for ``fx = fy = f`` it is exactly ``(m f) dz~/du + nx = 0``
with ``m f = nx (u - cx) + ny (v - cy) + nz f``), i.e. the per-axis form for
``fx != fy``.

Discretisation: one residual per pair of neighbouring pixels that are *both*
inside the mask (one-sided differences only inside masks).  Coefficients are
averaged over the two pixels (a midpoint rule: for a plane it reproduces the
exact log-ratio to third order), so each edge ``p -> q`` contributes

    mbar * (x_q - x_p) + (du * abar_u + dv * abar_v) = 0

with ``a_u = nx / fx``, ``a_v = ny / fy`` and ``(du, dv)`` the pixel step.
Right and down neighbours are always used; diagonal neighbours are added only
where a mask is 8- but not 4-connected (a one-pixel diagonal bridge), so thin
parts stay linked.  All masks form one block-diagonal sparse least-squares
problem solved at once (the normal equations are a weighted graph Laplacian).

Each connected part of a mask is determined up to an additive constant (the
log depth-scale).  We fix it as documented in :class:`IntegrationConfig`:
``"anchor"`` sets the anchor pixel's log-depth to 0 (docs/design.md §2), ``"mean"``
sets the mean over the mask to 0.  Parts of one mask that no 4/8-neighbour
chain links carry no relative information; they are aligned at equal mean
log-depth and counted in :attr:`IntegrationResult.n_components`."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from .camera import PinholeCamera
from .configs import config_class
from .validation import InputError, check_camera, check_mask_stack, check_normals

__all__ = ["IntegrationConfig", "IntegrationResult", "integrate_normals",
           "integrate_normals_regions"]

log = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class IntegrationConfig:
    """Options of the batched normal integration.

    Attributes:
        solver: ``"cholesky"`` (default: exact banded Cholesky (LAPACK) per
            group of linked parts of similar raster bandwidth; parts wider than
            ``cholesky_max_band`` go to the ``"direct"`` path), ``"direct"``
            (exact red-black elimination, then sparse LU (SuperLU) of the
            half-size Schur complement) or ``"cg"`` (Jacobi-preconditioned
            conjugate gradients, as the authors ran on a GPU; kept for
            comparison).  ``evaluation/bench/integration.py`` compares them
            (results in docs/results.md).
        cholesky_max_band: widest raster bandwidth (entries between a pixel
            and its farthest linked neighbour) that ``"cholesky"`` factorises
            as a band; wider parts use ``"direct"`` (default 64: beyond it the
            band's fill outgrows a fill-reducing sparse factorisation).
        natural_order_max_band: ``"direct"`` uses SuperLU's natural ordering
            when every region's raster bandwidth is at most this (small masks),
            else a minimum-degree ordering (default 96).
        cg_tol: relative residual tolerance of CG (default 1e-6; the authors
            used 1e-3).
        cg_maxiter: iteration cap for CG (default 1000, as the authors).
        constant: ``"anchor"`` (log-depth 0 at each mask's anchor pixel) or
            ``"mean"`` (zero mean over each mask).
        min_abs_m: lower bound on ``|n . r|`` (near-grazing or back-facing
            normals are clamped to ``-min_abs_m`` to keep gradients bounded).
        unknown_normals: pixels whose normal is unknown (NaN, shorter than
            :data:`spgeo.validation.MIN_NORMAL_LENGTH`) get NaN log-depth with
            ``"nan"`` (default); ``"fill"`` (front-ends) borrows a neighbour's
            coefficients on each edge to a known normal and makes parts without
            a known normal flat (see :attr:`IntegrationResult.known`).
    """

    solver: str = "cholesky"
    cg_tol: float = 1e-6
    cg_maxiter: int = 1000
    cholesky_max_band: int = 64
    natural_order_max_band: int = 96
    constant: str = "anchor"
    min_abs_m: float = 0.05
    unknown_normals: str = "nan"

    def __post_init__(self) -> None:
        if self.unknown_normals not in ("nan", "fill"):
            raise ValueError("IntegrationConfig.unknown_normals must be 'nan' or 'fill', "
                             f"got {self.unknown_normals!r}")
        if self.solver not in ("cholesky", "direct", "cg"):
            raise ValueError("IntegrationConfig.solver must be 'cholesky', 'direct' or 'cg', "
                             f"got {self.solver!r}")
        if self.constant not in ("anchor", "mean"):
            raise ValueError(f"IntegrationConfig.constant must be 'anchor' or 'mean', "
                             f"got {self.constant!r}")


@dataclass
class IntegrationResult:
    """Output of :func:`integrate_normals_regions`.

    Attributes:
        log_depth: (M,) unscaled log-depth for every entry of the concatenated
            regions (same order as the input).
        offsets: (N+1,) region boundaries into ``log_depth``.
        n_components: (N,) number of unlinked parts per region (1 = fully linked).
        n_edges: number of difference equations.
        solver_info: iterations / residual / timings (seconds).
        known: (M,) bool, True where the entry's normal was known.
    """

    log_depth: np.ndarray
    offsets: np.ndarray
    n_components: np.ndarray
    n_edges: int
    solver_info: dict = field(default_factory=dict)
    known: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def region(self, i: int) -> np.ndarray:
        return self.log_depth[self.offsets[i]:self.offsets[i + 1]]


_DIRECTIONS = ((1, 0), (0, 1), (1, 1), (-1, 1))   # right, down, down-right, down-left
_BAND_BIN = 1.25        # band groups: raster bandwidths within this ratio share one band


def _edges(key: np.ndarray, pix: np.ndarray, pix_u: np.ndarray, pix_v: np.ndarray,
           lookup: Optional[np.ndarray], width: int, height: int, du: int, dv: int):
    """Entries (p, q) with q the (du, dv)-neighbour of p in the same region
    (``(du, dv)`` one of :data:`_DIRECTIONS`; image borders never wrap into the
    next row or region).  ``lookup`` maps a flat pixel to its entry when no two
    regions overlap; ``None`` searches ``key`` instead."""
    if dv == 0:  # right: the next entry, if it is the next pixel of the same region
        p = np.flatnonzero((key[1:] - key[:-1] == 1) & (pix_u[:-1] < width - 1))
        return p, p + 1
    ok = pix_v < height - 1
    if du == 1:
        ok &= pix_u < width - 1
    elif du == -1:
        ok &= pix_u > 0
    p = np.flatnonzero(ok)
    step = dv * width + du
    target = key[p] + step
    if lookup is not None:
        q = lookup[pix[p] + step]
    else:
        q = np.minimum(np.searchsorted(key, target), key.size - 1)
    hit = key[q] == target        # also rejects a neighbour of another region
    return p[hit], q[hit]


def _laplacian(P: np.ndarray, Q: np.ndarray, wgt: np.ndarray, diag: np.ndarray) -> sp.csr_matrix:
    """``diag(diag) - sum_e wgt_e (e_P e_Q^T + e_Q e_P^T)`` as a CSR matrix."""
    n = diag.size
    idx = np.arange(n)
    rows = np.concatenate([P, Q, idx])
    cols = np.concatenate([Q, P, idx])
    vals = np.concatenate([-wgt, -wgt, diag])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def _permc(band: int, config: IntegrationConfig) -> str:
    """SuperLU column ordering for parts whose widest raster bandwidth is ``band``."""
    return "NATURAL" if band <= config.natural_order_max_band else "MMD_AT_PLUS_A"


def _solve_red_black(L: sp.csr_matrix, b: np.ndarray, colour: np.ndarray,
                     permc_spec: str):
    """Solve the SPD system ``L x = b`` by exact red-black reduction + sparse LU.

    "Red" unknowns (one checkerboard colour) that couple to no other red
    unknown have a diagonal block, so they are eliminated exactly; the Schur
    complement on the remaining unknowns (about half) is factorised by SuperLU
    and the red values are recovered by back-substitution.
    Returns ``(x, factor_nnz)``.
    """
    coo = L.tocoo()
    off = coo.row != coo.col
    same = off & (colour[coo.row] == colour[coo.col])
    blocked = np.zeros(L.shape[0], dtype=bool)
    blocked[coo.row[same]] = True
    red = (colour == 0) & ~blocked
    R = np.flatnonzero(red)
    B = np.flatnonzero(~red)
    Lr = L[R]
    d_r = Lr[:, R].diagonal()
    L_rb = Lr[:, B]
    S = (L[B][:, B] - L_rb.T @ sp.diags(1.0 / d_r) @ L_rb).tocsc()
    rhs = b[B] - L_rb.T @ (b[R] / d_r)
    x = np.empty_like(b)
    lu = spla.splu(S, permc_spec=permc_spec)
    x[B] = lu.solve(rhs)
    x[R] = (b[R] - L_rb @ x[B]) / d_r
    return x, int(lu.L.nnz + lu.U.nnz)


def _solve_banded(P: np.ndarray, Q: np.ndarray, wgt: np.ndarray, diag: np.ndarray,
                  b: np.ndarray, comp: np.ndarray, n_comp: int, colour: np.ndarray,
                  config: IntegrationConfig):
    """Solve the SPD system ``L x = b`` with ``L`` as in :func:`_laplacian` (``Q > P``).

    The system is block diagonal over the linked parts ``comp``.  Parts are
    grouped by raster bandwidth (ratio :data:`_BAND_BIN`); each group keeps its
    entries in order, so it is one band of its widest part's width, factorised
    by LAPACK's banded Cholesky.  Parts wider than ``config.cholesky_max_band``
    go to :func:`_solve_red_black`.  Returns ``(x, stats)``.
    """
    band = np.zeros(n_comp, dtype=np.int64)
    np.maximum.at(band, comp[P], Q - P)
    # small group ids (uint8: NumPy's stable sort is a radix sort for them)
    grp = np.ceil(np.log(np.maximum(band, 1)) / np.log(_BAND_BIN)).astype(np.uint8)
    wide_grp = int(np.ceil(np.log(config.cholesky_max_band + 1) / np.log(_BAND_BIN))) + 1
    grp[band > config.cholesky_max_band] = wide_grp
    g_ent = grp[comp]
    perm = np.argsort(g_ent, kind="stable")
    pos = np.empty_like(perm)
    pos[perm] = np.arange(perm.size)
    g_edge = g_ent[P]
    eperm = np.argsort(g_edge, kind="stable")
    Pn, Qn, We = pos[P[eperm]], pos[Q[eperm]], wgt[eperm]
    g_sorted = g_ent[perm]
    s_start = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    groups = g_sorted[s_start]
    e_start = np.searchsorted(g_edge[eperm], groups)
    s_bounds = np.append(s_start, perm.size)
    e_bounds = np.append(e_start, eperm.size)
    x = np.empty_like(b)
    stats = {"band_groups": int(groups.size), "factor_bytes": 0, "t_factor": 0.0}
    for k, g in enumerate(groups):
        s0, s1, e0, e1 = s_bounds[k], s_bounds[k + 1], e_bounds[k], e_bounds[k + 1]
        idx = perm[s0:s1]
        p, q, wk = Pn[e0:e1] - s0, Qn[e0:e1] - s0, We[e0:e1]
        t0 = time.perf_counter()
        if g == wide_grp:
            widest = int(band[comp[idx]].max())
            x[idx], nnz = _solve_red_black(_laplacian(p, q, wk, diag[idx]), b[idx], colour[idx],
                                           _permc(widest, config))
            stats["factor_bytes"] += 12 * nnz
            stats["t_factor"] += time.perf_counter() - t0
            continue
        kd = int((q - p).max(initial=0))
        ab = np.zeros((kd + 1, idx.size))
        ab[0] = diag[idx]
        ab[q - p, p] = -wk
        cb = sla.cholesky_banded(ab, lower=True, overwrite_ab=True, check_finite=False)
        stats["t_factor"] += time.perf_counter() - t0
        stats["factor_bytes"] += cb.nbytes
        x[idx] = sla.cho_solve_banded((cb, True), b[idx], overwrite_b=True, check_finite=False)
    return x, stats


def _solve(P: np.ndarray, Q: np.ndarray, wgt: np.ndarray, diag: np.ndarray, b: np.ndarray,
           comp: np.ndarray, n_comp: int, colour: np.ndarray, config: IntegrationConfig,
           info: dict) -> np.ndarray:
    """Solve ``L x = b`` (``L`` as in :func:`_laplacian`, ``Q > P``, linked parts
    ``comp``) with ``config.solver``; solver statistics go into ``info``."""
    if config.solver == "cholesky":
        x, stats = _solve_banded(P, Q, wgt, diag, b, comp, n_comp, colour, config)
        info.update(stats)
        info["iterations"] = 1
    elif config.solver == "direct":
        # Entries are block (region) ordered and raster ordered inside each
        # region, so the natural order is already banded per block; for wide
        # regions a fill-reducing ordering (threshold: natural_order_max_band).
        permc = _permc(int((Q - P).max(initial=0)), config)
        tf = time.perf_counter()
        x, nnz = _solve_red_black(_laplacian(P, Q, wgt, diag), b, colour, permc)
        info.update(iterations=1, ordering=permc, factor_bytes=12 * nnz,
                    t_factor=time.perf_counter() - tf)
    else:
        L = _laplacian(P, Q, wgt, diag)
        M = sp.diags(1.0 / diag)
        iters = [0]

        def _count(_):
            iters[0] += 1

        x, status = spla.cg(L, b, rtol=config.cg_tol, maxiter=config.cg_maxiter, M=M,
                            callback=_count)
        info["iterations"] = iters[0]
        info["converged"] = status == 0
        if status != 0:
            log.warning("integrate_normals: CG did not reach rtol=%g in %d iterations",
                        config.cg_tol, config.cg_maxiter)
    return x


def _stack_regions(regions: Sequence[np.ndarray], sizes: np.ndarray, npix: int):
    """Validated, stacked regions: ``(pix, rid, key, lookup)`` per entry (region
    ``rid``, flat pixel ``pix``, sort key ``rid * npix + pix``); ``lookup``: entry of
    each pixel, None when regions overlap (neighbours are then found by binary search)."""
    n = len(regions)
    pix = np.concatenate([np.asarray(r, dtype=np.int64) for r in regions])
    if pix.min() < 0 or pix.max() >= npix:
        raise InputError("integrate_normals: region pixel index outside the image")
    rid = np.repeat(np.arange(n, dtype=np.int64), sizes)
    key = rid * npix + pix
    if np.any(np.diff(key) <= 0):
        raise InputError("integrate_normals: each region's pixels must be sorted and unique")
    entries = np.arange(pix.size)
    lookup = np.full(npix, -1, dtype=np.int64)
    lookup[pix] = entries
    if np.any(lookup[pix] != entries):
        lookup = None   # regions overlap: neighbours by binary search
    return pix, rid, key, lookup


def _entry_coefficients(normals: np.ndarray, pix: np.ndarray, camera: PinholeCamera,
                        config: IntegrationConfig):
    """Per-entry coefficients ``(known, m, a_u, a_v, u, v)``: m = n . r (at most
    ``-config.min_abs_m``), a_u = nx / fx, a_v = ny / fy; unknown normals count as 0."""
    w = camera.shape[1]
    nrm = np.take(normals.reshape(-1, 3), pix, axis=0)
    known = np.isfinite(nrm[:, 0])
    if not bool(known.all()):
        nrm = np.where(known[:, None], nrm, 0.0)
    pu = pix % w
    pv = pix // w
    m = nrm[:, 0] * ((pu - camera.cx) / camera.fx) + nrm[:, 1] * ((pv - camera.cy) / camera.fy)
    m += nrm[:, 2]
    np.minimum(m, -config.min_abs_m, out=m)
    au = nrm[:, 0] / camera.fx
    av = nrm[:, 1] / camera.fy
    return known, m, au, av, pu, pv


def _edge_pairs(key, pix, pu, pv, lookup, w: int, h: int) -> list:
    """``(p, q)`` entry pairs per direction of :data:`_DIRECTIONS`: right and down
    always, diagonals only where the 4-neighbour path is missing."""
    m_tot = pix.size
    pairs = [_edges(key, pix, pu, pv, lookup, w, h, du, dv) for du, dv in _DIRECTIONS]
    (p_r, q_r), (p_d, _) = pairs[0], pairs[1]
    has_r = np.zeros(m_tot, bool)
    has_r[p_r] = True
    has_d = np.zeros(m_tot, bool)
    has_d[p_d] = True
    has_l = np.zeros(m_tot, bool)  # left neighbour exists  <=> some p_r points here
    has_l[q_r] = True
    # p -> p+(1,1) is linked through p's right or lower neighbour, p -> p+(-1,1)
    # through p's left or lower neighbour
    for k, side in ((2, has_r), (3, has_l)):
        p, q = pairs[k]
        keep = ~(side[p] | has_d[p])
        pairs[k] = (p[keep], q[keep])
    return pairs


def _edge_terms(pairs: list, known, m, au, av, config: IntegrationConfig):
    """``(P, Q, c, t)``: the edges and their terms ``c (x_q - x_p) + t``; with unknown
    normals ("fill") an unknown normal borrows its partner's coefficients on that edge."""
    P = np.concatenate([p for p, _ in pairs])
    Q = np.concatenate([q for _, q in pairs])
    # per edge: du * (a_u[P] + a_u[Q]) + dv * (a_v[P] + a_v[Q])
    slope = (au, av, au + av, av - au)
    tsum = np.concatenate([s[p] + s[q] for s, (p, q) in zip(slope, pairs)])
    if bool(known.all()):
        c = 0.5 * (m[P] + m[Q])
        t = 0.5 * tsum
    else:
        # "fill": an unknown normal borrows its partner's coefficients on that edge
        cnt = known[P].astype(np.float64) + known[Q]
        sel = cnt > 0 if config.unknown_normals == "fill" else cnt == 2
        mk = np.where(known, m, 0.0)
        P, Q, cnt, tsum = P[sel], Q[sel], cnt[sel], tsum[sel]
        c = (mk[P] + mk[Q]) / cnt
        t = tsum / cnt
    return P, Q, c, t


def _anchor_entries(anchors, pix, offsets, key, n: int, npix: int) -> np.ndarray:
    """Entry of each region's anchor pixel (default: its first pixel); InputError for an
    anchor outside its region."""
    m_tot = pix.size
    if anchors is None:
        anchor_pix = pix[offsets[:-1]]
    else:
        anchor_pix = np.asarray(anchors, dtype=np.int64).reshape(-1)
        if anchor_pix.shape != (n,):
            raise InputError(f"integrate_normals: {anchor_pix.size} anchors for {n} regions")
    akey = np.arange(n) * npix + anchor_pix
    apos = np.searchsorted(key, akey)
    apos_c = np.minimum(apos, m_tot - 1)
    if not np.all((apos < m_tot) & (key[apos_c] == akey)):
        bad = np.flatnonzero(~((apos < m_tot) & (key[apos_c] == akey)))[:5]
        raise InputError(f"integrate_normals: anchor outside its region for regions {bad.tolist()}")
    return apos_c


def _pins(comp: np.ndarray, n_comp: int, apos_c: np.ndarray):
    """``(first_of_comp, pin)``: the first entry of every component; the pinned entry of
    each: the anchor in its component, the first entry of every other component."""
    first_of_comp = np.full(n_comp, -1, dtype=np.int64)
    order = np.arange(comp.size)[::-1]
    first_of_comp[comp[order]] = order
    pin = first_of_comp.copy()
    pin[comp[apos_c]] = apos_c
    return first_of_comp, pin


def _solve_active(P, Q, wgt, diag, b, comp, n_comp: int, colour, config: IntegrationConfig,
                  info: dict) -> np.ndarray:
    """Solve the components whose right-hand side is not zero; the others (e.g.
    fronto-parallel normals) have the exact solution 0."""
    m_tot = b.size
    active = np.zeros(n_comp, dtype=bool)
    active[comp[b != 0.0]] = True
    info["n_solved_components"] = int(active.sum())
    if active.all():
        return _solve(P, Q, wgt, diag, b, comp, n_comp, colour, config, info)
    x = np.zeros(m_tot)
    if active.any():
        sub = active[comp]
        idx = np.flatnonzero(sub)
        new_pos = np.cumsum(sub) - 1
        e_sub = sub[P]
        new_comp = np.cumsum(active) - 1
        x[idx] = _solve(new_pos[P[e_sub]], new_pos[Q[e_sub]], wgt[e_sub], diag[idx], b[idx],
                        new_comp[comp[idx]], int(active.sum()), colour[idx], config, info)
    else:
        info["iterations"] = 0
    return x


def _fix_constants(x, comp, n_comp: int, known, rid, first_of_comp, apos_c, n: int,
                   config: IntegrationConfig):
    """``(x, n_components)``: per component mean or anchor; unlinked parts at equal mean;
    values for the "valid" entries only (the known ones with "nan", else all)."""
    valid = known if config.unknown_normals == "nan" else np.ones(x.size, bool)
    comp_sum = np.bincount(comp, weights=x, minlength=n_comp)
    comp_cnt = np.bincount(comp, minlength=n_comp)
    comp_mean = comp_sum / comp_cnt
    x = x - comp_mean[comp]  # every component now has zero mean
    comp_region = rid[first_of_comp[np.flatnonzero(valid[first_of_comp])]]
    n_components = np.bincount(comp_region, minlength=n).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):   # regions with no valid entry
        rmean = (np.bincount(rid, weights=np.where(valid, x, 0.0), minlength=n)
                 / np.bincount(rid, weights=valid, minlength=n))
    ref = np.where(valid[apos_c], x[apos_c], rmean) if config.constant == "anchor" else rmean
    return np.where(valid, x - ref[rid], np.nan), n_components


def integrate_normals_regions(normals: np.ndarray, regions: Sequence[np.ndarray],
                              camera: PinholeCamera, anchors: Optional[Sequence[int]] = None,
                              config: IntegrationConfig = IntegrationConfig()
                              ) -> IntegrationResult:
    """Integrate normals over many (possibly overlapping) regions at once.

    Args:
        normals: (H, W, 3) normals in the camera frame, pointing towards the
            camera (``n . r < 0``); normalised here; unknown ones (NaN, zero
            length) as ``config.unknown_normals`` says.
        regions: N sorted, unique int arrays of flat pixel indices ``v * W + u``.
        camera: :class:`PinholeCamera` of the normal map's grid.
        anchors: (N,) flat anchor pixel per region (required for
            ``constant="anchor"``; defaults to each region's first pixel); an
            anchor with unknown normal ("nan"): zero mean over the known pixels.
        config: :class:`IntegrationConfig`.
    Returns:
        :class:`IntegrationResult`.
    Raises:
        TypeError (``camera`` not a :class:`PinholeCamera`) / InputError (bad
        normals, empty or unsorted regions, pixels or anchors outside them).
    """
    t0 = time.perf_counter()
    check_camera(camera, "integrate_normals: camera")
    normals = check_normals(normals, "normals", camera.shape + (3,))
    h, w = camera.shape
    npix = h * w
    n = len(regions)
    sizes = np.array([len(r) for r in regions], dtype=np.int64)
    if np.any(sizes == 0):
        raise InputError(f"integrate_normals: region(s) {np.flatnonzero(sizes == 0)[:5].tolist()} "
                         "are empty")
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    if n == 0:
        return IntegrationResult(np.zeros(0), offsets, np.zeros(0, np.int64), 0, {})
    pix, rid, key, lookup = _stack_regions(regions, sizes, npix)
    m_tot = pix.size
    known, m, au, av, pu, pv = _entry_coefficients(normals, pix, camera, config)
    pairs = _edge_pairs(key, pix, pu, pv, lookup, w, h)
    P, Q, c, t = _edge_terms(pairs, known, m, au, av, config)
    n_edges = int(P.size)
    t_build = time.perf_counter()

    # Normal equations of sum_e (c_e (x_q - x_p) + t_e)^2: weighted Laplacian L x = b.
    wgt = c * c
    ct = c * t
    # (float: NumPy's bincount of no entries is integer)
    b = np.bincount(P, ct, m_tot) - np.bincount(Q, ct, m_tot).astype(np.float64)
    diag = np.bincount(P, wgt, m_tot) + np.bincount(Q, wgt, m_tot).astype(np.float64)

    # Connected components of the edge graph (each needs one pinned value).
    graph = sp.csr_matrix((np.ones(n_edges, np.int8), (P, Q)), shape=(m_tot, m_tot))
    n_comp, comp = csgraph.connected_components(graph, directed=False)
    apos_c = _anchor_entries(anchors, pix, offsets, key, n, npix)
    first_of_comp, pin = _pins(comp, n_comp, apos_c)
    diag[pin] += 1.0
    colour = (pu + pv) % 2
    t_assemble = time.perf_counter()

    info: dict = {"solver": config.solver, "n_unknowns": m_tot, "n_edges": n_edges,
                  "n_components": int(n_comp)}
    x = _solve_active(P, Q, wgt, diag, b, comp, n_comp, colour, config, info)
    t_solve = time.perf_counter()
    x, n_components = _fix_constants(x, comp, n_comp, known, rid, first_of_comp, apos_c, n,
                                     config)
    t_end = time.perf_counter()
    info.update(t_build=t_build - t0, t_assemble=t_assemble - t_build, t_solve=t_solve - t_assemble,
                t_finish=t_end - t_solve, t_total=t_end - t0, n_unknown=int((~known).sum()))
    if np.any(n_components > 1):
        log.debug("integrate_normals: %d regions have unlinked parts",
                  int(np.sum(n_components > 1)))
    return IntegrationResult(x, offsets, n_components, n_edges, info, known)


def integrate_normals(normals: np.ndarray, masks: np.ndarray, camera: PinholeCamera,
                      config: IntegrationConfig = IntegrationConfig(),
                      anchors: Optional[Sequence[int]] = None) -> np.ndarray:
    """Integrate normals over dense masks (stable entry point).

    Args:
        normals: (H, W, 3) float normals in spgeo's camera convention (x right,
            y down, z forward; a wall facing the camera has n = (0, 0, -1)).
        masks: (N, H, W) or (H, W) bool (or 0/1); may overlap; non-empty.
        camera: :class:`PinholeCamera` of the (H, W) grid.
        config: solver options; ``anchors`` optional flat anchor pixels.
    Returns:
        (N, H, W) float64 log-depth, NaN outside each mask and where the normal
        is unknown (``IntegrationConfig.unknown_normals``); each mask's additive
        constant is arbitrary (see :class:`IntegrationConfig`).
    Raises:
        as :func:`integrate_normals_regions`; InputError for bad masks too.
    """
    check_camera(camera, "integrate_normals: camera")  # before camera.shape below
    masks = check_mask_stack(masks, camera.shape)
    regions: List[np.ndarray] = [np.flatnonzero(mk) for mk in masks]
    res = integrate_normals_regions(normals, regions, camera, anchors, config)
    out = np.full((masks.shape[0], camera.height * camera.width), np.nan)
    for i, r in enumerate(regions):
        out[i, r] = res.region(i)
    return out.reshape(masks.shape)
