"""Rigid-body helpers.  Poses in data types are 4x4 float64 numpy arrays.

Naming: ``T_a_b`` maps points from frame ``b`` into frame ``a``
(``x_a = T_a_b @ x_b``).  ``T_world_cam`` is camera-to-world; the relative pose
of a target camera in a reference camera is ``T_ref_tgt = inv(T_world_ref) @ T_world_tgt``.
Quaternions are Hamilton ``(qx, qy, qz, qw)`` as in the TUM file format.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = [
    "check_pose", "check_poses", "invert_pose", "nearest_rotation", "relative_pose",
    "transform_points", "quat_to_rot",
    "rot_to_quat", "pose_from_tum", "pose_to_tum", "rotation_angle_deg", "to_pose3",
    "from_pose3", "so3_exp",
]


def check_pose(T: np.ndarray, name: str = "pose", atol: float = 1e-5) -> np.ndarray:
    """Return ``T`` as a float64 4x4 rigid transform or raise ``ValueError``."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name} contains NaN or inf")
    R = T[:3, :3]
    if (not np.allclose(R @ R.T, np.eye(3), atol=atol) or abs(np.linalg.det(R) - 1) > atol
            or not np.allclose(T[3], [0, 0, 0, 1], atol=atol)):
        raise ValueError(f"{name} is not a rigid transform (rotation not orthonormal or "
                         "last row not [0 0 0 1])")
    return T


def check_poses(T: np.ndarray, name: str = "T_world_cam") -> np.ndarray:
    """Return ``T`` as a float64 (n, 4, 4) stack of rigid transforms, n >= 1, or
    raise ``ValueError`` naming ``name`` (and the index of a bad one)."""
    T = np.asarray(T, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
        raise ValueError(f"{name} must be (n, 4, 4) with n >= 1, got {T.shape}")
    for i, Ti in enumerate(T):
        check_pose(Ti, f"{name}[{i}]")
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    T = np.asarray(T, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation (orthonormal, determinant +1) nearest the 3x3 matrix ``M`` in the
    Frobenius norm: with the SVD ``M = U S Vt``, ``U @ Vt``, or ``U diag(1, 1, -1) Vt``
    when ``U @ Vt`` is a reflection.

    The one projection onto SO(3) of spgeo (``tests/test_layering.py`` checks that no
    other module of ``spgeo/`` or ``factors/`` writes its own): re-orthonormalising a
    rotation that carries rounding, fitting one to a correlation matrix (Kabsch, an
    essential matrix's rotation, the mean of rotations).  Keep its floating-point
    operations as they are: the outputs of the VO, SfM and completion are compared
    byte for byte across refactors, and a form equal on paper, such as
    ``U @ diag(1, 1, det(U @ Vt)) @ Vt``, differs in the last bits."""
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return R


def nearest_rigid(T: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform nearest ``T`` (its rotation block projected on
    SO(3), :func:`nearest_rotation`, its translation kept): for a pose composed of
    poses whose rotations carry rounding (GTSAM's estimates are orthonormal only up
    to it)."""
    T = np.array(T, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = nearest_rotation(T[:3, :3]), T[:3, 3]
    return out


def relative_pose(T_world_a: np.ndarray, T_world_b: np.ndarray) -> np.ndarray:
    """``T_a_b = inv(T_world_a) @ T_world_b`` (pose of b in a)."""
    return invert_pose(T_world_a) @ np.asarray(T_world_b, dtype=np.float64)


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map points (..., 3) from frame b to frame a."""
    points_b = np.asarray(points_b, dtype=np.float64)
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def ray_angles_deg(points: np.ndarray, centre_a: np.ndarray, centre_b: np.ndarray) -> np.ndarray:
    """Angle (degrees) at each point (N, 3) between the rays from the two camera
    centres ``centre_a``, ``centre_b`` (3,), all in one frame: the triangulation
    (parallax) angle of a point seen from two views; NaN where a ray has no length."""
    a = np.asarray(points, dtype=np.float64) - centre_a
    b = np.asarray(points, dtype=np.float64) - centre_b
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def quat_to_rot(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a (qx, qy, qz, qw) quaternion (normalised first)."""
    x, y, z, w = np.asarray(q, dtype=np.float64)
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"invalid quaternion {tuple(q)}")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) of a rotation matrix, with qw >= 0."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def pose_from_tum(values: Sequence[float]) -> np.ndarray:
    """4x4 pose from TUM ``tx ty tz qx qy qz qw``."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (7,) or not np.all(np.isfinite(values)):
        raise ValueError(f"TUM pose needs 7 finite numbers, got {values!r}")
    T = np.eye(4)
    T[:3, :3] = quat_to_rot(values[3:])
    T[:3, 3] = values[:3]
    return T


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """TUM ``tx ty tz qx qy qz qw`` of a 4x4 pose."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[:3, 3], rot_to_quat(T[:3, :3])])


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of an axis-angle vector (radians)."""
    omega = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(omega)
    W = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]])
    if theta < 1e-12:
        return np.eye(3) + W
    return (np.eye(3) + np.sin(theta) / theta * W
            + (1 - np.cos(theta)) / theta ** 2 * W @ W)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Rotation angle of a 3x3 rotation (or of the rotation block of a 4x4), in degrees."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def to_pose3(T: np.ndarray):
    """gtsam.Pose3 of a 4x4 matrix."""
    import gtsam

    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


def from_pose3(pose) -> np.ndarray:
    """4x4 matrix of a gtsam.Pose3."""
    return np.asarray(pose.matrix(), dtype=np.float64)
