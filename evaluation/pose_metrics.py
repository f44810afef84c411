"""Relative-pose error metrics (rotation angle, translation direction).

Conventions (docs/design.md §1, :mod:`spgeo.geometry`): poses are 4x4 float
matrices; ``T_ref_view`` is the pose of a view in the reference camera
(camera-to-reference, ``inv(T_world_ref) @ T_world_view``).  Monocular
estimates have an unknown scale, so translations are compared by *direction*
only: the angle between the two translation vectors.

* :func:`rotation_error_deg`: geodesic angle of ``R_est^T R_gt`` in degrees.
* :func:`translation_direction_error_deg`: angle between two translation
  vectors in degrees; NaN (and a logged warning) when either is (near) zero,
  because a direction is then undefined.
* :func:`relative_pose_errors`: both errors of one estimated relative pose
  against ground truth, as a dict with an explicit ``translation_defined`` flag.
* :func:`compare_pose_lists`: the same over lists of poses (``None`` entries for
  views a method did not register), with a summary.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

__all__ = [
    "DEFAULT_MIN_TRANSLATION_NORM", "rotation_error_deg", "translation_direction_error_deg",
    "translation_direction_defined", "relative_pose_errors", "PoseListComparison",
    "compare_pose_lists",
]

logger = logging.getLogger(__name__)

#: Translations shorter than this (in the poses' unit) have no defined direction.
DEFAULT_MIN_TRANSLATION_NORM = 1e-9


def _rotation(R: np.ndarray, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape not in ((3, 3), (4, 4), (3, 4)):
        raise ValueError(f"{name} must be a 3x3 rotation or a 3x4/4x4 pose, got shape {R.shape}")
    R = R[:3, :3]
    if not np.all(np.isfinite(R)):
        raise ValueError(f"{name} contains NaN or inf")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or abs(np.linalg.det(R) - 1.0) > 1e-4:
        raise ValueError(f"{name} is not a rotation matrix (not orthonormal or det != 1)")
    return R


def _translation(t: np.ndarray, name: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    if t.shape in ((4, 4), (3, 4)):
        t = t[:3, 3]
    t = t.reshape(-1)
    if t.shape != (3,):
        raise ValueError(f"{name} must be a 3-vector or a 3x4/4x4 pose, got shape {np.shape(t)}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} contains NaN or inf")
    return t


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """Geodesic angle (degrees, in [0, 180]) between two rotations.

    Accepts 3x3 rotations or 3x4/4x4 poses (the rotation block is used).
    Computed as the angle of ``R_est^T R_gt`` from the quaternion-stable
    ``atan2(|axis|, trace)`` form, accurate also for tiny angles.
    Raises ``ValueError`` for non-rotations or non-finite input.
    """
    Ra = _rotation(R_est, "R_est")
    Rb = _rotation(R_gt, "R_gt")
    D = Ra.T @ Rb
    s = 0.5 * np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
    c = 0.5 * (np.trace(D) - 1.0)
    return float(np.degrees(math.atan2(s, c)))


def translation_direction_defined(t: np.ndarray,
                                  min_norm: float = DEFAULT_MIN_TRANSLATION_NORM) -> bool:
    """Whether a translation (3-vector or pose) is long enough to have a direction."""
    return bool(np.linalg.norm(_translation(t, "t")) > float(min_norm))


def translation_direction_error_deg(t_est: np.ndarray, t_gt: np.ndarray,
                                    min_norm: float = DEFAULT_MIN_TRANSLATION_NORM) -> float:
    """Angle (degrees, in [0, 180]) between the directions of two translations.

    Accepts 3-vectors or 3x4/4x4 poses (the translation column is used).
    The scale of either vector does not matter.  When either vector is shorter
    than ``min_norm`` its direction is undefined: the result is NaN and a
    warning is logged (use :func:`translation_direction_defined` or the flag of
    :func:`relative_pose_errors` to tell this case apart).  The sign matters:
    opposite directions give 180 degrees.
    """
    a = _translation(t_est, "t_est")
    b = _translation(t_gt, "t_gt")
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na <= min_norm or nb <= min_norm:
        logger.warning("translation direction undefined (|t_est| = %.3g, |t_gt| = %.3g, "
                       "min_norm = %.3g): returning NaN", na, nb, min_norm)
        return float("nan")
    a, b = a / na, b / nb
    return float(np.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))))


def relative_pose_errors(T_ref_view_est: np.ndarray, T_ref_view_gt: np.ndarray,
                         min_norm: float = DEFAULT_MIN_TRANSLATION_NORM) -> Dict[str, object]:
    """Errors of one estimated relative pose against ground truth.

    Both poses are ``T_ref_view`` (4x4, or 3x4) in the same convention; the
    estimate's translation scale is ignored.  Returns a dict:

    * ``rotation_error_deg``: :func:`rotation_error_deg` of the two.
    * ``translation_direction_error_deg``: :func:`translation_direction_error_deg`
      (NaN when undefined).
    * ``translation_defined``: False when either translation is (near) zero.
    * ``gt_rotation_deg``, ``gt_translation_norm``: size of the true motion.
    * ``est_rotation_deg``, ``est_translation_norm``: size of the estimate.
    """
    Re, Rg = _rotation(T_ref_view_est, "T_ref_view_est"), _rotation(T_ref_view_gt, "T_ref_view_gt")
    te = _translation(T_ref_view_est, "T_ref_view_est")
    tg = _translation(T_ref_view_gt, "T_ref_view_gt")
    defined = (np.linalg.norm(te) > min_norm) and (np.linalg.norm(tg) > min_norm)
    return {
        "rotation_error_deg": rotation_error_deg(Re, Rg),
        "translation_direction_error_deg": (translation_direction_error_deg(te, tg, min_norm)
                                            if defined else float("nan")),
        "translation_defined": bool(defined),
        "gt_rotation_deg": rotation_error_deg(np.eye(3), Rg),
        "gt_translation_norm": float(np.linalg.norm(tg)),
        "est_rotation_deg": rotation_error_deg(np.eye(3), Re),
        "est_translation_norm": float(np.linalg.norm(te)),
    }


def _nan_stat(values: np.ndarray, fn) -> float:
    values = values[np.isfinite(values)]
    return float(fn(values)) if values.size else float("nan")


@dataclass
class PoseListComparison:
    """Result of :func:`compare_pose_lists`.

    Attributes:
        rows: one dict per view: ``index``, ``name``, ``available`` (both poses
            given) and, when available, the fields of :func:`relative_pose_errors`
            (NaN otherwise).
        rotation_errors_deg, translation_direction_errors_deg: (n,) arrays, NaN
            where unavailable / undefined.
        n_missing: views for which the estimate (or ground truth) is ``None``.
    """

    rows: List[Dict[str, object]] = field(default_factory=list)
    rotation_errors_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    translation_direction_errors_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_missing: int = 0

    @property
    def max_rotation_error_deg(self) -> float:
        """Largest finite rotation error (NaN when none)."""
        return _nan_stat(self.rotation_errors_deg, np.max)

    @property
    def median_rotation_error_deg(self) -> float:
        return _nan_stat(self.rotation_errors_deg, np.median)

    @property
    def max_translation_direction_error_deg(self) -> float:
        return _nan_stat(self.translation_direction_errors_deg, np.max)

    @property
    def median_translation_direction_error_deg(self) -> float:
        return _nan_stat(self.translation_direction_errors_deg, np.median)

    def summary(self) -> Dict[str, float]:
        """JSON-friendly summary (max / median of both errors, missing count)."""
        return {
            "n_views": len(self.rows),
            "n_missing": int(self.n_missing),
            "max_rotation_error_deg": self.max_rotation_error_deg,
            "median_rotation_error_deg": self.median_rotation_error_deg,
            "max_translation_direction_error_deg": self.max_translation_direction_error_deg,
            "median_translation_direction_error_deg":
                self.median_translation_direction_error_deg,
        }

    def to_dict(self) -> Dict[str, object]:
        return {"rows": [dict(r) for r in self.rows], "summary": self.summary()}


def compare_pose_lists(T_est: Sequence[Optional[np.ndarray]],
                       T_gt: Sequence[Optional[np.ndarray]],
                       names: Optional[Sequence[str]] = None,
                       min_norm: float = DEFAULT_MIN_TRANSLATION_NORM) -> PoseListComparison:
    """Compare two equally long lists of relative poses view by view.

    ``None`` entries (a view the method failed to register, or without ground
    truth) give NaN errors and count in ``n_missing``.  Raises ``ValueError`` if
    the lists differ in length.
    """
    T_est, T_gt = list(T_est), list(T_gt)
    if len(T_est) != len(T_gt):
        raise ValueError(f"compare_pose_lists: {len(T_est)} estimates for {len(T_gt)} "
                         "reference poses")
    if names is not None and len(names) != len(T_est):
        raise ValueError(f"compare_pose_lists: {len(names)} names for {len(T_est)} poses")
    rows: List[Dict[str, object]] = []
    rot, tdir = np.full(len(T_est), np.nan), np.full(len(T_est), np.nan)
    missing = 0
    for i, (a, b) in enumerate(zip(T_est, T_gt)):
        row: Dict[str, object] = {"index": i, "name": None if names is None else str(names[i])}
        if a is None or b is None:
            missing += 1
            row.update(available=False, rotation_error_deg=float("nan"),
                       translation_direction_error_deg=float("nan"), translation_defined=False)
        else:
            row["available"] = True
            row.update(relative_pose_errors(a, b, min_norm))
            rot[i] = row["rotation_error_deg"]
            tdir[i] = row["translation_direction_error_deg"]
        rows.append(row)
    return PoseListComparison(rows=rows, rotation_errors_deg=rot,
                              translation_direction_errors_deg=tdir, n_missing=missing)
