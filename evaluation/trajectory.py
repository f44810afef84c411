"""Trajectories in the evaluation protocols: Sim(3)-aligned ATE, the TUM files, the
estimators' result base and the ATE association tolerance.

The ATE (:func:`ate_sim3`, :func:`ate_per_frame_and_keyframes`, :class:`AteResult`,
:func:`path_length`) lives in the core, :mod:`spgeo.metrics.ate` (a VO run's outcome
reports it too), and the TUM reader / writer in :mod:`spgeo.io.tum`; both are
re-exported here.  ``TumTrajectory`` is an alias of :class:`spgeo.trajectory.Trajectory`.
Defined here: :class:`TrajectoryResult` (the base of the reference estimators'
results) and :func:`default_max_time_diff`.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Sequence, Union

import numpy as np

from spgeo.io.tum import read_status, read_tum, status_path_for, write_status, write_tum
from spgeo.metrics.ate import (AteResult, TrajectoryLike, ate_per_frame_and_keyframes, ate_sim3,
                               path_length)
from spgeo.trajectory import FrameStatus, Trajectory

__all__ = [
    "TumTrajectory", "read_tum", "write_tum", "status_path_for", "write_status", "read_status",
    "AteResult", "ate_sim3", "ate_per_frame_and_keyframes", "path_length",
    "default_max_time_diff", "TrajectoryResult", "TrajectoryLike",
]

PathLike = Union[str, Path]
#: Former name of :class:`spgeo.trajectory.Trajectory`.
TumTrajectory = Trajectory


class TrajectoryResult:
    """Base of the estimators' result objects that hold a ``trajectory``
    (:class:`~spgeo.trajectory.Trajectory`): its per-frame arrays as attributes."""

    trajectory: Trajectory

    @property
    def timestamps(self) -> np.ndarray:
        """(n,) frame timestamps (seconds, or frame numbers for data without time)."""
        return self.trajectory.timestamps

    @property
    def poses(self) -> np.ndarray:
        """(n, 4, 4) camera-to-world, NaN for frames without a pose."""
        return self.trajectory.poses

    @property
    def status(self) -> List[FrameStatus]:
        """Per-frame :class:`~spgeo.trajectory.FrameStatus`."""
        return self.trajectory.status

    @property
    def is_keyframe(self) -> np.ndarray:
        return self.trajectory.is_keyframe

    @property
    def n_frames(self) -> int:
        return len(self.trajectory)


# ================================================================== ATE
def default_max_time_diff(timestamps: Sequence[float]) -> float:
    """ATE association tolerance: 0.1 for frame-number timestamps (all
    integral, e.g. 7-Scenes), else 0.02 s (TUM)."""
    stamps = np.asarray(timestamps, dtype=np.float64)
    if stamps.size and np.all(np.isfinite(stamps)) and np.allclose(stamps, np.round(stamps)):
        return 0.1
    return 0.02
