"""The VO's back end: what a new keyframe sets off after it is made (docs/design.md
§5.1, *The mapping port*), as one job in and one update out.

:class:`WindowBackend` keeps its own copies of the window's keyframes and runs, per
:class:`MappingJob`: the new keyframe's sparse landmarks
(:class:`~spgeo.vo.landmarks.LandmarkMap`), loop closure over the map segment
(:class:`~spgeo.vo.loops.SegmentLoopClosure`, when on; a correction moves its copies
and landmarks before the window is solved) and the window smoother's update
(:class:`~spgeo.vo.smoother.WindowMapper`).  It answers a :class:`MappingUpdate`:
what changed, for the caller to apply to its map
(:meth:`spgeo.vo.map.KeyframeMap.apply_update`).

The same object runs in the caller's process (``OdometryConfig.mapping.mode="inline"``)
or in the mapping worker process (``"live"``, :mod:`spgeo.vo.mapping_worker`);
both are reached through :mod:`spgeo.vo.mapping_port`, and the same job gives the
same numbers in both.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..loop import LoopCorrection
from .config import OdometryConfig
from .landmark_snapshot import LandmarkSnapshot
from .landmarks import LandmarkMap
from .loops import SegmentLoopClosure
from .map import MapKeyframe, SupportCandidate
from .smoother import WindowMapper

__all__ = ["WindowBackend", "MappingJob", "MappingUpdate", "BackendError"]


class BackendError(RuntimeError):
    """A :class:`MappingJob` the back end cannot run (e.g. keyframes it lacks)."""


@dataclass
class MappingJob:
    """One back-end update, made when a keyframe is added.

    Attributes:
        window: keyframe indices of the segment's window and the keyframe leaving
            it, oldest first (the newest is the new keyframe).
        keyframes: the window keyframes whose state the back end lacks (copies
            without cached mapping pixels).
        candidates: the previous keyframe's supporting frames (the mapper's
            choice among its candidates, :func:`~spgeo.vo.smoother.choose_support`:
            it keeps them all).
        segment: the map segment.
        reset: the smoother restarts first (a new segment).
    """

    window: List[int]
    keyframes: List[MapKeyframe]
    candidates: List[SupportCandidate]
    segment: int
    reset: bool = False


@dataclass
class MappingUpdate:
    """The back end's answer to a :class:`MappingJob`.

    Attributes:
        keyframes: keyframe index -> ``(T_world_kf, shape values)`` written by the
            smoother (:attr:`spgeo.vo.smoother.WindowMapper.refreshed`).
        support_pose: frame number -> smoothed ``T_world_frame`` of supporting frames.
        restarted: the window restarted from its last two keyframes.
        loop: the accepted loop's :class:`~spgeo.loop.LoopCorrection` (applied to
            the back end's copies before the window was solved; the caller
            applies it to its map first), or None.
        reports: the mapper's new report entries.
        timings: the back end's seconds (``landmarks``, ``loop``, ``mapping``).
        landmarks: the landmark map's report after the update (None without).
        loops: the loop closer's report after the update (None without).
        peak_rss_mib: the peak resident memory of the back end's process so far
            (MiB; None where ``/proc`` is absent).
        snapshot: the landmarks for the tracker after the update
            (:class:`~spgeo.vo.landmark_snapshot.LandmarkSnapshot`; None without
            landmarks).
        built: keyframe index -> the back end's refreshed
            :class:`~spgeo.vo.keyframe.Keyframe` (equal to ``with_shape_values`` of
            the caller's; only in the caller's process, never sent).
    """

    keyframes: Dict[int, Tuple[np.ndarray, np.ndarray]]
    support_pose: Dict[int, np.ndarray]
    restarted: bool
    loop: Optional[LoopCorrection] = None
    reports: List[dict] = field(default_factory=list)
    timings: Dict[str, float] = field(default_factory=dict)
    landmarks: Optional[dict] = None
    loops: Optional[dict] = None
    peak_rss_mib: Optional[float] = None
    snapshot: Optional[LandmarkSnapshot] = None
    built: Dict[int, object] = field(default_factory=dict)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "built": {}}


def peak_rss_mib() -> Optional[float]:
    """This process's peak resident set size, MiB: ``VmHWM`` of
    ``/proc/self/status`` (not ``ru_maxrss``, which keeps a forked parent's
    peak across ``exec``); None where it cannot be read."""
    try:
        with open("/proc/self/status", "rb") as fh:
            for line in fh:
                if line.startswith(b"VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


class WindowBackend:
    """Landmarks, loop closure and window mapping of one VO run.

    Args:
        camera: the processing camera.
        config: :class:`OdometryConfig` (``landmarks``, ``loop_closure``, the
            window's options).

    Attributes:
        mapper: the :class:`WindowMapper`.
        landmarks: the :class:`LandmarkMap` (None when ``config.landmarks`` is off).
        loops: the :class:`SegmentLoopClosure` (None when ``config.loop_closure`` is off).
        copies: keyframe index -> the back end's :class:`MapKeyframe` of the
            window (updated by every :meth:`run`).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig) -> None:
        self.config = config
        self.mapper = WindowMapper(config)
        self.landmarks = (LandmarkMap(camera, config.landmarks)
                          if config.landmarks.enabled else None)
        self.mapper.landmarks = self.landmarks
        self.loops = (SegmentLoopClosure(camera, config.loop_closure)
                      if config.loop_closure.enabled else None)
        self.copies: Dict[int, MapKeyframe] = {}
        self._landmark_segment = -1

    def run(self, job: MappingJob) -> MappingUpdate:
        """Apply ``job`` to :attr:`copies` (new states in, keyframes out of the
        window dropped), then landmarks, loop closure and the window update
        (module docstring).  Raises :class:`BackendError` when the job's window
        names a keyframe the back end has no copy of."""
        for kf in job.keyframes:
            self.copies[kf.index] = kf
        missing = [k for k in job.window if k not in self.copies]
        if missing:
            raise BackendError(f"mapping job without keyframes {missing}")
        self.copies = {k: v for k, v in self.copies.items() if k in job.window}
        if job.reset:
            self.reset()
        kfs = [self.copies[k] for k in job.window]
        timings: Dict[str, float] = {}
        n_reports = len(self.mapper.reports)
        self.add_landmarks(kfs, job.segment, timings)
        corr, candidates = self._close_loop(kfs, job, timings)
        restarted = self.map(kfs, candidates, job.segment, corr is not None, timings)
        if self.loops is not None:
            live = kfs[-2:] if restarted else kfs[-self.config.window:]
            self.loops.update_poses({kf.index: kf.T_world_kf for kf in live})
        refreshed = dict(self.mapper.refreshed)
        return MappingUpdate(
            refreshed, dict(self.mapper.refreshed_support), restarted,
            None if corr is None else dataclasses.replace(corr, graph=None),
            self.mapper.reports[n_reports:], timings, self.landmarks_report(),
            None if self.loops is None else self.loops.report(), peak_rss_mib(),
            self.snapshot(job.segment), {k: self.copies[k].keyframe for k in refreshed})

    def _close_loop(self, kfs: List[MapKeyframe], job: MappingJob, timings: Dict[str, float]
                    ) -> Tuple[Optional[LoopCorrection], List[SupportCandidate]]:
        """Register the new keyframe (and, in a new segment, its keyframe 0) with
        the loop closer; an accepted loop's correction moves the copies
        (:meth:`MapKeyframe.correct`), the landmarks (then fused) and the
        previous keyframe's supporting frames (their translations, in its depth
        units).  Returns ``(correction or None, the supporting frames)``."""
        if self.loops is None:
            return None, job.candidates
        t = time.perf_counter()
        corr = self.loops.add_keyframes(job.segment, kfs, self.landmarks)
        candidates = job.candidates
        if corr is not None:
            for kf in kfs:
                if kf.index in corr.scales:
                    kf.correct(corr.T_world_kf[kf.index], corr.scales[kf.index])
            if self.landmarks is not None:     # moved with the map, then fused
                self.landmarks.apply_similarity(corr.W_new_old)
                self.landmarks.reobserve(kfs[-1].index)
            s_prev = corr.scales.get(kfs[-2].index, 1.0)
            candidates = [c.scaled(s_prev) for c in candidates]
        timings["loop"] = time.perf_counter() - t
        return corr, candidates

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
            older = segment_kfs[-self.config.window:-1]   # keyframe 0, or a saved map's
            for j, kf in enumerate(older):
                self.landmarks.add_keyframe(kf.index, kf.image, kf.keyframe.T_world_kf,
                                            [k.index for k in older[:j + 1]])
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

    def snapshot(self, segment: int) -> Optional[LandmarkSnapshot]:
        """The tracker's :class:`LandmarkSnapshot` of the landmarks now (None
        without landmarks)."""
        if self.landmarks is None:
            return None
        return LandmarkSnapshot.of(self.landmarks, segment,
                                   self.config.landmarks.snapshot_landmarks)

    def landmarks_report(self) -> Optional[dict]:
        """:meth:`LandmarkMap.report` (None without landmarks)."""
        return None if self.landmarks is None else self.landmarks.report()
