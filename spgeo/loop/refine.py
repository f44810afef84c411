"""Refinement of a verified loop similarity on its inliers (docs/design.md §5.2).

The model of :func:`spgeo.loop.verify_sim3` is a PnP pose of the candidate's 3-D
points in the query image with the scale from the query's rough depths. The
refinement minimises the reprojection error of the inliers in both images (robust
Huber loss, pixels) plus a weak log-depth agreement term that fixes the scale;
bearings dominate, so the rotation comes from the keypoints rather than the depths.
:func:`sim3_information` is the Gauss-Newton information of the same cost at the
refined similarity: the loop edge's weight in the pose graph.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..camera import PinholeCamera
from ..similarity import sim3, sim3_inverse, sim3_parts

__all__ = ["refine_sim3", "sim3_information", "HUBER_PX", "DEPTH_PX"]

#: Huber threshold of the refinement's residuals (pixels), and the weight of a log-depth
#: disagreement (pixels per unit log ratio: 5 % costs 0.5 px); :func:`sim3_information`
#: weighs the same cost
HUBER_PX = 1.0
DEPTH_PX = 10.0


def _project(points: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    z = np.maximum(points[:, 2], 1e-9)
    return np.stack([camera.fx * points[:, 0] / z + camera.cx,
                     camera.fy * points[:, 1] / z + camera.cy], 1)


def _compose(x: np.ndarray, R0: np.ndarray, t0: np.ndarray, s0: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return sim3(Rotation.from_rotvec(x[:3]).as_matrix() @ R0, t0 + x[3:6], s0 * np.exp(x[6]))


def _residuals(x, R0, t0, s0, P_q, P_c, uv_q, uv_c, cam_q, cam_c, depth_px):
    return _residuals_of(_compose(x, R0, t0, s0), P_q, P_c, uv_q, uv_c, cam_q, cam_c, depth_px)


def _residuals_of(S, P_q, P_c, uv_q, uv_c, cam_q, cam_c, depth_px):
    """Pixel residuals of ``S`` (4x4): candidate image (2M), query image (2M), log-depth (M)."""
    Si = sim3_inverse(S)
    in_c = P_q @ S[:3, :3].T + S[:3, 3]
    in_q = P_c @ Si[:3, :3].T + Si[:3, 3]
    r_c = (_project(in_c, cam_c) - uv_c).ravel()
    r_q = (_project(in_q, cam_q) - uv_q).ravel()
    r_d = depth_px * np.log(np.maximum(in_c[:, 2], 1e-9) / P_c[:, 2])
    return np.concatenate([r_c, r_q, r_d])


def refine_sim3(S_cand_query: np.ndarray, P_query: np.ndarray, P_cand: np.ndarray,
                uv_query: np.ndarray, uv_cand: np.ndarray, cam_query: PinholeCamera,
                cam_cand: PinholeCamera, huber_px: float = HUBER_PX,
                depth_px: float = DEPTH_PX) -> Optional[np.ndarray]:
    """``S_cand_query`` refined on matched inliers (arguments as :func:`count_inliers`).

    Args:
        S_cand_query: 4x4 initial similarity (query camera -> candidate camera).
        P_query, P_cand: (M, 3) inlier points in each camera (their depth units).
        uv_query, uv_cand: (M, 2) their keypoints.
        huber_px: Huber threshold of the residuals, pixels.
        depth_px: weight of a log-depth disagreement in pixels per unit log ratio
            (10: 5 % depth disagreement costs 0.5 px).
    Returns:
        The refined 4x4 similarity, or None when the optimisation fails.
    """
    from scipy.optimize import least_squares

    if len(P_query) < 4:
        return None
    R0, t0, s0 = sim3_parts(S_cand_query)
    args = (R0, t0, s0, P_query, P_cand, uv_query, uv_cand, cam_query, cam_cand, depth_px)
    try:
        sol = least_squares(_residuals, np.zeros(7), args=args, loss="huber",
                            f_scale=huber_px, x_scale="jac", max_nfev=100)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(sol.x)):
        return None
    return _compose(sol.x, R0, t0, s0)


def sim3_information(S_cand_query: np.ndarray, P_query: np.ndarray, P_cand: np.ndarray,
                     uv_query: np.ndarray, uv_cand: np.ndarray, cam_query: PinholeCamera,
                     cam_cand: PinholeCamera, pixel_sigma: float = 1.0,
                     huber_px: float = HUBER_PX, depth_px: float = DEPTH_PX) -> np.ndarray:
    """Information (7x7) of a refined similarity from its reprojection residuals.

    The Gauss-Newton information ``J^T W J / pixel_sigma^2`` of :func:`refine_sim3`'s
    cost at ``S_cand_query`` (arguments as there), with ``J`` the residuals' Jacobian
    with respect to a right perturbation ``S @ Exp(xi)`` in GTSAM's Similarity3
    tangent order (rotation rad x3, translation x3, log-scale), i.e. the frame in which
    ``gtsam.BetweenFactorSimilarity3`` measures its error, and ``W`` the Huber weights
    of the residuals (central differences, step 1e-6).

    Returns:
        (7, 7) symmetric positive semi-definite information matrix.
    """
    import gtsam

    from ..similarity import from_gtsam, to_gtsam

    S0 = to_gtsam(np.asarray(S_cand_query, dtype=np.float64))
    args = (P_query, P_cand, uv_query, uv_cand, cam_query, cam_cand, depth_px)
    r0 = _residuals_of(from_gtsam(S0), *args)
    J = np.empty((len(r0), 7))
    h = 1e-6
    for i in range(7):
        d = np.zeros(7)
        d[i] = h
        plus = _residuals_of(from_gtsam(S0.compose(gtsam.Similarity3.Expmap(d))), *args)
        minus = _residuals_of(from_gtsam(S0.compose(gtsam.Similarity3.Expmap(-d))), *args)
        J[:, i] = (plus - minus) / (2 * h)
    a = np.abs(r0)
    w = np.where(a <= huber_px, 1.0, huber_px / np.maximum(a, 1e-12))
    info = (J * w[:, None]).T @ J / float(pixel_sigma) ** 2
    return 0.5 * (info + info.T)
