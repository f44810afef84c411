"""Sparse metric depth on one primitive's log-scale (docs/design.md §2, §5).

A primitive's true log-depth at pixel ``u`` is ``l(u) + s`` with ``l = log D``
its unscaled (integrated) log-depth and ``s`` its log-scale.  For sparse depth
measurements ``d_k`` at pixels ``u_k`` inside the primitive the residuals are

    r_k = (l_k + s) - log(d_k)          (log units; l_k = l(u_k))

with noise ``sigma`` in log units (0.01 is about 1 % depth noise).

Robustness is applied **per point inside the factor**: GTSAM's robust noise
models (``noiseModel.Robust``) would reweight the factor's whole residual
vector, so one outlier would down-weight all points of the primitive.  With
``e_k = r_k / sigma`` and the Huber cost ``rho(e) = e^2/2`` for ``|e| <= k``,
``k |e| - k^2/2`` otherwise, the factor returns the re-weighted residual

    r~_k = sigma * phi(e_k),    phi(e) = sign(e) sqrt(2 rho(e)) = sqrt(w(e)) * e,
    w(e) = 2 rho(e) / e^2       (1 for inliers; the IRLS-style square-root weight)

so that the whitened error ``0.5 |r~ / sigma|^2 = sum_k rho(e_k)`` is exactly
the Huber cost and Levenberg–Marquardt's cost-decrease test sees the true
robust objective.  The analytic Jacobian differentiates the weight as well:

    d r~_k / d s = phi'(e_k) = 1                         (|e_k| <= k)
                 = k / sqrt(2 k |e_k| - k^2)             (|e_k| >  k)

so it equals central differences of :meth:`gtsam.CustomFactor.unwhitenedError`
everywhere (tested).  ``huber_k=None`` gives plain least squares.

The log-scale lives in ``gtsam.Values`` as a 1-vector:
``values.insert(key, np.array([s]))``, read with ``values.atVector(key)``.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

import gtsam

__all__ = ["make_sparse_depth_factor", "SparseDepthFactor", "huber_phi"]


def huber_phi(e: np.ndarray, k: Optional[float]):
    """``(phi(e), phi'(e))`` of the square-rooted Huber cost (module docstring).

    ``k=None`` is plain least squares: ``phi(e) = e``, ``phi' = 1``.
    """
    e = np.asarray(e, dtype=np.float64)
    if k is None:
        return e.copy(), np.ones_like(e)
    a = np.abs(e)
    out = a > k
    phi = e.copy()
    dphi = np.ones_like(e)
    if np.any(out):
        root = np.sqrt(2.0 * k * a[out] - k * k)
        phi[out] = np.sign(e[out]) * root
        dphi[out] = k / root
    return phi, dphi


class SparseDepthFactor:
    """Builder / holder of one primitive's sparse-depth ``gtsam.CustomFactor``.

    Args:
        key: gtsam key of the primitive's log-scale (a 1-vector value).
        unscaled_log_depth: (K,) ``l_k``, the primitive's unscaled log-depth at
            the sparse points (log metres relative to the anchor).
        measured_depth: (K,) ``d_k`` metric depths (metres, finite, > 0).
        sigma: measurement noise in log units (> 0); default 0.01 (~1 %).
        huber_k: Huber threshold in units of ``sigma`` (> 0), or None for
            least squares; default 1.345 (95 % Gaussian efficiency).

    Attributes:
        factor: the ``gtsam.CustomFactor`` (add it to a graph).
        target: (K,) ``log d_k - l_k``: each point's own estimate of ``s``.
    """

    def __init__(self, key: int, unscaled_log_depth: np.ndarray, measured_depth: np.ndarray,
                 sigma: float = 0.01, huber_k: Optional[float] = 1.345) -> None:
        l = np.asarray(unscaled_log_depth, dtype=np.float64).reshape(-1)
        d = np.asarray(measured_depth, dtype=np.float64).reshape(-1)
        if l.size == 0:
            raise ValueError("SparseDepthFactor: no sparse point")
        if l.shape != d.shape:
            raise ValueError(f"SparseDepthFactor: {l.size} log-depths but {d.size} measurements")
        if not np.all(np.isfinite(l)):
            raise ValueError("SparseDepthFactor: unscaled log-depth contains NaN or inf")
        if not np.all(np.isfinite(d)) or np.any(d <= 0):
            raise ValueError("SparseDepthFactor: measured depths must be finite and > 0")
        sigma = float(sigma)
        if not np.isfinite(sigma) or sigma <= 0:
            raise ValueError(f"SparseDepthFactor: sigma must be finite and > 0, got {sigma}")
        if huber_k is not None:
            huber_k = float(huber_k)
            if not np.isfinite(huber_k) or huber_k <= 0:
                raise ValueError(f"SparseDepthFactor: huber_k must be > 0 or None, got {huber_k}")
        self.key = int(key)
        self.sigma = sigma
        self.huber_k = huber_k
        self.target = np.log(d) - l
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(l.size, sigma),
                                         [self.key], self._error)

    @property
    def n_points(self) -> int:
        return int(self.target.size)

    def residuals(self, s: float) -> np.ndarray:
        """(K,) raw log residuals ``l_k + s - log d_k`` at log-scale ``s``."""
        return float(s) - self.target

    def robust_residuals(self, s: float):
        """``(r~, d r~ / d s)`` at log-scale ``s`` (module docstring)."""
        e = self.residuals(s) / self.sigma
        phi, dphi = huber_phi(e, self.huber_k)
        return self.sigma * phi, dphi

    def cost(self, s: float) -> float:
        """The factor's error at ``s``: ``sum_k rho(e_k)`` (equals ``factor.error``)."""
        r, _ = self.robust_residuals(s)
        return 0.5 * float(np.sum((r / self.sigma) ** 2))

    def _error(self, this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        s = float(values.atVector(self.key)[0])
        r, dr = self.robust_residuals(s)
        if jacobians is not None:
            jacobians[0] = dr.reshape(-1, 1)
        return r


def make_sparse_depth_factor(key: int, unscaled_log_depth_at_points: np.ndarray,
                             measured_depth: np.ndarray, sigma: float = 0.01,
                             huber_k: Optional[float] = 1.345) -> gtsam.CustomFactor:
    """One ``gtsam.CustomFactor`` tying a primitive's log-scale ``key`` to sparse depths.

    See :class:`SparseDepthFactor` for the arguments and the module docstring
    for the residual, the per-point Huber weighting and the Jacobian.
    """
    return SparseDepthFactor(key, unscaled_log_depth_at_points, measured_depth, sigma,
                             huber_k).factor
