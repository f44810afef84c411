"""The VO's motion model (docs/design.md §5.1): the last two good camera poses
and the brightness of the last tracked frame, from which the next frame's
initial pose guesses come."""
from __future__ import annotations

from typing import Callable, List, Optional

import numpy as np

from ..geometry import invert_pose
from .tracking import TrackResult, constant_velocity_guess

__all__ = ["MotionModel"]


class MotionModel:
    """Pose prediction of the next frame.

    Attributes:
        last_good: rigid 4x4 camera-to-world pose of the last well-tracked
            frame (or keyframe), None before the first keyframe.
        prev_good: the one before it (None after a reset: no velocity yet).
        brightness: ``(a, b)`` affine brightness of the last tracked frame
            relative to its keyframe (zeros at a new keyframe).
    """

    def __init__(self) -> None:
        self.last_good: Optional[np.ndarray] = None
        self.prev_good: Optional[np.ndarray] = None
        self.brightness = np.zeros(2)

    def reset(self, T_world: np.ndarray) -> None:
        """Restart at a map segment's keyframe 0 at ``T_world``: no velocity, no
        brightness change."""
        self.last_good, self.prev_good = np.array(T_world, dtype=float), None
        self.brightness = np.zeros(2)

    def set_poses(self, T_last: np.ndarray, T_prev: np.ndarray) -> None:
        """The last two good poses (copies; e.g. an initialisation's keyframe 1
        and the frame before it)."""
        self.last_good, self.prev_good = T_last.copy(), T_prev.copy()

    def accept(self, tr: TrackResult) -> None:
        """A frame tracked ``ok``: its pose and brightness become the last good."""
        self.prev_good, self.last_good = self.last_good, tr.T_world_frame.copy()
        self.brightness = np.asarray(tr.brightness, dtype=float).copy()

    def replace_last(self, tr: TrackResult) -> None:
        """The last accepted frame tracked again (``tr`` ok): its pose and
        brightness replace the last good ones (the previous pose stays)."""
        self.last_good = tr.T_world_frame.copy()
        self.brightness = np.asarray(tr.brightness, dtype=float).copy()

    def guesses(self) -> List[Callable[[], Optional[np.ndarray]]]:
        """The initial pose guesses in the order to try, each computed when
        called: the constant-velocity prediction, then (with a velocity) the last
        good pose."""
        guesses = [lambda: constant_velocity_guess(self.last_good, self.prev_good)]
        if self.prev_good is not None:
            guesses.append(lambda: self.last_good)
        return guesses

    def move(self, frame_pose: Callable[[np.ndarray], np.ndarray]) -> None:
        """Both poses moved by ``frame_pose`` (old pose -> new pose; e.g. a
        similarity correction of the map they are anchored to)."""
        self.last_good = frame_pose(self.last_good)
        if self.prev_good is not None:
            self.prev_good = frame_pose(self.prev_good)

    def to_keyframe(self, T_new: np.ndarray) -> None:
        """The new keyframe's smoothed pose ``T_new`` replaces the last good
        (tracked) one; the same world-frame correction moves the previous pose,
        and the brightness restarts at zero (the keyframe is the reference)."""
        if self.prev_good is not None:
            self.prev_good = T_new @ invert_pose(self.last_good) @ self.prev_good
        self.last_good = T_new.copy()
        self.brightness = np.zeros(2)
