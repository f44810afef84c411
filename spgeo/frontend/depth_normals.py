"""Normal estimators that need no learned model.

* :class:`DepthNormalEstimator` — **uses depth** (``uses_depth = True``): unit
  normals computed from a depth image (an RGB-D sensor's, or ground truth for
  oracle ablations).  It is *not* a monocular estimator; use it only where the
  task legitimately has depth or to isolate the segmentation / back-end from
  normal-prediction errors.
* :class:`FrontoParallelNormals` — ``(0, 0, -1)`` everywhere: integrating these
  gives a constant depth per primitive (the paper's "constant depth" ablation).

Conventions (``spgeo.frontend.base.NormalEstimator``): camera frame x right,
y down, z forward; normals point towards the camera (``n · X < 0`` for the
surface point ``X``); output float32 (H, W, 3), NaN where unknown.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from ..camera import PinholeCamera
from ..configs import config_class
from .base import config_with_overrides

__all__ = ["DepthNormalEstimatorConfig", "DepthNormalEstimator", "FrontoParallelNormals",
           "normals_from_depth"]

logger = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class DepthNormalEstimatorConfig:
    """Configuration of :class:`DepthNormalEstimator`.

    Attributes:
        method: ``"pca"`` (default): plane fit to the points of a ``window`` x
            ``window`` neighbourhood (normal = eigenvector of the smallest
            eigenvalue of their covariance) — robust to noise and holes.
            ``"differences"``: cross product of the two image-axis tangents
            from central differences where both neighbours are usable, else
            one-sided differences, else NaN (optionally on a point map smoothed
            over ``window``, see ``smooth``).
        window: odd neighbourhood size in pixels (PCA window; smoothing window
            of ``"differences"``).  Default 5.
        smooth: ``"differences"`` only: average each point with its accepted
            neighbours in the window before differencing.  Default False.
        max_incidence_deg: edge-aware neighbour test.  A neighbour at pixel
            offset ``(du, dv)`` is used only if its depth differs from the
            centre's by at most ``z * tan(max_incidence_deg) *
            hypot(du / fx, dv / fy)`` — the change a surface seen at this
            incidence angle would produce — so windows never straddle a depth
            discontinuity.  ``None`` disables the test.  Default 80.
        min_valid_fraction: PCA: minimum fraction of the window that must be
            valid, accepted points (and at least 3).  Default 0.3.
        min_planarity: PCA: the fit is rejected (NaN) when the middle
            eigenvalue is below this fraction of the largest (points nearly on
            a line).  Default 1e-3.
        fill_holes: replace NaN normals by the nearest known normal
            (Euclidean nearest pixel).  Default False: unknown stays NaN.
    """

    method: str = "pca"
    window: int = 5
    smooth: bool = False
    max_incidence_deg: Optional[float] = 80.0
    min_valid_fraction: float = 0.3
    min_planarity: float = 1e-3
    fill_holes: bool = False

    def __post_init__(self) -> None:
        if self.method not in ("pca", "differences"):
            raise ValueError(f"DepthNormalEstimatorConfig: method must be 'pca' or "
                             f"'differences', got {self.method!r}")
        if int(self.window) != self.window or self.window < 3 or self.window % 2 == 0:
            raise ValueError(f"DepthNormalEstimatorConfig: window must be an odd integer >= 3, "
                             f"got {self.window!r}")
        if self.max_incidence_deg is not None and not (0.0 < self.max_incidence_deg < 90.0):
            raise ValueError("DepthNormalEstimatorConfig: max_incidence_deg must be in (0, 90) "
                             "or None")
        if not (0.0 <= self.min_valid_fraction <= 1.0):
            raise ValueError("DepthNormalEstimatorConfig: min_valid_fraction must be in [0, 1]")
        if not (0.0 <= self.min_planarity < 1.0):
            raise ValueError("DepthNormalEstimatorConfig: min_planarity must be in [0, 1)")


# ----------------------------------------------------------------------------- helpers
def _shifted(a: np.ndarray, dv: int, du: int, fill) -> np.ndarray:
    """``out[v, u] = a[v + dv, u + du]`` with ``fill`` outside the image."""
    h, w = a.shape[:2]
    out = np.full_like(a, fill)
    v0, v1 = max(0, -dv), min(h, h - dv)
    u0, u1 = max(0, -du), min(w, w - du)
    if v0 < v1 and u0 < u1:
        out[v0:v1, u0:u1] = a[v0 + dv:v1 + dv, u0 + du:u1 + du]
    return out


def _accept(z_c: np.ndarray, z_n: np.ndarray, du: int, dv: int, camera: PinholeCamera,
            tan_max: Optional[float]) -> np.ndarray:
    """Bool mask: neighbour depth ``z_n`` usable for centre depth ``z_c`` (NaN -> False)."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(z_n) & np.isfinite(z_c)
        if tan_max is not None:
            tol = z_c * (tan_max * float(np.hypot(du / camera.fx, dv / camera.fy)))
            ok &= np.abs(z_n - z_c) <= tol
    return ok


def _orient_and_normalise(n: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Unit normals (NaN where degenerate) flipped so that ``n · ray < 0``."""
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(norm > 0, n / norm, np.nan)
        flip = np.sum(n * rays, axis=-1, keepdims=True) > 0
    return np.where(flip, -n, n)


def _fill_nearest(normals: np.ndarray) -> np.ndarray:
    unknown = ~np.isfinite(normals).all(axis=-1)
    if not unknown.any() or unknown.all():
        return normals
    _, (iv, iu) = ndimage.distance_transform_edt(unknown, return_indices=True)
    return normals[iv, iu]


def _smallest_eigvec_sym3(a00, a11, a22, a01, a02, a12, min_planarity: float) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of many symmetric 3x3 matrices.

    Closed form (Smith 1961 trigonometric eigenvalues; the eigenvector is the
    longest cross product of two rows of ``A - lambda_min I``), vectorised over
    N matrices instead of ``np.linalg.eigh`` on (N, 3, 3).  NaN where the matrix is
    isotropic or where ``lambda_mid < min_planarity * lambda_max`` (points on a
    line: no plane).
    """
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_p = np.where(p > 0, 1.0 / p, 0.0)
        det_b = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
                 + a02 * (a01 * a12 - b11 * a02)) * inv_p ** 3
        phi = np.arccos(np.clip(det_b * 0.5, -1.0, 1.0)) / 3.0
        lam_max = q + 2.0 * p * np.cos(phi)
        lam_min = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
        lam_mid = 3.0 * q - lam_max - lam_min
        d0, d1, d2 = a00 - lam_min, a11 - lam_min, a22 - lam_min
        # rows r0 = (d0, a01, a02), r1 = (a01, d1, a12), r2 = (a02, a12, d2)
        ca = (a01 * a12 - a02 * d1, a02 * a01 - d0 * a12, d0 * d1 - a01 * a01)  # r0 x r1
        cb = (a01 * d2 - a02 * a12, a02 * a02 - d0 * d2, d0 * a12 - a01 * a02)  # r0 x r2
        cc = (d1 * d2 - a12 * a12, a12 * a02 - a01 * d2, a01 * a12 - d1 * a02)  # r1 x r2
        na = ca[0] * ca[0] + ca[1] * ca[1] + ca[2] * ca[2]
        nb = cb[0] * cb[0] + cb[1] * cb[1] + cb[2] * cb[2]
        nc = cc[0] * cc[0] + cc[1] * cc[1] + cc[2] * cc[2]
        use_b = nb > na
        n2 = np.where(use_b, nb, na)
        vec = [np.where(use_b, cb[i], ca[i]) for i in range(3)]
        use_c = nc > n2
        n2 = np.where(use_c, nc, n2)
        norm = np.sqrt(n2)
        inv = np.where(norm > 0, 1.0 / norm, np.nan)
        n = np.stack([np.where(use_c, cc[i], vec[i]) * inv for i in range(3)], axis=-1)
    bad = ~(p > 0) | ~(norm > 0) | ~(lam_mid > min_planarity * np.maximum(lam_max, 0.0))
    n[bad] = np.nan
    return n


def _box_moments(x: np.ndarray, y: np.ndarray, zz: np.ndarray, m: np.ndarray, k: int):
    """``(count, [sx, sy, sz], [sxx, syy, szz, sxy, sxz, syz])``: sums over every
    ``k`` x ``k`` window (``cv2.boxFilter``, zero outside the image)."""
    import cv2

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, cv2.CV_64F, (k, k), normalize=False,
                             borderType=cv2.BORDER_CONSTANT)

    cnt = box(m)
    s = [box(x), box(y), box(zz)]
    ss = [box(x * x), box(y * y), box(zz * zz), box(x * y), box(x * zz), box(y * zz)]
    return cnt, s, ss


def _near_depth_edges(z: np.ndarray, valid: np.ndarray, k: int, tan_max: Optional[float],
                      camera: PinholeCamera) -> np.ndarray:
    """Valid pixels whose window might hold a rejected neighbour (edge-aware path)."""
    import cv2

    if tan_max is None:
        return np.zeros_like(valid)
    kernel = np.ones((k, k), np.uint8)
    z_lo = cv2.erode(np.where(valid, z, np.inf), kernel, borderType=cv2.BORDER_CONSTANT,
                     borderValue=np.inf)
    z_hi = cv2.dilate(np.where(valid, z, -np.inf), kernel, borderType=cv2.BORDER_CONSTANT,
                      borderValue=-np.inf)
    tol_min = tan_max * min(1.0 / camera.fx, 1.0 / camera.fy)
    with np.errstate(invalid="ignore"):
        return valid & ((z_hi - z > tol_min * z) | (z - z_lo > tol_min * z))


def _central_covariance(cnt: np.ndarray, s: list, ss: list):
    """``(cov, count)`` flat: the 6 entries xx, yy, zz, xy, xz, yz of each window's
    central covariance E[XX^T] - E[X]E[X]^T (translation invariant) and its count."""
    with np.errstate(invalid="ignore", divide="ignore"):
        c_safe = np.maximum(cnt, 1.0)
        mean = [s[i] / c_safe for i in range(3)]
        sec = [ss[i] / c_safe for i in range(6)]
    cov = [sec[0] - mean[0] ** 2, sec[1] - mean[1] ** 2, sec[2] - mean[2] ** 2,
           sec[3] - mean[0] * mean[1], sec[4] - mean[0] * mean[2], sec[5] - mean[1] * mean[2]]
    return [c.ravel() for c in cov], cnt.ravel().copy()


def _edge_aware_sums(idx: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray,
                     valid: np.ndarray, r: int, tan_max: float,
                     camera: PinholeCamera) -> np.ndarray:
    """(10, len(idx)) sums over the accepted neighbours of the pixels ``idx``: count,
    the offsets ``X_neighbour - X_centre`` (3) and their products (6), gathered from
    padded flat arrays once per window offset."""
    w = z.shape[1]
    wp = w + 2 * r
    pad = ((r, r), (r, r))
    zp = np.pad(np.where(valid, z, np.nan), pad, constant_values=np.nan).ravel()
    xp = np.pad(x, pad).ravel()
    yp = np.pad(y, pad).ravel()
    base = (idx // w + r) * wp + (idx % w + r)
    zc, xc, yc = zp[base], xp[base], yp[base]
    acc = np.zeros((10, idx.size))
    for dv in range(-r, r + 1):
        for du in range(-r, r + 1):
            nb = base + dv * wp + du
            dz = zp[nb] - zc
            with np.errstate(invalid="ignore"):
                if dv == 0 and du == 0:
                    ok = np.isfinite(dz)
                else:
                    tol = tan_max * float(np.hypot(du / camera.fx, dv / camera.fy))
                    ok = np.abs(dz) <= tol * zc
            dz = np.where(ok, dz, 0.0)
            dx = np.where(ok, xp[nb] - xc, 0.0)
            dy = np.where(ok, yp[nb] - yc, 0.0)
            acc[0] += ok
            acc[1] += dx
            acc[2] += dy
            acc[3] += dz
            acc[4] += dx * dx
            acc[5] += dy * dy
            acc[6] += dz * dz
            acc[7] += dx * dy
            acc[8] += dx * dz
            acc[9] += dy * dz
    return acc


def _set_edge_aware_covariance(cov: list, cnt_flat: np.ndarray, idx: np.ndarray,
                               acc: np.ndarray) -> None:
    """Overwrite the covariance and count of the pixels ``idx`` with the edge-aware ones."""
    c = acc[0]
    mu = acc[1:4] / c
    cnt_flat[idx] = c
    cov[0][idx] = acc[4] / c - mu[0] ** 2
    cov[1][idx] = acc[5] / c - mu[1] ** 2
    cov[2][idx] = acc[6] / c - mu[2] ** 2
    cov[3][idx] = acc[7] / c - mu[0] * mu[1]
    cov[4][idx] = acc[8] / c - mu[0] * mu[2]
    cov[5][idx] = acc[9] / c - mu[1] * mu[2]


def _pca_normals(points: np.ndarray, z: np.ndarray, camera: PinholeCamera,
                 cfg: DepthNormalEstimatorConfig) -> np.ndarray:
    """Plane-fit normals from the covariance of the accepted window points.

    Two vectorised paths give the same moments:

    * fast path: box filters (``cv2.boxFilter``) of the point moments 1, x, y,
      z, xx, ..., with invalid pixels weighted out — exact wherever the whole
      window passes the edge-aware test (checked conservatively with min/max
      filters of the depth);
    * edge-aware path, only for the remaining valid pixels (near depth
      discontinuities): moments of the offsets ``X_neighbour - X_centre`` of
      the accepted neighbours, gathered from padded flat arrays once per
      window offset.
    """
    h, w = z.shape
    k = int(cfg.window)
    r = k // 2
    tan_max = None if cfg.max_incidence_deg is None else float(np.tan(np.radians(
        cfg.max_incidence_deg)))
    valid = np.isfinite(z)
    x = np.where(valid, points[..., 0], 0.0)
    y = np.where(valid, points[..., 1], 0.0)
    zz = np.where(valid, z, 0.0)
    m = valid.astype(np.float64)
    cnt, s, ss = _box_moments(x, y, zz, m, k)
    slow = _near_depth_edges(z, valid, k, tan_max, camera)
    cov, cnt_flat = _central_covariance(cnt, s, ss)
    idx = np.flatnonzero(slow)
    if idx.size:
        acc = _edge_aware_sums(idx, x, y, z, valid, r, tan_max, camera)
        _set_edge_aware_covariance(cov, cnt_flat, idx, acc)

    min_count = max(3.0, cfg.min_valid_fraction * k * k)
    good = np.flatnonzero(valid.ravel() & (cnt_flat >= min_count))
    normals = np.full((h * w, 3), np.nan)
    if good.size:
        # per-pixel scale normalisation, then float32 (ample for a unit vector)
        sel = [c[good] for c in cov]
        scale = sel[0] + sel[1] + sel[2]
        inv = np.where(scale > 0, 1.0 / np.where(scale > 0, scale, 1.0), 0.0)
        sel = [(c * inv).astype(np.float32) for c in sel]
        normals[good] = _smallest_eigvec_sym3(*sel, min_planarity=cfg.min_planarity)
    return normals.reshape(h, w, 3)


def _difference_normals(points: np.ndarray, z: np.ndarray, camera: PinholeCamera,
                        cfg: DepthNormalEstimatorConfig) -> np.ndarray:
    tan_max = None if cfg.max_incidence_deg is None else float(np.tan(np.radians(
        cfg.max_incidence_deg)))
    if cfg.smooth:
        r = cfg.window // 2
        acc = np.zeros_like(points)
        cnt = np.zeros(z.shape)
        for dv in range(-r, r + 1):
            for du in range(-r, r + 1):
                z_n = _shifted(z, dv, du, np.nan)
                ok = _accept(z, z_n, du, dv, camera, tan_max)
                acc += np.where(ok[..., None], _shifted(points, dv, du, np.nan), 0.0)
                cnt += ok
        with np.errstate(invalid="ignore", divide="ignore"):
            points = np.where((cnt > 0)[..., None], acc / cnt[..., None], np.nan)

    def tangent(axis_du: int, axis_dv: int) -> np.ndarray:
        p_f = _shifted(points, axis_dv, axis_du, np.nan)
        p_b = _shifted(points, -axis_dv, -axis_du, np.nan)
        ok_f = _accept(z, _shifted(z, axis_dv, axis_du, np.nan), axis_du, axis_dv, camera,
                       tan_max)
        ok_b = _accept(z, _shifted(z, -axis_dv, -axis_du, np.nan), -axis_du, -axis_dv, camera,
                       tan_max)
        central = (p_f - p_b) * 0.5
        forward = p_f - points
        backward = points - p_b
        t = np.where((ok_f & ok_b)[..., None], central,
                     np.where(ok_f[..., None], forward,
                              np.where(ok_b[..., None], backward, np.nan)))
        return t

    t_u = tangent(1, 0)
    t_v = tangent(0, 1)
    n = np.cross(t_u, t_v)
    n[~np.isfinite(z)] = np.nan
    return n


def normals_from_depth(depth: np.ndarray, camera: PinholeCamera,
                       config: Optional[DepthNormalEstimatorConfig] = None) -> np.ndarray:
    """Unit normals (float32 (H, W, 3), towards the camera) of a depth map.

    ``depth`` in metres along the optical axis, (H, W) matching ``camera``;
    NaN, inf, 0 and negative values are invalid.  Raises ``ValueError`` on a
    wrong shape or when no pixel is valid.
    """
    cfg = config or DepthNormalEstimatorConfig()
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a (H, W) array, got shape {depth.shape}")
    if depth.shape != camera.shape:
        raise ValueError(f"depth has shape {depth.shape}, expected {camera.shape} for {camera}")
    if not (np.issubdtype(depth.dtype, np.floating) or np.issubdtype(depth.dtype, np.integer)):
        raise ValueError(f"depth must be numeric, got dtype {depth.dtype}")
    points = camera.unproject_depth_map(depth)  # NaN where invalid
    z = points[..., 2]
    n_valid = int(np.count_nonzero(np.isfinite(z)))
    if n_valid == 0:
        raise ValueError("depth has no valid pixel (all NaN / inf / <= 0)")
    if cfg.method == "pca":
        n = _pca_normals(points, z, camera, cfg)
    else:
        n = _difference_normals(points, z, camera, cfg)
    normals = _orient_and_normalise(n, camera.rays())
    if cfg.fill_holes:
        normals = _fill_nearest(normals)
    out = normals.astype(np.float32)
    logger.debug("normals_from_depth(%s): %d valid depth, %d known normals", cfg.method,
                 n_valid, int(np.count_nonzero(np.isfinite(out[..., 0]))))
    return out


# ----------------------------------------------------------------------------- estimators
class DepthNormalEstimator:
    """Normals from depth (RGB-D / oracle).  **Uses depth**: ``uses_depth = True``.

    Implements :class:`spgeo.frontend.base.NormalEstimator`; ``estimate``
    ignores the image content (its shape is checked) and requires ``depth``.
    See :class:`DepthNormalEstimatorConfig` and :func:`normals_from_depth`.
    """

    uses_depth: bool = True

    def __init__(self, config: Optional[DepthNormalEstimatorConfig] = None, **overrides) -> None:
        self.config = config_with_overrides(DepthNormalEstimatorConfig, config, overrides)

    def estimate(self, image: Optional[np.ndarray], camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        if depth is None:
            raise ValueError("DepthNormalEstimator needs a depth image (it is an RGB-D / oracle "
                             "estimator); got depth=None")
        if image is not None:
            camera.check_image(image)
        return normals_from_depth(depth, camera, self.config)

    def __repr__(self) -> str:
        return f"DepthNormalEstimator({self.config!r})"


class FrontoParallelNormals:
    """Constant normal ``(0, 0, -1)``: every primitive integrates to constant depth
    (the paper's "constant depth per primitive" ablation).  Uses no depth."""

    uses_depth: bool = False

    def estimate(self, image: Optional[np.ndarray], camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        if image is not None:
            camera.check_image(image)
        out = np.zeros((camera.height, camera.width, 3), dtype=np.float32)
        out[..., 2] = -1.0
        return out

    def __repr__(self) -> str:
        return "FrontoParallelNormals()"
