"""Sim(3)-aligned absolute trajectory error (ATE) of an estimated trajectory against ground truth.

ATE (:func:`ate_sim3`) uses evo's library API: nearest-timestamp association
(:func:`evo.core.sync.associate_trajectories`), Umeyama Sim(3) alignment of
the estimate onto the ground truth (``correct_scale=True``; the equivalent of
``evo_ape -as``) and :class:`evo.core.metrics.APE` on the translation part.

*Per-frame* ATE evaluates every frame that has a pose; *keyframe-only* ATE
evaluates (and aligns on) the keyframes only.  They are different numbers:
every table must say which one it reports.  :func:`ate_sim3` on any subset of
the estimated poses gives the subset's ATE; :func:`ate_per_frame_and_keyframes`
returns both.  A VO run's outcome (:mod:`spgeo.apps.vo_outcome`) and the
evaluation protocols (:mod:`spgeo.evaluation.trajectory`) report it.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple, Union

import numpy as np

from ..trajectory import Trajectory

__all__ = ["TrajectoryLike", "AteResult", "ate_sim3", "ate_per_frame_and_keyframes",
           "path_length"]

logger = logging.getLogger(__name__)

#: ``(timestamps (n,), poses (n, 4, 4))`` or a :class:`~spgeo.trajectory.Trajectory`.
TrajectoryLike = Union[Tuple[Sequence[float], Sequence[np.ndarray]], Trajectory]


def _as_trajectory(traj: TrajectoryLike, name: str) -> Trajectory:
    """``traj`` as a :class:`~spgeo.trajectory.Trajectory`: itself, an object's
    ``timestamps``, ``poses`` and (when it has them) ``statuses``, or a
    ``(timestamps, poses)`` pair; ``TypeError`` (naming ``name``) for anything else."""
    if isinstance(traj, Trajectory):
        return traj
    if hasattr(traj, "timestamps") and hasattr(traj, "poses"):   # e.g. a VO result
        return Trajectory(traj.timestamps, traj.poses, getattr(traj, "statuses", None))
    try:
        stamps, poses = traj
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected (timestamps, poses) or a Trajectory, "
                        f"got {type(traj).__name__}") from None
    return Trajectory(stamps, np.stack([np.asarray(p, dtype=np.float64) for p in poses])
                      if len(poses) else np.zeros((0, 4, 4)))


def path_length(positions: np.ndarray) -> float:
    """Sum of the distances between consecutive positions (n, 3)."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


@dataclass
class AteResult:
    """Absolute trajectory error after Sim(3) (or SE(3)) alignment.

    Attributes:
        rmse, mean, median, max, std: statistics of the per-pose translation
            errors (metres, in the ground truth's unit) after alignment.
        scale: Sim(3) scale that maps the estimate onto the ground truth (1 when
            ``correct_scale`` was False).
        rotation, translation: the alignment ``x_gt ≈ scale * R x_est + t``.
        n_associated: poses matched by timestamp (and evaluated).
        n_estimated, n_groundtruth: poses used (finite poses with finite timestamps).
        n_estimated_dropped: estimated poses left out as non-finite (frames
            without a pose, e.g. lost).
        n_groundtruth_dropped: ground-truth poses left out as non-finite (a
            warning is logged when there are any).
        trajectory_length: ground-truth path length over the associated poses (m).
        label: what was evaluated, e.g. ``"per-frame"`` or ``"keyframe-only"``.
        timestamps: (n_associated,) estimate timestamps of the evaluated poses.
        errors: (n_associated,) translation errors (m).
        aligned_positions, gt_positions: (n_associated, 3) after alignment.
    """

    rmse: float
    mean: float
    median: float
    max: float
    std: float
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    n_associated: int
    n_estimated: int
    n_groundtruth: int
    trajectory_length: float
    label: str = "per-frame"
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    aligned_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gt_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    n_estimated_dropped: int = 0
    n_groundtruth_dropped: int = 0

    @property
    def rmse_percent_of_length(self) -> float:
        """RMSE as % of the ground-truth path length (NaN for a zero-length path)."""
        if self.trajectory_length <= 0:
            return float("nan")
        return 100.0 * self.rmse / self.trajectory_length

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no per-pose arrays)."""
        return {
            "label": self.label, "rmse_m": self.rmse, "mean_m": self.mean,
            "median_m": self.median, "max_m": self.max, "std_m": self.std,
            "scale": self.scale, "n_associated": self.n_associated,
            "n_estimated": self.n_estimated, "n_groundtruth": self.n_groundtruth,
            "n_estimated_dropped": self.n_estimated_dropped,
            "n_groundtruth_dropped": self.n_groundtruth_dropped,
            "trajectory_length_m": self.trajectory_length,
            "rmse_percent_of_length": self.rmse_percent_of_length,
        }

    def __str__(self) -> str:
        return (f"ATE ({self.label}, Sim(3)-aligned): RMSE {self.rmse:.4f} m "
                f"({self.rmse_percent_of_length:.2f}% of {self.trajectory_length:.2f} m), "
                f"median {self.median:.4f} m, max {self.max:.4f} m, scale {self.scale:.4g}, "
                f"{self.n_associated} poses")


def _to_evo(traj: Trajectory):
    from evo.core.trajectory import PoseTrajectory3D

    order = np.argsort(traj.timestamps, kind="stable")
    return PoseTrajectory3D(poses_se3=[p for p in traj.poses[order]],
                            timestamps=traj.timestamps[order].copy())


def _finite_part(traj: Trajectory) -> Tuple[Trajectory, int]:
    """The poses of ``traj`` that are finite with a finite timestamp, and how
    many were left out."""
    keep = np.all(np.isfinite(traj.poses.reshape(len(traj), -1)), axis=1) & np.isfinite(
        traj.timestamps)
    return traj.subset(keep), int(len(traj) - keep.sum())


def ate_sim3(est: TrajectoryLike, gt: TrajectoryLike, max_time_diff: float = 0.02,
             correct_scale: bool = True, label: str = "per-frame",
             min_poses: int = 3, warn_dropped: bool = True,
             tracked_only: bool = True) -> AteResult:
    """Sim(3)-aligned ATE of ``est`` against ``gt`` with evo (``evo_ape -as``).

    Args:
        est, gt: ``(timestamps, poses)`` (camera-to-world 4x4) or
            :class:`~spgeo.trajectory.Trajectory` (or any object with ``timestamps`` and ``poses``).
            Estimated poses that are ``NaN`` (frames without a pose) are dropped;
            so are ground-truth poses that are non-finite, with a logged warning
            naming how many (``warn_dropped``); both counts are in the result
            (``n_estimated_dropped``, ``n_groundtruth_dropped``).
        max_time_diff: largest timestamp difference for a nearest-time match
            (default 0.02 s; use < 0.5 for frame-number timestamps).
        correct_scale: Sim(3) (default) or SE(3) alignment.
        label: recorded in the result (``"per-frame"`` / ``"keyframe-only"``).
        min_poses: fewest associated poses to evaluate (default 3).
        warn_dropped: log the warning about dropped ground-truth poses (default
            True; False when the caller already did for the same ground truth).
        tracked_only: an estimated :class:`~spgeo.trajectory.Trajectory` counts
            its :attr:`~spgeo.trajectory.Trajectory.tracked` frames only (default
            True: a ``LOST`` frame holds the last good pose, not its own; False:
            every finite pose).  ``(timestamps, poses)`` are all counted.

    To evaluate a subset (e.g. keyframes), pass only those poses: the alignment
    is then fitted on the subset too.  Raises ``ValueError`` when fewer than
    ``min_poses`` poses associate or the alignment is degenerate (e.g. all
    estimated positions identical).
    """
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException

    e = _as_trajectory(est, "est")
    if tracked_only:        # by status: a non-finite pose is counted as dropped below
        e = e.subset(np.array([s.has_pose for s in e.status], dtype=bool))
    e, n_e_drop = _finite_part(e)
    g, n_g_drop = _finite_part(_as_trajectory(gt, "gt"))
    if n_g_drop and warn_dropped:
        logger.warning("ATE (%s): %d of %d ground-truth poses are not finite (NaN / inf pose or "
                       "timestamp) and were left out", label, n_g_drop, n_g_drop + len(g))
    if len(e) < min_poses or len(g) < min_poses:
        raise ValueError(f"ate_sim3: need at least {min_poses} finite poses "
                         f"(estimate has {len(e)}, ground truth {len(g)})")
    try:
        ref_sync, est_sync = sync.associate_trajectories(_to_evo(g), _to_evo(e),
                                                         max_diff=float(max_time_diff))
    except sync.SyncException as exc:
        raise ValueError(f"ate_sim3: no timestamps associate within {max_time_diff}: "
                         f"{exc}") from None
    n = est_sync.num_poses
    if n < min_poses:
        raise ValueError(f"ate_sim3: only {n} poses associate within {max_time_diff} "
                         f"(need {min_poses})")
    try:
        R, t, s = est_sync.align(ref_sync, correct_scale=correct_scale)
    except GeometryException as exc:
        raise ValueError(f"ate_sim3: degenerate alignment: {exc}") from None
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"ate_sim3: degenerate alignment (scale {s})")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_sync, est_sync))
    stats = ape.get_all_statistics()
    return AteResult(
        rmse=float(stats["rmse"]), mean=float(stats["mean"]), median=float(stats["median"]),
        max=float(stats["max"]), std=float(stats["std"]), scale=float(s),
        rotation=np.asarray(R, float), translation=np.asarray(t, float).reshape(3),
        n_associated=int(n), n_estimated=len(e), n_groundtruth=len(g),
        trajectory_length=path_length(ref_sync.positions_xyz), label=label,
        timestamps=np.asarray(est_sync.timestamps, float).copy(),
        errors=np.asarray(ape.error, float).copy(),
        aligned_positions=np.asarray(est_sync.positions_xyz, float).copy(),
        gt_positions=np.asarray(ref_sync.positions_xyz, float).copy(),
        n_estimated_dropped=n_e_drop, n_groundtruth_dropped=n_g_drop)


def ate_per_frame_and_keyframes(est: TrajectoryLike, gt: TrajectoryLike,
                                keyframe_mask: Optional[Sequence[bool]] = None,
                                max_time_diff: float = 0.02,
                                correct_scale: bool = True) -> Dict[str, Optional[AteResult]]:
    """Both ATE variants: ``{"per-frame": ..., "keyframe-only": ...}``.

    The keyframe-only entry is None when no mask is given or when fewer than 3
    keyframes associate (logged).
    """
    e = _as_trajectory(est, "est")
    out: Dict[str, Optional[AteResult]] = {
        "per-frame": ate_sim3(e, gt, max_time_diff, correct_scale, label="per-frame"),
        "keyframe-only": None,
    }
    if keyframe_mask is not None:
        mask = np.asarray(keyframe_mask, dtype=bool)
        if mask.shape != (len(e),):
            raise ValueError(f"keyframe_mask has shape {mask.shape}, expected ({len(e)},)")
        try:
            out["keyframe-only"] = ate_sim3(e.subset(mask), gt, max_time_diff, correct_scale,
                                            label="keyframe-only", warn_dropped=False)
        except ValueError as exc:
            logger.warning("keyframe-only ATE not available: %s", exc)
    return out
