"""Tracking one frame with its retries (docs/design.md §5.1): the motion model's
pose guesses, the feature-based retry, relocalisation against the window's older
keyframes, and the keyframe decision of a tracked frame.

:class:`FrameTracker` owns the :class:`~spgeo.vo.motion.MotionModel` and the
:class:`~spgeo.vo.feature_retry.FeatureRetry`; :class:`spgeo.vo.Odometry` asks it
for a :class:`~spgeo.vo.tracking.TrackResult` and decides what follows.
"""
from __future__ import annotations

import dataclasses
from typing import List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose, rotation_angle_deg
from .config import OdometryConfig
from .feature_retry import FeaturePose, FeatureRetry
from .initialisation import RetrackedFrame
from .map import MapKeyframe
from .motion import MotionModel
from .tracking import Keyframe, TrackResult, track_frame

__all__ = ["FrameTracker"]


class FrameTracker:
    """A frame tracked against a keyframe from several initial poses.

    Args:
        camera: the processing camera (of the feature-based retry).
        config: :class:`OdometryConfig` (``tracker``, ``feature_retry``, ``keyframe``).

    Attributes:
        motion: the :class:`MotionModel` whose guesses start tracking and which a
            caller updates (accept, reset, move).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig) -> None:
        self.config = config
        self.motion = MotionModel()
        self._retry = FeatureRetry(camera, config.feature_retry)

    def track(self, kf: Keyframe, image: np.ndarray, retry: Optional[MapKeyframe] = None,
              timestamp: Optional[float] = None) -> TrackResult:
        """``image`` (taken at ``timestamp``; None: one period after the last
        good frame) tracked against ``kf`` from the motion model's guesses
        (constant velocity over the time gap, then the last good pose), then (``retry``: ``kf``'s
        map keyframe, with ``feature_retry.enabled``) the feature-based PnP pose;
        the first ``ok`` result, else the one of lowest photometric cost.  A
        result refused only for its cost (``"high_cost"``) is ``ok`` when the
        PnP pose's matches agree with it (:meth:`FeaturePose.agrees`)."""
        guesses = self.motion.guesses(timestamp)
        pnp: Optional[FeaturePose] = None
        if retry is not None and self.config.feature_retry.enabled:
            def feature_guess() -> Optional[np.ndarray]:
                nonlocal pnp
                pnp = self._retry.pose(retry.index, retry.image, kf.primitives, kf.T_world_kf,
                                       image)
                return None if pnp is None else pnp.T_world_frame
            guesses.append(feature_guess)
        tr = None
        for guess in guesses:
            T0 = guess()
            if T0 is None:
                continue
            tr2 = track_frame(kf, image, T0, self.motion.brightness, self.config.tracker)
            if tr is None or tr2.ok or tr2.photometric_cost < tr.photometric_cost:
                tr = tr2
            if tr.ok:
                break
        if (tr is not None and tr.reason == "high_cost" and pnp is not None
                and pnp.agrees(tr.T_world_frame, self._retry.camera, self.config.feature_retry)):
            tr = dataclasses.replace(tr, status="ok", reason=None, feature_checked=True)
        return tr

    def retrack(self, kf: MapKeyframe, frames: Sequence[Tuple[int, np.ndarray, float]]
                ) -> List[RetrackedFrame]:
        """``(frame number, image, timestamp)`` frames, in order, tracked against
        ``kf`` as :meth:`track` does (the motion model's guesses, the feature
        retry; each one tracked becomes the last good); one not tracked gets the
        last good pose."""
        out: List[RetrackedFrame] = []
        T_kf_world = invert_pose(kf.keyframe.T_world_kf)
        for i, image, stamp in frames:
            tr = self.track(kf.keyframe, image, kf, stamp)
            if tr.ok:
                self.motion.accept(tr, float(stamp))
                out.append(RetrackedFrame(i, image, True, tr.T_world_frame.copy(),
                                          T_kf_world @ tr.T_world_frame,
                                          np.asarray(tr.brightness, float)))
            else:
                out.append(RetrackedFrame(i, image, False, self.motion.last_good.copy()))
        return out

    def relocalise(self, older: Sequence[MapKeyframe], image: np.ndarray
                   ) -> Tuple[Optional[TrackResult], Optional[MapKeyframe]]:
        """``image`` tracked from the last good pose against the live keyframes
        ``older`` in the order given (the caller passes newest first); the first
        ``ok`` result and its keyframe, else ``(None, None)``."""
        for kf in older:
            tr = track_frame(kf.keyframe, image, self.motion.last_good, self.motion.brightness,
                             self.config.tracker)
            if tr.ok:
                return tr, kf
        return None, None

    def wants_keyframe(self, tr: TrackResult, T_kf_f: np.ndarray, latest: MapKeyframe) -> bool:
        """The keyframe decision (``OdometryConfig.keyframe``) of a frame tracked
        against the live keyframe ``latest`` at ``T_kf_f`` (``T_latest_frame``,
        translation in ``latest``'s depth units)."""
        dec = self.config.keyframe
        rel_t = float(np.linalg.norm(T_kf_f[:3, 3])) / max(latest.keyframe.median_depth, 1e-9)
        rot = rotation_angle_deg(T_kf_f[:3, :3])
        return (tr.valid_fraction < dec.min_valid_fraction
                or rel_t > dec.max_translation
                or tr.relative_cost > dec.max_relative_cost
                or rot > dec.max_rotation_deg)
