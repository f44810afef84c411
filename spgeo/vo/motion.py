"""The VO's motion model (docs/design.md §5.1): the last two good camera poses,
their timestamps and the brightness of the last tracked frame, from which the
next frame's initial pose guesses come.

Skip-aware: the constant-velocity step is the last motion scaled by the ratio of
time gaps, ``(t_next - t_last) / (t_last - t_prev)``, so a frame two or three
camera periods after the last one (frames dropped by a live camera, or lost) is
predicted two or three steps ahead, and a velocity measured across a gap is
applied per period.  A ratio within :data:`SAME_STEP` of 1 (timestamp jitter) is
one step exactly."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, List, Optional

import gtsam
import numpy as np

from ..geometry import invert_pose, nearest_rigid, nearest_rotation
from ..similarity import moved_frame
from .tracking import TrackResult, constant_velocity_guess

__all__ = ["MotionModel", "MotionChange", "SAME_STEP", "MAX_STEPS"]

#: a ratio of time gaps within this of 1 is one constant-velocity step (jitter)
SAME_STEP = 0.25
#: the most constant-velocity steps one prediction extrapolates
MAX_STEPS = 4.0


@dataclass
class MotionChange:
    """How an applied mapping update moves the motion model
    (:meth:`MotionModel.follow`; :meth:`spgeo.vo.mapping_port.MappingPort.apply_pending`).

    Attributes:
        similarities: 4x4 world similarities ``S_world_kf(new) @ inv(T_world_kf(old))``
            of the newest keyframe, applied in order (the map moved under the frames
            tracked since).
        keyframe_pose: or the new keyframe's smoothed ``T_world_kf``, when no frame
            was tracked since (:meth:`MotionModel.to_keyframe`).
    """

    similarities: List[np.ndarray] = field(default_factory=list)
    keyframe_pose: Optional[np.ndarray] = None


class MotionModel:
    """Pose prediction of the next frame.

    Attributes:
        last_good: rigid 4x4 camera-to-world pose of the last well-tracked
            frame (or keyframe), None before the first keyframe.
        prev_good: the one before it (None after a reset: no velocity yet).
        last_time, prev_time: their timestamps (seconds, or frame numbers for
            data without time; None where unknown: steps of one period).
        brightness: ``(a, b)`` affine brightness of the last tracked frame
            relative to its keyframe (zeros at a new keyframe).
    """

    def __init__(self) -> None:
        self.last_good: Optional[np.ndarray] = None
        self.prev_good: Optional[np.ndarray] = None
        self.last_time: Optional[float] = None
        self.prev_time: Optional[float] = None
        self.brightness = np.zeros(2)

    def reset(self, T_world: np.ndarray, timestamp: Optional[float] = None) -> None:
        """Restart at a map segment's keyframe 0 at ``T_world`` (taken at
        ``timestamp``): no velocity, no brightness change."""
        self.last_good, self.prev_good = np.array(T_world, dtype=float), None
        self.last_time, self.prev_time = timestamp, None
        self.brightness = np.zeros(2)

    def set_poses(self, T_last: np.ndarray, T_prev: np.ndarray,
                  t_last: Optional[float] = None, t_prev: Optional[float] = None) -> None:
        """The last two good poses (copies; e.g. an initialisation's keyframe 1
        and the last frame tracked before it) and their timestamps."""
        self.last_good, self.prev_good = T_last.copy(), T_prev.copy()
        self.last_time, self.prev_time = t_last, t_prev

    def accept(self, tr: TrackResult, timestamp: Optional[float] = None) -> None:
        """A frame tracked ``ok`` at ``timestamp``: its pose and brightness become
        the last good."""
        self.prev_good, self.last_good = self.last_good, tr.T_world_frame.copy()
        self.prev_time, self.last_time = self.last_time, timestamp
        self.brightness = np.asarray(tr.brightness, dtype=float).copy()

    def replace_last(self, tr: TrackResult) -> None:
        """The last accepted frame tracked again (``tr`` ok): its pose and
        brightness replace the last good ones (the previous pose and the times
        stay)."""
        self.last_good = tr.T_world_frame.copy()
        self.brightness = np.asarray(tr.brightness, dtype=float).copy()

    def steps(self, timestamp: Optional[float]) -> float:
        """Constant-velocity steps from the last good frame to a frame at
        ``timestamp``: the ratio of time gaps (module docstring), 1 within
        :data:`SAME_STEP` or where a time is unknown, at most :data:`MAX_STEPS`."""
        if timestamp is None or self.last_time is None or self.prev_time is None:
            return 1.0
        base = self.last_time - self.prev_time
        if not base > 0:
            return 1.0
        ratio = (float(timestamp) - self.last_time) / base
        if abs(ratio - 1.0) <= SAME_STEP or not np.isfinite(ratio):
            return 1.0
        return float(np.clip(ratio, 0.0, MAX_STEPS))

    def predict(self, timestamp: Optional[float] = None) -> Optional[np.ndarray]:
        """The constant-velocity pose of a frame at ``timestamp``
        (:meth:`steps` steps of the last motion; the last good pose without a
        velocity; None before the first keyframe)."""
        if self.last_good is None:
            return None
        k = self.steps(timestamp)
        if self.prev_good is None or k == 1.0:
            return constant_velocity_guess(self.last_good, self.prev_good)
        step = invert_pose(self.prev_good) @ self.last_good
        xi = gtsam.Pose3.Logmap(gtsam.Pose3(nearest_rigid(step)))
        T = self.last_good @ gtsam.Pose3.Expmap(k * xi).matrix()
        T[:3, :3] = nearest_rotation(T[:3, :3])
        return T

    def guesses(self, timestamp: Optional[float] = None
                ) -> List[Callable[[], Optional[np.ndarray]]]:
        """The initial pose guesses of a frame at ``timestamp`` in the order to
        try, each computed when called: the constant-velocity prediction
        (:meth:`predict`), then (with a velocity) the last good pose."""
        guesses = [lambda: self.predict(timestamp)]
        if self.prev_good is not None:
            guesses.append(lambda: self.last_good)
        return guesses

    def move(self, frame_pose: Callable[[np.ndarray], np.ndarray]) -> None:
        """Both poses moved by ``frame_pose`` (old pose -> new pose; e.g. a
        similarity correction of the map they are anchored to); times stay."""
        self.last_good = frame_pose(self.last_good)
        if self.prev_good is not None:
            self.prev_good = frame_pose(self.prev_good)

    def follow(self, change: MotionChange) -> None:
        """Follow the map an update moved (:class:`MotionChange`): both poses moved
        by each similarity in turn (made exactly rigid again,
        :func:`~spgeo.geometry.nearest_rigid`: tracking starts from them), then
        :meth:`to_keyframe` of its keyframe pose."""
        for W in change.similarities:
            self.move(lambda T, W=W: nearest_rigid(moved_frame(W, T)))
        if change.keyframe_pose is not None:
            self.to_keyframe(change.keyframe_pose)

    def to_keyframe(self, T_new: np.ndarray) -> None:
        """The new keyframe's smoothed pose ``T_new`` replaces the last good
        (tracked) one; the same world-frame correction moves the previous pose,
        and the brightness restarts at zero (the keyframe is the reference)."""
        if self.prev_good is not None:
            self.prev_good = T_new @ invert_pose(self.last_good) @ self.prev_good
        self.last_good = T_new.copy()
        self.brightness = np.zeros(2)

