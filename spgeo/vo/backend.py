"""The VO's back end: what a new keyframe sets off after it is made (docs/design.md
§5.1, *Mapping off the tracking path*): its sparse landmarks
(:class:`~spgeo.vo.landmarks.LandmarkMap`) and the window smoother's update
(:class:`~spgeo.vo.smoother.WindowMapper`).

:class:`WindowBackend` runs either inside :class:`spgeo.vo.Odometry` (between two
frames, ``OdometryConfig.mapping="inline"``) or in the mapping worker process
(:mod:`spgeo.vo.mapping_worker`, ``"live"``), on that process's copies of the
window's keyframes; the same code gives the same numbers in both.
"""
from __future__ import annotations

import time
from typing import Dict, List, Optional, Sequence

from ..camera import PinholeCamera
from .config import OdometryConfig
from .landmarks import LandmarkMap
from .map import MapKeyframe, SupportCandidate
from .smoother import WindowMapper

__all__ = ["WindowBackend"]


class WindowBackend:
    """Landmarks and window mapping of one VO run.

    Args:
        camera: the processing camera.
        config: :class:`OdometryConfig` (``landmarks``, the window's options).

    Attributes:
        mapper: the :class:`WindowMapper`.
        landmarks: the :class:`LandmarkMap` (None when ``config.landmarks`` is off).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig) -> None:
        self.config = config
        self.mapper = WindowMapper(config)
        self.landmarks = (LandmarkMap(camera, config.landmarks)
                          if config.landmarks.enabled else None)
        self.mapper.landmarks = self.landmarks
        self._landmark_segment = -1

    def add_landmarks(self, segment_kfs: Sequence[MapKeyframe], segment: int,
                      timings: Dict[str, float]) -> None:
        """The newest keyframe's landmarks (:mod:`spgeo.vo.landmarks`;
        ``segment_kfs``: the segment's window and the keyframe leaving it,
        oldest first); a new ``segment`` forgets the old ones (another scale).
        Seconds in ``timings["landmarks"]``; nothing without landmarks."""
        if self.landmarks is None:
            return
        t = time.perf_counter()
        new = segment_kfs[-1]
        if self._landmark_segment != segment:
            self.landmarks.clear()
            self._landmark_segment = segment
            if len(segment_kfs) >= 2:     # the previous keyframe's features too
                prev = segment_kfs[-2]
                self.landmarks.add_keyframe(prev.index, prev.image, prev.keyframe.T_world_kf,
                                            [prev.index])
        live = [kf.index for kf in segment_kfs[-self.config.window:]]
        self.landmarks.add_keyframe(new.index, new.image, new.keyframe.T_world_kf, live)
        timings["landmarks"] = time.perf_counter() - t

    def map(self, segment_kfs: Sequence[MapKeyframe], candidates: Sequence[SupportCandidate],
            segment: int, closed: bool, timings: Dict[str, float]) -> bool:
        """Window update with the newest of ``segment_kfs`` (as
        :meth:`add_landmarks`); after an applied loop correction (``closed``)
        the window restarts from the previous and the new keyframe (their
        corrected poses and scales; older keyframes stay as corrected).
        Refreshes the keyframes' ``keyframe`` (:meth:`WindowMapper.map_keyframe`).

        Returns True when the caller's segment keeps only its last two
        keyframes (the window restarted).  Seconds in ``timings["mapping"]``."""
        t = time.perf_counter()
        kfs: List[MapKeyframe] = list(segment_kfs)
        if closed:
            self.mapper.reset()
            kfs = kfs[-2:]
        restarted = self.mapper.map_keyframe(kfs, candidates, segment)
        timings["mapping"] = time.perf_counter() - t
        return restarted

    def reset(self) -> None:
        """A new map segment: the smoother restarts (the landmarks are forgotten
        by the segment's first :meth:`add_landmarks`)."""
        self.mapper.reset()

    def landmarks_report(self) -> Optional[dict]:
        """:meth:`LandmarkMap.report` (None without landmarks)."""
        return None if self.landmarks is None else self.landmarks.report()
