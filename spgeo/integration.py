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
log-depth and counted in :attr:`IntegrationResult.n_components`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from .camera import PinholeCamera

__all__ = ["IntegrationConfig", "IntegrationResult", "integrate_normals",
           "integrate_normals_regions"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class IntegrationConfig:
    """Options of the batched normal integration.

    Attributes:
        solver: ``"direct"`` (default: exact red-black elimination, then sparse
            LU (SuperLU) of the half-size Schur complement) or ``"cg"``
            (Jacobi-preconditioned conjugate gradients, as the authors ran on a
            GPU; kept for comparison).  ``evaluation/bench_integration.py``
            compares them (results in docs/results.md).
        natural_order_max_band: use SuperLU's natural ordering when every
            region's raster bandwidth is at most this (small masks), else a
            minimum-degree ordering (default 96).
        cg_tol: relative residual tolerance of CG (default 1e-6; the authors
            used 1e-3).
        cg_maxiter: iteration cap for CG (default 1000, as the authors).
        constant: ``"anchor"`` (log-depth 0 at each mask's anchor pixel) or
            ``"mean"`` (zero mean over each mask).
        min_abs_m: lower bound on ``|n . r|`` (near-grazing or back-facing
            normals are clamped to ``-min_abs_m`` to keep gradients bounded).
    """

    solver: str = "direct"
    cg_tol: float = 1e-6
    cg_maxiter: int = 1000
    natural_order_max_band: int = 96
    constant: str = "anchor"
    min_abs_m: float = 0.05

    def __post_init__(self) -> None:
        if self.solver not in ("direct", "cg"):
            raise ValueError("IntegrationConfig.solver must be 'direct' or 'cg', "
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
    """

    log_depth: np.ndarray
    offsets: np.ndarray
    n_components: np.ndarray
    n_edges: int
    solver_info: dict = field(default_factory=dict)

    def region(self, i: int) -> np.ndarray:
        return self.log_depth[self.offsets[i]:self.offsets[i + 1]]


def _edges(key: np.ndarray, pix_u: np.ndarray, pix_v: np.ndarray, width: int, height: int,
           du: int, dv: int):
    """Entries (p, q) with q the (du, dv)-neighbour of p in the same region
    (``dv`` in {0, 1}; image borders never wrap into the next row or region)."""
    target = key + dv * width + du
    pos = np.searchsorted(key, target)
    pos_c = np.minimum(pos, key.size - 1)
    ok = (pos < key.size) & (key[pos_c] == target)
    if du == 1:
        ok &= pix_u < width - 1
    elif du == -1:
        ok &= pix_u > 0
    if dv == 1:
        ok &= pix_v < height - 1
    p = np.flatnonzero(ok)
    return p, pos_c[p]


def _solve_red_black(L: sp.csr_matrix, b: np.ndarray, colour: np.ndarray,
                     permc_spec: str) -> np.ndarray:
    """Solve the SPD system ``L x = b`` by exact red-black reduction + sparse LU.

    "Red" unknowns (one checkerboard colour) that couple to no other red
    unknown have a diagonal block, so they are eliminated exactly; the Schur
    complement on the remaining unknowns (about half) is factorised by SuperLU
    and the red values are recovered by back-substitution.
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
    x[B] = spla.splu(S, permc_spec=permc_spec).solve(rhs)
    x[R] = (b[R] - L_rb @ x[B]) / d_r
    return x


def integrate_normals_regions(normals: np.ndarray, regions: Sequence[np.ndarray],
                              camera: PinholeCamera, anchors: Optional[Sequence[int]] = None,
                              config: IntegrationConfig = IntegrationConfig()
                              ) -> IntegrationResult:
    """Integrate normals over many (possibly overlapping) regions at once.

    Args:
        normals: (H, W, 3) unit normals in the camera frame, pointing towards
            the camera (``n . r < 0``).  NaN marks unknown normals: edges whose
            two normals are both unknown are dropped.
        regions: N sorted, unique int arrays of flat pixel indices ``v * W + u``.
        camera: intrinsics of the normal map's grid.
        anchors: (N,) flat anchor pixel per region (required for
            ``constant="anchor"``; defaults to each region's first pixel).
        config: :class:`IntegrationConfig`.
    Returns:
        :class:`IntegrationResult`.
    """
    t0 = time.perf_counter()
    normals = np.asarray(camera.check_image(normals, "normals"), dtype=np.float64)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise ValueError(f"normals must be (H, W, 3), got {normals.shape}")
    h, w = camera.shape
    npix = h * w
    n = len(regions)
    sizes = np.array([len(r) for r in regions], dtype=np.int64)
    if np.any(sizes == 0):
        raise ValueError(f"integrate_normals: region(s) {np.flatnonzero(sizes == 0)[:5].tolist()} "
                         "are empty")
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    if n == 0:
        return IntegrationResult(np.zeros(0), offsets, np.zeros(0, np.int64), 0, {})
    pix = np.concatenate([np.asarray(r, dtype=np.int64) for r in regions])
    if pix.min() < 0 or pix.max() >= npix:
        raise ValueError("integrate_normals: region pixel index outside the image")
    rid = np.repeat(np.arange(n, dtype=np.int64), sizes)
    key = rid * npix + pix
    if np.any(np.diff(key) <= 0):
        raise ValueError("integrate_normals: each region's pixels must be sorted and unique")
    m_tot = pix.size

    # Per-entry coefficients: m = n . r, a_u = nx / fx, a_v = ny / fy.
    nrm = normals.reshape(-1, 3)[pix]
    known = np.all(np.isfinite(nrm), axis=1)
    pu = pix % w
    pv = pix // w
    rx = (pu - camera.cx) / camera.fx
    ry = (pv - camera.cy) / camera.fy
    nrm = np.where(known[:, None], nrm, 0.0)
    m = nrm[:, 0] * rx + nrm[:, 1] * ry + nrm[:, 2]
    m = np.minimum(m, -config.min_abs_m)
    au = nrm[:, 0] / camera.fx
    av = nrm[:, 1] / camera.fy

    # Edges: right, down always; diagonals only where the 4-neighbour path is missing.
    p_r, q_r = _edges(key, pu, pv, w, h, 1, 0)
    p_d, q_d = _edges(key, pu, pv, w, h, 0, 1)
    has_r = np.zeros(m_tot, bool)
    has_r[p_r] = True
    has_d = np.zeros(m_tot, bool)
    has_d[p_d] = True
    has_l = np.zeros(m_tot, bool)  # left neighbour exists  <=> some p_r points here
    has_l[q_r] = True
    # p -> p+(1,1) is already linked through p's right or p's lower neighbour
    p_dr, q_dr = _edges(key, pu, pv, w, h, 1, 1)
    keep = ~(has_r[p_dr] | has_d[p_dr])
    p_dr, q_dr = p_dr[keep], q_dr[keep]
    # p -> p+(-1,1) is already linked through p's left or p's lower neighbour
    p_dl, q_dl = _edges(key, pu, pv, w, h, -1, 1)
    keep = ~(has_l[p_dl] | has_d[p_dl])
    p_dl, q_dl = p_dl[keep], q_dl[keep]

    P = np.concatenate([p_r, p_d, p_dr, p_dl])
    Q = np.concatenate([q_r, q_d, q_dr, q_dl])
    DU = np.concatenate([np.ones(p_r.size), np.zeros(p_d.size), np.ones(p_dr.size),
                         -np.ones(p_dl.size)])
    DV = np.concatenate([np.zeros(p_r.size), np.ones(p_d.size), np.ones(p_dr.size),
                         np.ones(p_dl.size)])
    both_unknown = ~known[P] & ~known[Q]
    # an unknown normal borrows its partner's coefficients on that edge
    wp = known[P].astype(np.float64)
    wq = known[Q].astype(np.float64)
    wsum = np.maximum(wp + wq, 1.0)
    c = (wp * m[P] + wq * m[Q]) / wsum
    t = (DU * (wp * au[P] + wq * au[Q]) + DV * (wp * av[P] + wq * av[Q])) / wsum
    sel = ~both_unknown
    P, Q, c, t = P[sel], Q[sel], c[sel], t[sel]
    n_edges = int(P.size)
    t_build = time.perf_counter()

    # Normal equations of sum_e (c_e (x_q - x_p) + t_e)^2: weighted Laplacian L x = b.
    wgt = c * c
    rows = np.concatenate([P, Q, P, Q])
    cols = np.concatenate([P, Q, Q, P])
    vals = np.concatenate([wgt, wgt, -wgt, -wgt])
    L = sp.csr_matrix((vals, (rows, cols)), shape=(m_tot, m_tot))
    ct = c * t
    b = np.bincount(P, weights=ct, minlength=m_tot) - np.bincount(Q, weights=ct, minlength=m_tot)

    # Connected components of the edge graph (each needs one pinned value); L's
    # off-diagonal pattern is the edge graph (weights c^2 >= min_abs_m^2 > 0).
    n_comp, comp = csgraph.connected_components(L, directed=False)
    if anchors is None:
        anchor_pix = pix[offsets[:-1]]
    else:
        anchor_pix = np.asarray(anchors, dtype=np.int64).reshape(-1)
        if anchor_pix.shape != (n,):
            raise ValueError(f"integrate_normals: {anchor_pix.size} anchors for {n} regions")
    akey = np.arange(n) * npix + anchor_pix
    apos = np.searchsorted(key, akey)
    apos_c = np.minimum(apos, m_tot - 1)
    if not np.all((apos < m_tot) & (key[apos_c] == akey)):
        bad = np.flatnonzero(~((apos < m_tot) & (key[apos_c] == akey)))[:5]
        raise ValueError(f"integrate_normals: anchor outside its region for regions {bad.tolist()}")
    # pin: the anchor in its component, the first entry of every other component
    first_of_comp = np.full(n_comp, -1, dtype=np.int64)
    order = np.arange(m_tot)[::-1]
    first_of_comp[comp[order]] = order
    pin = first_of_comp.copy()
    pin[comp[apos_c]] = apos_c
    diag_add = np.zeros(m_tot)
    diag_add[pin] = 1.0
    L = L + sp.diags(diag_add)
    t_assemble = time.perf_counter()

    info: dict = {"solver": config.solver, "n_unknowns": m_tot, "n_edges": n_edges,
                  "n_components": int(n_comp)}
    if config.solver == "direct":
        # Entries are block (region) ordered and raster ordered inside each
        # region, so the natural order is already banded per block; for wide
        # regions a fill-reducing ordering (threshold: natural_order_max_band).
        widths = np.zeros(n, dtype=np.int64)
        np.maximum.at(widths, rid[P], Q - P)
        permc = "NATURAL" if widths.max(initial=0) <= config.natural_order_max_band else "MMD_AT_PLUS_A"
        x = _solve_red_black(L.tocsr(), b, (pu + pv) % 2, permc)
        info["iterations"] = 1
        info["ordering"] = permc
    else:
        dinv = 1.0 / L.diagonal()
        M = sp.diags(dinv)
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
    t_solve = time.perf_counter()

    # Fix constants: per component mean or anchor; unlinked parts at equal mean.
    comp_sum = np.bincount(comp, weights=x, minlength=n_comp)
    comp_cnt = np.bincount(comp, minlength=n_comp)
    comp_mean = comp_sum / comp_cnt
    x = x - comp_mean[comp]  # every component now has zero mean
    comp_region = rid[first_of_comp]
    n_components = np.bincount(comp_region, minlength=n).astype(np.int64)
    if config.constant == "anchor":
        x = x - x[apos_c][rid]
    else:
        rmean = np.bincount(rid, weights=x, minlength=n) / sizes
        x = x - rmean[rid]
    t_end = time.perf_counter()
    info.update(t_build=t_build - t0, t_assemble=t_assemble - t_build, t_solve=t_solve - t_assemble,
                t_finish=t_end - t_solve, t_total=t_end - t0)
    if np.any(n_components > 1):
        log.debug("integrate_normals: %d regions have unlinked parts",
                  int(np.sum(n_components > 1)))
    return IntegrationResult(x, offsets, n_components, n_edges, info)


def integrate_normals(normals: np.ndarray, masks: np.ndarray, camera: PinholeCamera,
                      config: IntegrationConfig = IntegrationConfig(),
                      anchors: Optional[Sequence[int]] = None) -> np.ndarray:
    """Integrate normals over dense masks (stable entry point).

    Args:
        normals: (H, W, 3) float unit normals in spgeo's camera convention
            (x right, y down, z forward; a wall facing the camera has n = (0, 0, -1)).
        masks: (N, H, W) bool; masks may overlap; each must be non-empty.
        camera: :class:`PinholeCamera` of the (H, W) grid.
        config: solver options; ``anchors`` optional flat anchor pixels.
    Returns:
        (N, H, W) float64 log-depth, NaN outside each mask; each mask's
        additive constant is arbitrary (see :class:`IntegrationConfig`).
    """
    masks = np.asarray(masks)
    if masks.ndim == 2:
        masks = masks[None]
    if masks.ndim != 3 or masks.shape[1:] != camera.shape:
        raise ValueError(f"masks must be (N, {camera.height}, {camera.width}), got {masks.shape}")
    masks = masks.astype(bool)
    regions: List[np.ndarray] = [np.flatnonzero(mk) for mk in masks]
    res = integrate_normals_regions(normals, regions, camera, anchors, config)
    out = np.full((masks.shape[0], camera.height * camera.width), np.nan)
    for i, r in enumerate(regions):
        out[i, r] = res.region(i)
    return out.reshape(masks.shape)
