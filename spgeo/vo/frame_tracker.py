"""The one tracking decision of the VO (docs/design.md §5.1): every path that
tracks a frame against a keyframe goes through :meth:`FrameTracker.track` — the
frame of an initialised map, the frames of a segment waiting for keyframe 1,
relocalisation against the window's older keyframes, the re-decision after a late
update, the initialiser's re-tracking of its buffer and the frames of a solve that
ran beside the tracker (:meth:`FrameTracker.retrack`, the one re-tracking loop).

One decision: the photometric tracker (:func:`~spgeo.vo.tracking.track_frame`) from
each initial pose guess in the order given, then (``OdometryConfig.feature_retry.enabled``)
from the feature-based PnP poses: the frame's features matched with the map's
landmarks (:class:`~spgeo.vo.landmark_snapshot.LandmarkSnapshot`, issue 51), then
with the keyframe's features lifted by its primitive depth (with a keyframe whose
features may lift to depth); the first ``ok`` result, else the one of lowest
photometric cost; a result refused only for its cost (``"high_cost"``) is ``ok``
at its pose when the matches of a PnP pose agree with it
(:meth:`~spgeo.vo.feature_retry.FeaturePose.agrees`), else ``ok`` at the PnP pose
of most inliers (``TrackResult.feature_pose``; on a street the right pose's
photometric cost can exceed the tracker's bound for frames on end while the
landmarks place it: docs/results.md, issue 51).  The frame's features are
computed once per frame, the landmark pose once per frame and snapshot.

:class:`FrameTracker` holds no pose state: the caller's
:class:`~spgeo.vo.motion.MotionModel` gives the guesses and the brightness start.
"""
from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose
from .config import OdometryConfig
from .feature_retry import FeaturePose, FeatureRetry
from .landmark_snapshot import LandmarkSnapshot
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
        # the window's keyframes and the one leaving it: a retired keyframe's features and
        # primitives are not kept for the whole run
        self._retry = FeatureRetry(camera, config.feature_retry, capacity=config.window + 1)
        # the last frame: (its key, its features, the snapshot it was placed on, that pose)
        self._frame: Optional[tuple] = None

    def track(self, kf: MapKeyframe, image: np.ndarray, guesses: Sequence[Guess],
              brightness: np.ndarray, features: bool = True,
              landmarks: Optional[LandmarkSnapshot] = None) -> TrackResult:
        """``image`` tracked against the map keyframe ``kf``: the decision of the
        module docstring over ``guesses`` (in order; e.g.
        :meth:`MotionModel.guesses`) from the affine brightness ``brightness``
        ``(a, b)``.  ``features``: whether ``kf``'s primitives carry depth its
        features may be lifted with (the feature retry and check; False for a
        segment's keyframe 0 before its initialisation).  ``landmarks``: the
        map's :class:`~spgeo.vo.landmark_snapshot.LandmarkSnapshot` (its PnP pose
        is the first feature guess; None: none).  None only when no guess gives
        a pose."""
        on = self.config.feature_retry.enabled
        pnps: List[FeaturePose] = []
        tries = list(guesses)
        if on and landmarks is not None and len(landmarks):
            def landmark_guess() -> Optional[np.ndarray]:
                p = self._landmark_pose(image, landmarks)
                pnps.extend([p] if p is not None else [])
                return None if p is None else p.T_world_frame
            tries.append(landmark_guess)
        if features and on:
            def feature_guess() -> Optional[np.ndarray]:
                k = kf.keyframe
                p = self._retry.pose(kf.index, kf.image, k.primitives, k.T_world_kf, image,
                                     self.frame_features(image))
                pnps.extend([p] if p is not None else [])
                return None if p is None else p.T_world_frame
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
        return self._checked(tr, pnps)

    def _checked(self, tr: Optional[TrackResult], pnps: List[FeaturePose]
                 ) -> Optional[TrackResult]:
        """A result refused only for its photometric cost, judged by the PnP
        poses ``pnps``: ``ok`` at its pose when one of them agrees with it, else
        ``ok`` at the PnP pose of most inliers (``feature_pose``)."""
        if tr is None or not pnps:
            return tr
        best = max(pnps, key=lambda p: p.inliers)
        tr = dataclasses.replace(tr, pnp_inliers=best.inliers)
        if tr.reason != "high_cost":
            return tr
        cfg = self.config.feature_retry
        if any(p.agrees(tr.T_world_frame, self._retry.camera, cfg) for p in pnps):
            return dataclasses.replace(tr, status="ok", reason=None, feature_checked=True)
        return dataclasses.replace(tr, T_world_frame=best.T_world_frame.copy(), status="ok",
                                   reason=None, feature_checked=True, feature_pose=True)

    def frame_features(self, image: np.ndarray) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        """The frame's features ``(pixels (M, 2), descriptors)``
        (:meth:`FeatureRetry.frame_features`), computed once per frame: the last
        frame's are kept, keyed by its shape and the CRC-32 of its bytes (a caller
        may reuse one array for the next frame)."""
        key = (image.shape, str(image.dtype), zlib.crc32(np.ascontiguousarray(image)))
        if self._frame is None or self._frame[0] != key:
            self._frame = (key, self._retry.frame_features(image), None, None)
        return self._frame[1]

    def _landmark_pose(self, image: np.ndarray, landmarks: LandmarkSnapshot
                       ) -> Optional[FeaturePose]:
        """The frame's PnP pose on ``landmarks`` (:meth:`LandmarkSnapshot.pose`),
        computed once per frame and snapshot."""
        feats = self.frame_features(image)     # a new frame resets the snapshot and pose
        key, _, seen, pose = self._frame
        if seen is not landmarks:
            cfg = self.config.feature_retry
            pose = landmarks.pose(feats, cfg.features, self._retry.camera, cfg)
            self._frame = (key, feats, landmarks, pose)
        return pose

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

    def relocalise(self, older: Sequence[MapKeyframe], image: np.ndarray, motion: MotionModel,
                   landmarks: Optional[LandmarkSnapshot] = None
                   ) -> Tuple[Optional[TrackResult], Optional[MapKeyframe]]:
        """``image`` tracked (:meth:`track`) from ``motion``'s last good pose,
        then from its PnP pose on the map's ``landmarks``, against the live
        keyframes ``older`` in the order given (the caller passes newest first);
        the first ``ok`` result and its keyframe, else ``(None, None)``."""
        for kf in older:
            tr = self.track(kf, image, [lambda: motion.last_good], motion.brightness,
                            landmarks=landmarks)
            if tr is not None and tr.ok:
                return tr, kf
        return None, None
