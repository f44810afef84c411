"""Outputs of the feature VO baseline (:mod:`.feature_vo`): one frame
(:class:`FeatureVOFrame`) and one run (:class:`FeatureVOResult`, a
:class:`~spgeo.trajectory.Trajectory` plus timings)."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from spgeo.trajectory import FrameStatus, Trajectory

from spgeo.evaluation.trajectory import (AteResult, TrajectoryResult, ate_per_frame_and_keyframes,
                                         status_path_for)

from .feature_vo_frontend import FeatureVOConfig

__all__ = ["STATUSES", "FeatureVOFrame", "FeatureVOResult"]

#: Every per-frame status the feature VO reports (:class:`FrameStatus` values).
STATUSES = tuple(s.value for s in (FrameStatus.INIT, FrameStatus.OK, FrameStatus.LOST,
                                   FrameStatus.REINIT))


@dataclass
class FeatureVOFrame:
    """Outcome of :meth:`FeatureVO.track` for one frame.

    Attributes:
        index: frame number (0-based, in call order).
        timestamp: the frame's timestamp.
        T_world_cam: 4x4 camera-to-world pose, NaN without a pose (a frame
            waiting for the initialisation gets its pose later, in
            :meth:`FeatureVO.result`).
        status: :class:`~spgeo.trajectory.FrameStatus` (:data:`STATUSES`).
        is_keyframe: whether the frame became a keyframe.
        segment: map id (0, +1 per re-initialisation; -1 without a pose).
        inliers: PnP inliers (or initial-map points).
        time_s: processing seconds.
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: FrameStatus
    is_keyframe: bool
    segment: int
    inliers: int
    time_s: float


@dataclass
class FeatureVOResult(TrajectoryResult):
    """Output of :func:`run_feature_vo`: the :class:`~spgeo.trajectory.Trajectory`
    (extra column ``inliers``) plus timings.

    Attributes:
        trajectory: poses camera-to-world, NaN for frames without a pose; the
            first posed frame is the identity; the scale is arbitrary (median
            depth of the initial map = 1).
        frame_time_s: (n,) processing seconds per frame.
        timings: total seconds per stage (``features``, ``matching``, ``pnp``,
            ``initialisation``, ``triangulation``, ``total``).
        names: frame names.
        config: the configuration used.
    """

    trajectory: Trajectory
    frame_time_s: np.ndarray
    timings: Dict[str, float]
    names: List[str]
    config: FeatureVOConfig

    @property
    def segment(self) -> np.ndarray:
        """(n,) map id, -1 for frames without a pose."""
        return self.trajectory.segment

    @property
    def n_inliers(self) -> np.ndarray:
        """(n,) PnP inliers (or initial-map points) per frame."""
        return np.asarray(self.trajectory.columns["inliers"], dtype=int)

    @property
    def valid(self) -> np.ndarray:
        """(n,) bool: frames with a pose."""
        return self.trajectory.finite

    @property
    def n_segments(self) -> int:
        return int(self.segment.max()) + 1 if np.any(self.segment >= 0) else 0

    @property
    def fps(self) -> float:
        total = self.timings.get("total", 0.0)
        return len(self.timestamps) / total if total > 0 else float("nan")

    def status_counts(self) -> Dict[str, int]:
        """Frames per status of :data:`STATUSES`."""
        counts = self.trajectory.status_counts()
        return {s: counts[s] for s in STATUSES}

    def table(self) -> str:
        """One line: frames, posed, keyframes, segments, statuses, speed."""
        return (f"feature VO: {len(self.timestamps)} frames, {int(self.valid.sum())} posed, "
                f"{int(self.is_keyframe.sum())} keyframes, {self.n_segments} segment(s), "
                f"statuses {self.status_counts()}, {self.fps:.1f} FPS")

    def save_tum(self, path: Union[str, Path], keyframes_only: bool = False) -> Path:
        """Write the posed frames (or keyframes) as a TUM file and every frame's
        status into ``<stem>.status.txt`` beside it.  Returns ``path``."""
        header = [f"spgeo feature VO baseline ({self.config.detector.upper()} + essential "
                  f"matrix + PnP); {'keyframes' if keyframes_only else 'every posed frame'}; "
                  "monocular: scale arbitrary",
                  f"frames {len(self.timestamps)}, posed {int(self.valid.sum())}, "
                  f"segments {self.n_segments}; statuses in {status_path_for(path).name}"]
        return self.trajectory.save(path, keyframes_only=keyframes_only, header=header)

    def ate(self, gt_timestamps: Sequence[float], gt_poses: Sequence[np.ndarray],
            max_time_diff: float = 0.02) -> Dict[str, Optional[AteResult]]:
        """Sim(3) ATE, per-frame and keyframe-only (see :mod:`spgeo.evaluation.trajectory`)."""
        return ate_per_frame_and_keyframes((self.timestamps, self.poses),
                                           (gt_timestamps, gt_poses), self.is_keyframe,
                                           max_time_diff=max_time_diff)

    def summary(self) -> Dict[str, object]:
        return {"n_frames": len(self.timestamps), "n_posed": int(self.valid.sum()),
                "n_keyframes": int(self.is_keyframe.sum()), "n_segments": self.n_segments,
                "status_counts": self.status_counts(), "fps": self.fps,
                "timings_s": dict(self.timings), "config": asdict(self.config)}
