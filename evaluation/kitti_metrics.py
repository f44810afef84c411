"""KITTI odometry's own metrics (issue 38): relative translation and rotation errors over
path segments, as the KITTI devkit (``evaluate_odometry.cpp``, Geiger et al., CVPR 2012)
defines them.

For every first frame ``i`` (every ``step``-th frame) and segment length ``L``: the last
frame ``j`` is the first whose ground-truth path distance from ``i`` exceeds ``L``
(strictly); with ``E = inv(inv(T_est_i) T_est_j) @ inv(T_gt_i) T_gt_j`` the segment's
translation error is ``|t(E)| / L`` and its rotation error ``angle(E) / L``.
``t_rel`` is their mean in percent, ``r_rel`` in degrees per 100 m (the leaderboard's
units), averaged over all segments of all lengths.  The devkit's lengths are 100..800 m;
a path shorter than 100 m uses eight lengths spread over it (10 .. 80 % of the path,
stated with the result), so a short clip still gets the same kind of number.

A monocular estimate has no metric scale: pass the scale of its Sim(3) alignment
(:class:`~spgeo.evaluation.trajectory.AteResult`'s ``scale``); relative poses do not
depend on the alignment's rotation and translation.  Poses are camera-to-world 4x4; a
segment whose first or last estimated pose is not finite (a lost frame) is left out.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from spgeo.geometry import invert_pose

__all__ = ["KITTI_LENGTHS", "KITTI_STEP", "KittiRelativeError", "segment_lengths",
           "kitti_relative_errors"]

#: the devkit's segment lengths (metres)
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: the devkit's spacing of first frames
KITTI_STEP = 10


@dataclass
class KittiRelativeError:
    """Relative errors over path segments (module docstring).

    Attributes:
        t_rel_pct: mean translation error, % of the segment length.
        r_rel_deg_per_100m: mean rotation error, degrees per 100 m (per 100 ground-truth
            units for data in other units).
        lengths: the segment lengths used (ground-truth units).
        n_segments: segments evaluated.
        per_length: length -> ``(t_rel_pct, r_rel_deg_per_100m, n_segments)``.
    """

    t_rel_pct: float
    r_rel_deg_per_100m: float
    lengths: Tuple[float, ...]
    n_segments: int
    per_length: Dict[float, Tuple[float, float, int]] = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready (``per_length`` keys as strings)."""
        return {"t_rel_pct": self.t_rel_pct, "r_rel_deg_per_100m": self.r_rel_deg_per_100m,
                "lengths": list(self.lengths), "n_segments": self.n_segments,
                "per_length": {f"{k:g}": list(v) for k, v in self.per_length.items()}}


def segment_lengths(path_length: float) -> Tuple[float, ...]:
    """The devkit's lengths shorter than ``path_length``; for a path shorter than the
    first of them, ``0.1 .. 0.8 x path_length`` (eight lengths, rounded to 0.1)."""
    fit = tuple(L for L in KITTI_LENGTHS if L < path_length)
    if fit:
        return fit
    return tuple(round(f * path_length, 1) for f in np.arange(1, 9) / 10.0)


def _rotation_angle(R: np.ndarray) -> float:
    """The devkit's rotation error: ``acos`` of ``(trace - 1) / 2`` clipped to [-1, 1]."""
    return float(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)))


def kitti_relative_errors(est_poses: np.ndarray, gt_poses: np.ndarray, scale: float = 1.0,
                          lengths: Optional[Sequence[float]] = None,
                          step: int = KITTI_STEP) -> KittiRelativeError:
    """t_rel and r_rel of ``est_poses`` against ``gt_poses`` (module docstring).

    Args:
        est_poses, gt_poses: (N, 4, 4) camera-to-world poses of the same N frames in
            order (estimated NaN where lost).
        scale: multiplies the estimate's translations first (a monocular run's Sim(3)
            scale onto the ground truth; 1 for metric estimates).
        lengths: segment lengths in ground-truth units (default
            :func:`segment_lengths` of the ground-truth path).
        step: first frames every ``step`` frames (the devkit's 10).

    Raises ``ValueError`` for mismatched shapes, a non-positive scale or step, or when no
    segment fits (NaN results would hide it).
    """
    est = np.asarray(est_poses, dtype=np.float64).copy()
    gt = np.asarray(gt_poses, dtype=np.float64)
    if est.shape != gt.shape or est.ndim != 3 or est.shape[1:] != (4, 4):
        raise ValueError(f"kitti_relative_errors: poses must be two (N, 4, 4) arrays of one "
                         f"shape, got {est.shape} and {gt.shape}")
    if not (scale > 0 and step >= 1):
        raise ValueError(f"kitti_relative_errors: scale must be > 0 and step >= 1, got "
                         f"{scale}, {step}")
    est[:, :3, 3] *= scale
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0),
                                                           axis=1))])
    lengths = tuple(segment_lengths(dist[-1]) if lengths is None else lengths)
    ok = np.all(np.isfinite(est.reshape(len(est), -1)), axis=1)
    errs: Dict[float, list] = {L: [] for L in lengths}
    for i in range(0, len(gt), step):
        for L in lengths:
            j = int(np.searchsorted(dist, dist[i] + L, side="right"))   # first beyond L
            if j == len(gt) or not ok[i] or not ok[j]:
                continue
            E = invert_pose(invert_pose(est[i]) @ est[j]) @ (invert_pose(gt[i]) @ gt[j])
            errs[L].append((np.linalg.norm(E[:3, 3]) / L, _rotation_angle(E[:3, :3]) / L))
    return _summarised(errs, lengths)


def _summarised(errs: Dict[float, list], lengths: Tuple[float, ...]) -> KittiRelativeError:
    """Means over all segments (and per length) in the leaderboard's units."""
    all_errs = np.array([e for L in lengths for e in errs[L]]).reshape(-1, 2)
    if not len(all_errs):
        raise ValueError(f"kitti_relative_errors: no segment of lengths {lengths} fits the "
                         "path with finite poses at both ends")
    units = np.array([100.0, np.degrees(1.0) * 100.0])
    per = {L: (*(np.mean(errs[L], axis=0) * units).tolist(), len(errs[L]))
           for L in lengths if errs[L]}
    t, r = np.mean(all_errs, axis=0) * units
    return KittiRelativeError(float(t), float(r), lengths, len(all_errs), per)
