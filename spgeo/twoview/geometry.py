"""Epipolar geometry helpers of the two-view estimator (:mod:`spgeo.twoview`).

Pixel correspondences ``x1`` (reference) and ``x2`` (target) are (N, 2) arrays
in spgeo pixel coordinates (pixel centres at integers) of an undistorted
:class:`~spgeo.camera.PinholeCamera`; a relative pose ``(R, t)`` maps
reference to target coordinates, ``x_tgt = R x_ref + t`` (``T_tgt_ref``).
"""
from __future__ import annotations

import math
from typing import Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import nearest_rotation, so3_exp

__all__ = [
    "bearings", "parallax_angles_deg", "kabsch", "rotation_only_fit", "pose_from_tgt_ref",
    "undistort_points", "skew", "sampson_px", "tangent_basis", "pose_std_deg",
    "refine_sampson", "positive_depth",
]


def bearings(camera: PinholeCamera, pts: np.ndarray) -> np.ndarray:
    """(N, 3) unit rays of (N, 2) pixels (distortion ignored)."""
    f = np.stack([(pts[:, 0] - camera.cx) / camera.fx, (pts[:, 1] - camera.cy) / camera.fy,
                  np.ones(len(pts))], axis=1)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def parallax_angles_deg(camera: PinholeCamera, pts_ref: np.ndarray, pts_tgt: np.ndarray,
                        R_tgt_ref: np.ndarray) -> np.ndarray:
    """Rotation-compensated parallax angle (degrees) of each correspondence:
    the angle between the target ray and the reference ray rotated into the
    target frame (``R_tgt_ref @ f_ref``).  Zero for pure rotation."""
    f1 = bearings(camera, np.asarray(pts_ref, float)) @ np.asarray(R_tgt_ref, float).T
    f2 = bearings(camera, np.asarray(pts_tgt, float))
    s = np.linalg.norm(np.cross(f1, f2), axis=1)
    c = np.sum(f1 * f2, axis=1)
    return np.degrees(np.arctan2(s, c))


def kabsch(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising ``sum |f2 - R f1|^2`` over unit rays: the rotation
    nearest ``sum f2 f1^T`` (:func:`~spgeo.geometry.nearest_rotation` of its transpose
    ``f1^T f2``, transposed back into a C-ordered array)."""
    return nearest_rotation(f1.T @ f2).T.copy()


def rotation_only_fit(camera: PinholeCamera, pts_ref: np.ndarray, pts_tgt: np.ndarray,
                      max_error_px: float = 2.0, iterations: int = 5) -> Tuple[np.ndarray, np.ndarray]:
    """Robust rotation-only model ``f_tgt ~ R_tgt_ref f_ref`` (Kabsch on rays,
    re-fitted on the points whose rotated ray lands within ``max_error_px``).

    Returns ``(R_tgt_ref (3, 3), inlier mask)``."""
    f1 = bearings(camera, np.asarray(pts_ref, float))
    f2 = bearings(camera, np.asarray(pts_tgt, float))
    keep = np.ones(len(f1), bool)
    R = np.eye(3)
    tol = math.atan(float(max_error_px) / max(camera.fx, camera.fy))
    for _ in range(max(1, int(iterations))):
        if keep.sum() < 3:
            break
        R = kabsch(f1[keep], f2[keep])
        ang = np.arctan2(np.linalg.norm(np.cross(f1 @ R.T, f2), axis=1), np.sum(f1 @ R.T * f2, 1))
        new_keep = ang < max(tol, np.median(ang) * 3.0)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return R, keep


def pose_from_tgt_ref(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``T_ref_tgt`` from ``x_tgt = R x_ref + t`` (translation normalised if nonzero)."""
    R = np.asarray(R, float)
    t = np.asarray(t, float).reshape(3)
    T = np.eye(4)
    T[:3, :3] = R.T
    c = -R.T @ t
    n = np.linalg.norm(c)
    T[:3, 3] = c / n if n > 0 else c
    return T


def undistort_points(camera: PinholeCamera, pts: np.ndarray) -> np.ndarray:
    """(N, 2) undistorted pixels of ``camera`` (unchanged without distortion)."""
    if camera.distortion is None or len(pts) == 0:
        return pts
    import cv2

    out = cv2.undistortPoints(pts.reshape(-1, 1, 2).astype(np.float64), camera.K,
                              np.asarray(camera.distortion, float), P=camera.K)
    return out.reshape(-1, 2)


def skew(v: np.ndarray) -> np.ndarray:
    """3x3 cross-product matrix ``[v]_x``."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def sampson_px(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
               x2: np.ndarray) -> np.ndarray:
    """Signed Sampson distances (pixels) of pixel correspondences for ``x2 = R x1 + t``."""
    Kinv = camera.K_inv
    F = Kinv.T @ skew(t) @ R @ Kinv
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.sum(h2 * Fx1, axis=1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2) + 1e-15
    return num / den


def tangent_basis(t: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Two orthogonal unit vectors spanning the tangent plane of the unit sphere
    at the unit vector ``t`` (3,)."""
    a = np.eye(3)[int(np.argmin(np.abs(t)))]
    b1 = np.cross(t, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(t, b1)
    return b1, b2


def pose_std_deg(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
                 x2: np.ndarray) -> Tuple[float, float]:
    """First-order standard deviations (degrees) of the rotation and of the
    translation direction of ``x2 = R x1 + t`` from the Sampson residuals of the
    inliers (largest principal axis of each block of ``sigma^2 (J^T J)^-1``,
    with a numerical 5-column Jacobian).  ``(inf, inf)`` when unconstrained."""
    n = len(x1)
    if n < 8:
        return float("inf"), float("inf")
    t = t / np.linalg.norm(t)
    b1, b2 = tangent_basis(t)

    def res(p):
        tt = t + p[3] * b1 + p[4] * b2
        return sampson_px(camera, so3_exp(p[:3]) @ R, tt / np.linalg.norm(tt), x1, x2)

    r0 = res(np.zeros(5))
    h = 1e-6
    J = np.empty((n, 5))
    for k in range(5):
        e = np.zeros(5)
        e[k] = h
        J[:, k] = (res(e) - res(-e)) / (2 * h)
    sigma2 = float(r0 @ r0) / max(n - 5, 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float("inf"), float("inf")
    if not np.all(np.isfinite(cov)):
        return float("inf"), float("inf")
    rot = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov[:3, :3])[-1]), 0.0)))
    tra = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(cov[3:, 3:])[-1]), 0.0)))
    return rot, tra


def refine_sampson(camera: PinholeCamera, R0: np.ndarray, t0: np.ndarray, x1: np.ndarray,
                   x2: np.ndarray, scale_px: float) -> Tuple[np.ndarray, np.ndarray]:
    """LM refinement of (R, unit t) minimising robust Sampson errors (5 DoF)."""
    from scipy.optimize import least_squares

    t0 = t0 / np.linalg.norm(t0)
    b1, b2 = tangent_basis(t0)

    def unpack(p):
        R = so3_exp(p[:3]) @ R0
        t = t0 + p[3] * b1 + p[4] * b2
        return R, t / np.linalg.norm(t)

    def fun(p):
        R, t = unpack(p)
        return sampson_px(camera, R, t, x1, x2)

    sol = least_squares(fun, np.zeros(5), method="trf", loss="soft_l1", f_scale=scale_px,
                        x_scale=1.0, max_nfev=50)
    if not sol.success and sol.status <= 0:
        return R0, t0
    R, t = unpack(sol.x)
    return nearest_rotation(R), t


def positive_depth(cam: PinholeCamera, R: np.ndarray, t: np.ndarray, x1: np.ndarray,
                   x2: np.ndarray) -> np.ndarray:
    """Cheirality: both midpoint-triangulated depths positive."""
    f1 = bearings(cam, x1)
    f2 = bearings(cam, x2)
    # solve d1 R f1 + t = d2 f2 in least squares for (d1, d2)
    a = f1 @ R.T
    b = -f2
    aa, bb, ab = np.sum(a * a, 1), np.sum(b * b, 1), np.sum(a * b, 1)
    at, bt = a @ t, b @ t
    det = aa * bb - ab ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        d1 = (-at * bb + bt * ab) / det
        d2 = (-bt * aa + at * ab) / det
    return np.isfinite(d1) & (d1 > 0) & (d2 > 0)

