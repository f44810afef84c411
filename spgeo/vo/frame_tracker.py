"""The one tracking decision of the VO (docs/design.md §5.1): every path that
tracks a frame against a keyframe goes through :meth:`FrameTracker.track` — the
frame of an initialised map, the frames of a segment waiting for keyframe 1,
relocalisation against the window's older keyframes, the re-decision after a late
update, the initialiser's re-tracking of its buffer and the frames of a solve that
ran beside the tracker (:meth:`FrameTracker.retrack`, the one re-tracking loop).

One decision: the photometric tracker (:func:`~spgeo.vo.tracking.track_frame`) from
each initial pose guess in the order given, then (with a keyframe whose features
may lift to depth, ``OdometryConfig.feature_retry.enabled``) the feature-based PnP
pose; the first ``ok`` result, else the one of lowest photometric cost; a result
refused only for its cost (``"high_cost"``) is ``ok`` when the PnP pose's matches
agree with it (:meth:`~spgeo.vo.feature_retry.FeaturePose.agrees`).

:class:`FrameTracker` holds no pose state: the caller's
:class:`~spgeo.vo.motion.MotionModel` gives the guesses and the brightness start.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose
from .config import OdometryConfig
from .feature_retry import FeaturePose, FeatureRetry
from .map import MapKeyframe
from .motion import MotionModel
from .tracking import TrackResult, track_frame

__all__ = ["FrameTracker", "RetrackedFrame", "Guess"]

#: an initial pose guess, computed when called: a 4x4 ``T_world_frame`` or None (no guess)
Guess = Callable[[], Optional[np.ndarray]]


@dataclass
class RetrackedFrame:
    """A frame tracked again by :meth:`FrameTracker.retrack`.

    Attributes:
        frame: frame number.
        image: its image.
        ok: whether it tracked.
        T_world_frame: its re-tracked pose, or (not ``ok``) the last good pose
            before it.
        T_kf_frame: its pose in the keyframe it was tracked against (``ok`` only).
        brightness: its tracked ``(a, b)`` (``ok`` only).
    """

    frame: int
    image: np.ndarray
    ok: bool
    T_world_frame: np.ndarray
    T_kf_frame: Optional[np.ndarray] = None
    brightness: Optional[np.ndarray] = None


class FrameTracker:
    """The one tracking decision (module docstring).

    Args:
        camera: the processing camera (of the feature-based retry).
        config: :class:`OdometryConfig` (``tracker``, ``feature_retry``).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig) -> None:
        self.config = config
        self._retry = FeatureRetry(camera, config.feature_retry)

    def track(self, kf: MapKeyframe, image: np.ndarray, guesses: Sequence[Guess],
              brightness: np.ndarray, features: bool = True) -> TrackResult:
        """``image`` tracked against the map keyframe ``kf``: the decision of the
        module docstring over ``guesses`` (in order; e.g.
        :meth:`MotionModel.guesses`) from the affine brightness ``brightness``
        ``(a, b)``.  ``features``: whether ``kf``'s primitives carry depth its
        features may be lifted with (the feature retry and check; False for a
        segment's keyframe 0 before its initialisation).  None only when no
        guess gives a pose."""
        pnp: Optional[FeaturePose] = None
        tries = list(guesses)
        if features and self.config.feature_retry.enabled:
            def feature_guess() -> Optional[np.ndarray]:
                nonlocal pnp
                k = kf.keyframe
                pnp = self._retry.pose(kf.index, kf.image, k.primitives, k.T_world_kf, image)
                return None if pnp is None else pnp.T_world_frame
            tries.append(feature_guess)
        tr = None
        for guess in tries:
            T0 = guess()
            if T0 is None:
                continue
            tr2 = track_frame(kf.keyframe, image, T0, brightness, self.config.tracker)
            if tr is None or tr2.ok or tr2.photometric_cost < tr.photometric_cost:
                tr = tr2
            if tr.ok:
                break
        if (tr is not None and tr.reason == "high_cost" and pnp is not None
                and pnp.agrees(tr.T_world_frame, self._retry.camera, self.config.feature_retry)):
            tr = dataclasses.replace(tr, status="ok", reason=None, feature_checked=True)
        return tr

    def retrack(self, kf: MapKeyframe, frames: Sequence[Tuple[int, np.ndarray, Optional[float]]],
                motion: MotionModel, extra_guess: Optional[Callable[[int], np.ndarray]] = None
                ) -> List[RetrackedFrame]:
        """The one re-tracking loop: ``(frame number, image, timestamp)`` frames,
        in order, each tracked against ``kf`` (:meth:`track`) from ``motion``'s
        guesses (:meth:`MotionModel.guesses`) and then ``extra_guess(frame
        number)`` when given, from ``motion``'s brightness; a frame tracked
        ``ok`` is accepted by ``motion`` (the next frame's velocity and
        brightness), one not tracked gets the last good pose."""
        out: List[RetrackedFrame] = []
        T_kf_world = invert_pose(kf.keyframe.T_world_kf)
        for i, image, stamp in frames:
            guesses = motion.guesses(stamp)
            if extra_guess is not None:
                guesses.append(lambda i=i: extra_guess(i))
            tr = self.track(kf, image, guesses, motion.brightness)
            if tr.ok:
                motion.accept(tr, None if stamp is None else float(stamp))
                out.append(RetrackedFrame(i, image, True, tr.T_world_frame.copy(),
                                          T_kf_world @ tr.T_world_frame,
                                          np.asarray(tr.brightness, float)))
            else:
                out.append(RetrackedFrame(i, image, False, motion.last_good.copy()))
        return out

    def relocalise(self, older: Sequence[MapKeyframe], image: np.ndarray, motion: MotionModel
                   ) -> Tuple[Optional[TrackResult], Optional[MapKeyframe]]:
        """``image`` tracked (:meth:`track`) from ``motion``'s last good pose
        against the live keyframes ``older`` in the order given (the caller
        passes newest first); the first ``ok`` result and its keyframe, else
        ``(None, None)``."""
        for kf in older:
            tr = self.track(kf, image, [lambda: motion.last_good], motion.brightness)
            if tr.ok:
                return tr, kf
        return None, None
