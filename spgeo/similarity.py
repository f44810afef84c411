"""Similarity transforms Sim(3) as 4x4 float64 arrays: construction, parts, inverse,
GTSAM conversion, differences, Umeyama alignment and the move of an anchored frame.

The one similarity toolkit of the project (beside the rigid helpers of
:mod:`spgeo.geometry`): loop closure (:mod:`spgeo.loop`), the VO's loop
corrections (:mod:`spgeo.vo`) and the evaluation use it.

Convention: ``S_a_b`` maps points of frame
``b`` into frame ``a`` as ``x_a = s R x_b + t``; its matrix is
``[[s R, t], [0, 0, 0, 1]]`` and composition is the matrix product
(``S_a_c = S_a_b @ S_b_c``).  A rigid ``T_a_b`` is the case ``s = 1``.  A keyframe's
similarity ``S_world_kf = [[s R, t], [0, 1]]`` is applied to the map as the rigid pose
``T_world_kf = [[R, t], [0, 1]]`` plus the keyframe's depths multiplied by ``s``
(each primitive's log-scale increased by ``log s``): both give the same world points.

GTSAM's ``Similarity3(R, t_g, s)`` maps ``x -> s (R x + t_g)``; so ``t = s t_g``.
:func:`to_gtsam` / :func:`from_gtsam` do the conversion.  GTSAM's tangent order is
``(omega (3), u (3), log s)``.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

__all__ = ["sim3", "sim3_parts", "sim3_inverse", "check_sim3", "to_gtsam", "from_gtsam",
           "sim3_difference", "umeyama", "moved_frame"]


def sim3(R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:
    """4x4 matrix ``[[s R, t], [0, 1]]`` of the similarity ``x -> s R x + t``."""
    S = np.eye(4)
    S[:3, :3] = float(s) * np.asarray(R, dtype=np.float64)
    S[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return S


def sim3_parts(S: np.ndarray) -> Tuple[np.ndarray, np.ndarray, float]:
    """``(R, t, s)`` of a 4x4 similarity ``[[s R, t], [0, 1]]`` (``s > 0``)."""
    S = np.asarray(S, dtype=np.float64)
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    return S[:3, :3] / s, S[:3, 3].copy(), s


def check_sim3(S: np.ndarray, name: str = "S", atol: float = 1e-5) -> np.ndarray:
    """``S`` as a float64 4x4 similarity (positive scale, orthonormal rotation) or ``ValueError``."""
    S = np.asarray(S, dtype=np.float64)
    if S.shape != (4, 4) or not np.all(np.isfinite(S)):
        raise ValueError(f"{name} must be a finite 4x4 matrix, got shape {S.shape}")
    det = np.linalg.det(S[:3, :3])
    if not det > 0 or not np.allclose(S[3], [0, 0, 0, 1], atol=atol):
        raise ValueError(f"{name} is not a similarity (det <= 0 or last row not [0 0 0 1])")
    R = S[:3, :3] / np.cbrt(det)
    if not np.allclose(R @ R.T, np.eye(3), atol=atol):
        raise ValueError(f"{name} is not a similarity (s^-1 * rotation block not orthonormal)")
    return S


def sim3_inverse(S: np.ndarray) -> np.ndarray:
    """Inverse similarity: ``x_b = (1/s) R^T (x_a - t)``."""
    R, t, s = sim3_parts(S)
    return sim3(R.T, -(R.T @ t) / s, 1.0 / s)


def to_gtsam(S: np.ndarray):
    """``gtsam.Similarity3`` of a 4x4 similarity in this module's convention."""
    import gtsam

    R, t, s = sim3_parts(S)
    return gtsam.Similarity3(gtsam.Rot3(R), t / s, s)


def from_gtsam(S_g) -> np.ndarray:
    """4x4 similarity (this module's convention) of a ``gtsam.Similarity3``."""
    s = float(S_g.scale())
    return sim3(S_g.rotation().matrix(), s * np.asarray(S_g.translation(), dtype=np.float64), s)


def sim3_difference(S_a: np.ndarray, S_b: np.ndarray) -> Tuple[float, float, float]:
    """How far ``S_b`` is from ``S_a``: ``(rotation deg, translation, |log scale|)`` of
    ``inv(S_a) @ S_b`` (translation in the units of ``S_a``'s source frame)."""
    R, t, s = sim3_parts(sim3_inverse(S_a) @ S_b)
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle), float(np.linalg.norm(t)), float(abs(np.log(s)))


def moved_frame(W_new_old: np.ndarray, T_world_frame: np.ndarray) -> np.ndarray:
    """Rigid 4x4 camera-to-world pose of a frame anchored to a keyframe whose map
    moved by the world similarity ``W_new_old`` (``S_world_kf(new) @
    inv(T_world_kf(old))``, the keyframe's depth factor as its scale): the frame
    moves with the keyframe's map, its offset from the keyframe multiplied by
    the scale, its rotation turned as the keyframe's."""
    R, t, _ = sim3_parts(np.asarray(W_new_old, dtype=np.float64)
                         @ np.asarray(T_world_frame, dtype=np.float64))
    return sim3(R, t)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Optional[np.ndarray]:
    """Least-squares similarity ``S`` with ``dst ~= s R src + t`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) corresponding points, N >= 3.
        with_scale: fit ``s`` (else ``s = 1``).
    Returns:
        4x4 ``S_dst_src``, or None when the points are degenerate (collinear,
        coincident or non-finite).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if len(src) < 3 or src.shape != dst.shape or not np.all(np.isfinite(src)) \
            or not np.all(np.isfinite(dst)):
        return None
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs ** 2).sum() / len(src))
    if var_s <= 1e-12:
        return None
    U, D, Vt = np.linalg.svd(xd.T @ xs / len(src))
    if D[1] <= 1e-9 * max(D[0], 1e-300):
        return None
    E = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        E[2, 2] = -1.0
    R = U @ E @ Vt
    s = float((D * np.diag(E)).sum() / var_s) if with_scale else 1.0
    if not s > 0:
        return None
    return sim3(R, mu_d - s * R @ mu_s, s)
