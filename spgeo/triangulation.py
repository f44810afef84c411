"""Multi-view linear (DLT) triangulation and its gates: the one triangulator of spgeo.

Every triangulation of matched pixels into points goes through :func:`triangulate`:
the VO's new landmarks (:class:`spgeo.vo.landmarks.LandmarkMap`, two keyframes), the
few-view SfM's tracks (:func:`spgeo.sfm.bundle.triangulate_tracks`, any number of
views) and the two-view initialisation's depths
(:func:`spgeo.sfm.init.triangulate_depths`).

Conventions (docs/design.md §1): ``V`` cameras share one pinhole camera; their poses
are camera-to-world 4x4 rigid transforms ``T_world_cam`` (V, 4, 4); ``pixels`` (N, V, 2)
holds point ``n``'s pixel ``(u, v)`` in view ``v``, NaN where that view does not see
it (a track seen by some of the views).  Points are (N, 3) in the poses' world frame,
in the poses' translation units.

**The DLT** (:func:`dlt_points`).  Each view that sees a point gives the two rows
``u P[2] - P[0]`` and ``v P[2] - P[1]`` of its projection matrix
``P = K [R^T | -R^T t]`` in pixel coordinates (with zero skew a row is ``fx``, resp.
``fy``, times the same row in normalised coordinates, so the algebraic residuals are
weighted as pixels); a view that does not see it gives two zero rows, which leave
``A^T A`` and so the solution unchanged.  All points form one (N, 2V, 4) stack solved
by one batched SVD: a point is the right singular vector of the least singular value,
dehomogenised, NaN where its ``w`` is within 1e-12 of 0 (a point at infinity).

**The gates** (:func:`triangulate`).  A point is kept, else NaN, when

* at least two views see it;
* its DLT solution is finite;
* cheirality: its depth is positive in every view that sees it;
* reprojection: it projects within ``max_reprojection_px`` of its pixel in every
  view that sees it (default: no bound);
* parallax: the largest angle between two of its rays, from the centres of the views
  that see it, is at least ``min_angle_deg`` (:func:`max_ray_angle_deg`; default 0:
  no bound).
"""
from __future__ import annotations

from itertools import combinations
from typing import Sequence, Union

import numpy as np

from .camera import PinholeCamera
from .geometry import invert_pose, ray_angles_deg, transform_points

__all__ = ["triangulate", "dlt_points", "max_ray_angle_deg"]

#: a homogeneous solution with ``|w|`` at most this (unit vector) is a point at infinity
_W_EPS = 1e-12

Poses = Union[np.ndarray, Sequence[np.ndarray]]


def _inputs(T_world_cams: Poses, pixels: np.ndarray):
    """``(T (V, 4, 4), x (N, V, 2))`` as float64, or ``ValueError``."""
    T = np.asarray(T_world_cams, dtype=np.float64)
    x = np.asarray(pixels, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"T_world_cams must be (V, 4, 4), got {T.shape}")
    if x.ndim != 3 or x.shape[1:] != (len(T), 2):
        raise ValueError(f"pixels must be (N, {len(T)}, 2) for {len(T)} poses, got {x.shape}")
    return T, x


def dlt_points(K: np.ndarray, T_world_cams: Poses, pixels: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation, without gates (module docstring).

    Args:
        K: 3x3 intrinsics shared by the views.
        T_world_cams: (V, 4, 4) camera-to-world poses.
        pixels: (N, V, 2) pixels, NaN where a view does not see the point.
    Returns:
        (N, 3) world points; NaN at infinity.  A point seen by fewer than two views
        gets an arbitrary point of its ray (:func:`triangulate` refuses it).
    """
    T, x = _inputs(T_world_cams, pixels)
    n, v = x.shape[:2]
    if n == 0:
        return np.zeros((0, 3))
    P = np.stack([np.asarray(K, dtype=np.float64) @ invert_pose(Tv)[:3] for Tv in T])
    A = np.empty((n, v, 2, 4))
    A[:, :, 0] = x[..., 0:1] * P[:, 2] - P[:, 0]
    A[:, :, 1] = x[..., 1:2] * P[:, 2] - P[:, 1]
    seen = np.isfinite(x[..., 0])
    A = np.where(seen[:, :, None, None], A, 0.0).reshape(n, 2 * v, 4)
    h = np.linalg.svd(A)[2][:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = h[:, :3] / h[:, 3:4]
    return np.where(np.abs(h[:, 3:4]) > _W_EPS, X, np.nan)


def max_ray_angle_deg(points: np.ndarray, centres: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(N,) the largest angle (degrees) at each point (N, 3) between its rays from two
    camera centres (V, 3) that both see it (``seen`` (N, V) bool), all in one frame:
    the parallax of a multi-view point (:func:`spgeo.geometry.ray_angles_deg` for
    each pair of views); NaN where no two views see it."""
    best = np.full(len(points), np.nan)
    for a, b in combinations(range(len(centres)), 2):
        both = seen[:, a] & seen[:, b]
        best = np.fmax(best, np.where(both, ray_angles_deg(points, centres[a], centres[b]),
                                      np.nan))
    return best


def triangulate(camera: PinholeCamera, T_world_cams: Poses, pixels: np.ndarray,
                max_reprojection_px: float = np.inf, min_angle_deg: float = 0.0) -> np.ndarray:
    """Points of pixels matched across views, by DLT, where they pass the gates
    (module docstring).

    Args:
        camera: the views' shared pinhole camera (``pixels`` are at its resolution).
        T_world_cams: (V, 4, 4) camera-to-world poses, V >= 2 (two views: a pair).
        pixels: (N, V, 2) pixels, NaN where a view does not see the point.
        max_reprojection_px: reprojection bound (pixels) in every view that sees a point.
        min_angle_deg: least parallax (degrees): the largest angle between two rays.
    Returns:
        (N, 3) world points (the poses' frame and units), NaN rows where refused.
    """
    T, x = _inputs(T_world_cams, pixels)
    X = dlt_points(camera.K, T, x)
    seen = np.isfinite(x[..., 0])
    ok = (np.sum(seen, axis=1) >= 2) & np.all(np.isfinite(X), axis=1)
    Xs = np.where(ok[:, None], X, 0.0)
    for v, Tv in enumerate(T):
        uv, z = camera.project(transform_points(invert_pose(Tv), Xs))
        err = np.linalg.norm(uv - x[:, v], axis=1)
        ok &= ~seen[:, v] | ((z > 0) & (err <= max_reprojection_px))
    if min_angle_deg > 0:
        ok &= max_ray_angle_deg(Xs, T[:, :3, 3], seen) >= min_angle_deg
    return np.where(ok[:, None], X, np.nan)
