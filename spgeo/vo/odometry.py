"""Keyframe-based monocular visual odometry on SuperPrimitives (docs/design.md §5):
the per-frame state machine (initialise, track, lose, re-initialise).

One call per frame (:meth:`Odometry.track`).  The states and
their rules (initialisation, tracking with its retries, relocalisation,
re-initialisation, keyframe decisions, the trajectory that
:meth:`Odometry.result` reports) are stated in docs/design.md §5.1; options
are :class:`~spgeo.vo.config.OdometryConfig`'s.  ``Odometry`` drives them over
its state: the keyframe map (:class:`spgeo.vo.map.KeyframeMap`: keyframes,
segments, the store of retired keyframes, anchored and supporting frames) and
the frame tracker (:class:`spgeo.vo.frame_tracker.FrameTracker`: the motion
model's guesses, the retries, relocalisation, the keyframe decision).  The initialisation is
:class:`spgeo.vo.initialisation.Initialiser`'s (an owned object that returns an
:class:`~spgeo.vo.initialisation.InitDecision` which ``Odometry`` applies): a
keyframe pair without parallax never initialises a map
(:attr:`Odometry.init_failure`).  Mapping is
:class:`spgeo.vo.smoother.WindowMapper`'s (fixed-lag smoother over the last
``window`` keyframes and their supporting frames); with the landmarks it is
the back end (:class:`spgeo.vo.backend.WindowBackend`), which runs in a worker
process while the next frames are tracked (``OdometryConfig.mapping="live"``,
:mod:`spgeo.vo.mapping_worker`) or between two frames (``"inline"``).

Ablations: ``OdometryConfig.primitive_model`` (docs/design.md §5); oracle normals:
the ``"depth"`` front-end.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Dict, Iterable, Iterator, List, Optional, Tuple, Union

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..frame import Frame
from ..primitives import PrimitiveSet
from ..frontend import PrimitiveFrontEnd
from ..geometry import invert_pose, nearest_rigid
from ..similarity import moved_frame, sim3
from ..validation import check_camera
from .config import OdometryConfig
from .initialisation import FAILED, START, InitDecision, Initialiser
from .keyframe_store import KeyframeStore
from .loops import SegmentLoopClosure
from .frame_tracker import FrameTracker
from .keyframing import KeyframeMaker
from .backend import WindowBackend
from .keyframe import with_shape_values
from .map import KeyframeMap, MapKeyframe, SupportCandidate
from .mapping_worker import LiveMapping, MappingUpdate, MappingWorker
from .processing import checked_frame, opencv_threads
from .smoother import adopt_selection
from .result import (FrameResult, FrameStatus, OdometryResult, frame_records, save_run,
                     timing_statistics)
from .tracking import Keyframe, TrackResult, track_frame

__all__ = ["Odometry", "MAX_LEAD_FRAMES"]

#: live mapping: the most frames tracked while a window update is pending; the next one
#: waits for it (about what a 30 Hz camera gives during one update on two cores: an
#: offline run then tracks as far ahead of its map as a live one; docs/results.md)
MAX_LEAD_FRAMES = 8

log = logging.getLogger(__name__)


class Odometry:
    """Streaming monocular VO (module docstring).

    Args:
        camera: intrinsics of the input frames (:attr:`input_camera`).  The
            VO works at ``config.processing_size_for(camera.size)``
            (:mod:`spgeo.vo.processing`; :attr:`camera` is ``camera`` resized to
            it): :meth:`track` resizes frames of the input size, so a loop over
            full-size frames processes what ``spgeo vo`` processes.
        config: :class:`OdometryConfig`.
        frontend: the :class:`PrimitiveFrontEnd` that primifies keyframes (its
            working size: the processing size, or None for the image's).
        store: where keyframes that left the window keep their image and
            primitives (:class:`~spgeo.vo.keyframe_store.KeyframeStore`;
            default None: a temporary folder, removed with the odometry).
        wait_for_mapper: with the mapping worker (``config.mapping="live"``),
            wait for each window update before the next frame: the numbers of
            ``"inline"`` mapping, through the worker (its tests).

    Live mapping (docs/design.md §5.1, *Mapping off the tracking path*): a new
    keyframe's back end runs in the worker while the next frames are tracked
    against the new keyframe as made (pose and scales before the update); the
    update is applied at the first frame that finds it ready.  A frame that
    wants a keyframe while the update is pending gets its front-end primitives
    at once (the segmentation overlaps the solve), then, once the update is
    applied, is tracked again against the updated keyframe and decided again
    (an unrefined keyframe tracks worse and would ask for keyframes sooner); a
    kept keyframe is rendered on the updated map.  A frame lost against a
    pending map is tracked again after the update.  One update is in flight at
    a time, and at most :data:`MAX_LEAD_FRAMES` frames are tracked while it is
    pending (the next waits for it).
    Frames tracked while an update was pending, the updates' latency in frames
    and the worker's seconds and peak memory are in :meth:`report`
    (``mapping_worker``).  The trajectory then depends on when updates arrive,
    i.e. on the machine and its load.  :meth:`result`, :meth:`report`,
    :meth:`save` and the keyframe accessors wait for the pending update.
    :meth:`close` (or ``with Odometry(...) as vo:``) stops the worker; so does
    garbage collection.

    Memory: after a frame is processed only its :class:`FrameResult` (pose,
    status, timings, the small :class:`TrackResult`) and relative pose stay;
    keyframes outside the window are retired
    (:meth:`spgeo.vo.map.MapKeyframe.retire`: pose and median depth in
    memory, image and primitives in the store), so memory grows with the
    number of frames only by these small records.
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig = OdometryConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None,
                 store: Optional[KeyframeStore] = None,
                 wait_for_mapper: bool = False) -> None:
        if frontend is None:
            raise ValueError("Odometry needs a front-end (spgeo.frontend.make_frontend)")
        if not isinstance(config, OdometryConfig):
            raise TypeError(f"Odometry: config must be an OdometryConfig, got "
                            f"{type(config).__name__}")
        self.input_camera = check_camera(camera, "Odometry: camera")
        self.camera = self.input_camera.resized(*config.processing_size_for(camera.size))
        self.config = config
        self.frontend = frontend
        self._frames: List[FrameResult] = []
        self._map = KeyframeMap(config.window, config.keyframe_levels, config.n_support, store)
        self._tracker = FrameTracker(self.camera, config)
        self._motion = self._tracker.motion
        self._initialiser = Initialiser(config, self.camera, frontend.uses_depth)
        self._n_lost = 0
        self._backend: Optional[WindowBackend] = None
        self._worker: Optional[MappingWorker] = None
        if config.mapping_in_worker:
            self._worker = MappingWorker(self.camera, config)
        else:
            self._backend = WindowBackend(self.camera, config)
            # the smoother writes the map's supporting-frame poses
            self._backend.mapper.support_pose = self._map.support_pose
        self._wait = bool(wait_for_mapper)
        self._live = LiveMapping()
        self._maker = KeyframeMaker(self.camera, config, frontend)
        self._loops = (SegmentLoopClosure(self.camera, config.loop_closure)
                       if config.loop_closure.enabled else None)

    # ------------------------------------------------------------ public API
    def track(self, frame: Frame) -> FrameResult:
        """Process the next frame (a :class:`~spgeo.frame.Frame` at the input
        camera's size, resized here by :func:`~spgeo.vo.processing.resize_for_vo`,
        or already at the processing size; its depth is read only by a
        depth-using front-end).

        Returns the frame's online :class:`FrameResult` (also in :attr:`frames`),
        final except for one case: a frame returned while its segment waits for
        keyframe 1 (``INIT`` / ``LOST``, buffered by the
        :class:`~spgeo.vo.initialisation.Initialiser`) gets its ``status``
        (``INIT`` or ``LOST``) and ``T_world_cam`` rewritten once, in place, by
        the call that creates keyframe 1 (it is re-tracked against the solved
        keyframe 0); nothing else changes.  The trajectory's authority is
        :meth:`result` (it follows the map's smoothed poses and scales).

        Raises:
            TypeError: ``frame`` is not a :class:`~spgeo.frame.Frame`.
            InputError: (a ``ValueError``) the image's (H, W) is neither the
                input camera's nor the processing camera's, it holds NaN / inf,
                or the timestamp is not finite or
                not strictly after the previous frame's (seconds, or frame
                numbers for data without time); the frame is not processed.
        """
        with opencv_threads(1):
            return self._track_frame(frame)

    def _track_frame(self, frame: Frame) -> FrameResult:
        """:meth:`track`'s body."""
        t0 = time.perf_counter()
        idx = len(self._frames)
        frame = checked_frame(frame, idx, self.camera, self.input_camera,
                              bool(self.frontend.uses_depth),
                              self._frames[-1].timestamp if self._frames else None)
        timings: Dict[str, float] = {}
        if self._update_pending and (self._worker.ready()
                                     or self._live.lead(idx) >= MAX_LEAD_FRAMES):
            self._sync(timings)
        if self._update_pending:
            self._live.older_map_frames += 1
        if idx == 0:
            res = self._start(frame, idx, np.eye(4), timings)
        elif len(self._map.seg_kfs) < 2:
            res = self._initialise(frame, idx, timings)
        else:
            res = self._track(frame, idx, timings)
        timings["total"] = time.perf_counter() - t0
        res.timings = timings
        res.segment = self._map.segment
        self._frames.append(res)
        return res

    def result(self) -> OdometryResult:
        """Per-frame trajectory (docs/design.md §5.1, *Trajectory*;
        :meth:`spgeo.vo.map.KeyframeMap.frame_poses`), after the pending window
        update (live mapping: waits for it)."""
        self._sync()
        poses, is_kf = self._map.frame_poses(self._frames)
        return OdometryResult(np.array([f.timestamp for f in self._frames], dtype=float),
                              poses, [f.status for f in self._frames], is_kf,
                              np.array([f.segment for f in self._frames], dtype=int))

    def smoother_estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window)."""
        return self._inline_backend("smoother_estimate").mapper.estimate()

    @property
    def smoother(self) -> gtsam.BatchFixedLagSmoother:
        """The window's ``gtsam.BatchFixedLagSmoother`` (:class:`WindowMapper`;
        ``OdometryConfig.mapping="inline"`` only: live, it is in the worker
        process, and this raises ``RuntimeError``)."""
        return self._inline_backend("smoother").mapper.smoother

    @smoother.setter
    def smoother(self, value) -> None:
        self._inline_backend("smoother").mapper.smoother = value

    def _inline_backend(self, what: str) -> WindowBackend:
        if self._backend is None:
            raise RuntimeError(f"Odometry.{what}: the window smoother is in the mapping "
                               "worker process (OdometryConfig.mapping='live'); use "
                               "mapping='inline' to reach it")
        return self._backend

    def close(self) -> None:
        """Stop the mapping worker (a pending update is dropped: call
        :meth:`result` first to keep it); idempotent.  Nothing to do with
        inline mapping."""
        if self._worker is not None:
            self._worker.close()

    def __enter__(self) -> "Odometry":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def keyframes(self) -> List[Keyframe]:
        """All keyframes in creation order (the window's at their smoothed state).

        Keyframes that left the window are built again from the store at every
        call (new objects, equal to the ones they were): for their poses use
        :meth:`result`, for the window :meth:`window_keyframes`."""
        self._sync()
        return [self.keyframe(k) for k in self._map.order]

    @property
    def n_keyframes(self) -> int:
        """Number of keyframes so far (indices ``0 .. n_keyframes - 1``)."""
        return len(self._map.order)

    def keyframe(self, k: int) -> Keyframe:
        """Keyframe ``k`` (:attr:`keyframes`; one read from the store if retired)."""
        self._sync()
        return self._map.restore(k)[1]

    def keyframe_image(self, k: int) -> np.ndarray:
        """The input image keyframe ``k`` was made from (as given to :meth:`track`)."""
        return self._map.kfs[k].input_image(self._map.store)

    def iter_keyframes(self, indices: Optional[Iterable[int]] = None
                       ) -> Iterator[Tuple[int, np.ndarray, Keyframe]]:
        """``(k, input image, Keyframe)`` of keyframes ``indices`` (default: all),
        in the order given, at their current state: keyframes that left the
        window are read back from the store one at a time (a consumer that
        keeps none holds one in memory)."""
        self._sync()
        return self._map.iter_keyframes(indices)

    def window_keyframes(self) -> Dict[int, Keyframe]:
        """Keyframe index -> :class:`Keyframe` of the keyframes not retired (the
        window's: the only ones that can still change), in creation order."""
        self._sync()
        return {k: self._map.kfs[k].keyframe for k in self._map.live}

    @property
    def frames(self) -> List[FrameResult]:
        """The :class:`FrameResult` of every frame so far."""
        return list(self._frames)

    @property
    def initialised(self) -> bool:
        """Whether the current map segment has its keyframe pair (keyframes 0
        and 1): until then no frame is tracked against a map and, with a
        monocular front-end, keyframe 0 has no depth."""
        return len(self._map.seg_kfs) >= 2

    @property
    def init_failure(self) -> Optional[str]:
        """Why the current segment is not initialised (None when it is, or
        before its second frame)."""
        init = self._initialiser
        return None if self.initialised else (init.failure or init.wait_note)

    def keyframes_with_depth(self) -> List[int]:
        """Indices (as in :attr:`keyframes`) of the keyframes whose primitives
        carry depth: all with a depth-using front-end; monocular, those of map
        segments that were initialised (a segment's lone keyframe 0 has only
        its unscaled shapes: its cloud would be a surface at an arbitrary depth)."""
        return self._map.keyframes_with_depth(bool(self.frontend.uses_depth))

    def report(self) -> dict:
        """Run statistics (JSON-ready): counts, per-stage seconds, mapping and
        initialisation reports (``initialised``: :attr:`initialised`;
        ``init_failure``: :attr:`init_failure`), configuration."""
        self._sync()
        reports = self._live.reports if self._backend is None else self._backend.mapper.reports
        maps = [m["seconds"] for m in reports if "seconds" in m]
        lms = (self._live.landmarks if self._backend is None
               else self._backend.landmarks_report())
        return {
            "n_frames": len(self._frames), "n_keyframes": len(self._map.order),
            "n_segments": self._map.segment + 1,
            "initialised": self.initialised, "init_failure": self.init_failure,
            "status_counts": self.result().status_counts(),
            **timing_statistics(self._frames),
            "mapping_seconds_per_keyframe": float(np.mean(maps)) if maps else None,
            "config": dataclasses.asdict(self.config),
            "frontend": getattr(self.frontend, "name", str(self.frontend)),
            "sfm": self._initialiser.reports,
            "scale_checks": self._maker.scale_checks,
            "mapping": reports,
            "mapping_mode": "inline" if self._worker is None else "live",
            **({} if self._worker is None else {"mapping_worker": self._live.report()}),
            "loop_closures": None if self._loops is None else self._loops.report(),
            **({} if lms is None else {"landmarks": lms}),
            "frames": frame_records(self._frames),
        }

    def save(self, directory: Union[str, Path], clouds: bool = True,
             extra_report: Optional[dict] = None,
             trajectory: Optional[OdometryResult] = None) -> Dict[str, object]:
        """:func:`spgeo.vo.result.save_run` of ``trajectory`` (default
        :meth:`result`; a caller may pass it with frames the VO never saw, e.g.
        :meth:`Trajectory.with_skipped`), :meth:`report` updated with
        ``extra_report`` and, with ``clouds``, the keyframes that carry depth
        (:meth:`keyframes_with_depth`; keyframes that left the window are read
        back from the keyframe store one at a time)."""
        kfs = self.iter_keyframes(self.keyframes_with_depth())
        traj = self.result() if trajectory is None else trajectory
        return save_run(directory, traj, {**self.report(), **(extra_report or {})},
                        kfs if clouds else None)

    # ------------------------------------------------------------ stages
    def _start(self, frame: Frame, idx: int, T_world: np.ndarray,
               timings: Dict[str, float], median_depth: Optional[float] = None) -> FrameResult:
        """Keyframe 0 of a map segment at ``T_world``."""
        kf = self._maker.first(frame, T_world, timings, median_depth)
        k = self._map.next_index
        self._map.add(MapKeyframe(k, idx, np.asarray(frame.image), kf, self._map.segment),
                      new_segment=True)
        self._map.retire_outside_window()
        self._map.candidates.clear()
        self._initialiser.reset()
        self._motion.reset(T_world)
        self._n_lost = 0
        return FrameResult(idx, float(frame.timestamp), np.array(T_world, dtype=float),
                           FrameStatus.KEYFRAME if idx == 0 else FrameStatus.REINIT, keyframe_index=k)

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of a segment with only keyframe 0: tracked against it, then
        the :class:`Initialiser`'s decision applied."""
        kf0 = self._map.kfs[self._map.seg_kfs[0]]
        t = time.perf_counter()
        tr = self._tracker.track(kf0.keyframe, frame.image)
        timings["track"] = time.perf_counter() - t
        if tr.ok:
            self._motion.accept(tr)
        self._n_lost = 0 if tr.ok else self._n_lost + 1
        dec = self._initialiser.step(frame.image, idx, kf0, tr, self._motion.brightness,
                                     self._map.segment, timings)
        if dec.action == START:
            return self._start_map(frame, idx, kf0, dec, tr, timings)
        last_good = self._motion.last_good
        if dec.action == FAILED:
            self._n_lost += 1
            return FrameResult(idx, float(frame.timestamp), last_good.copy(),
                               FrameStatus.LOST, track=tr)
        if tr.ok:   # waiting for keyframe 1: INIT at the pose tracked against keyframe 0
            self._map.anchors[idx] = (kf0.index, dec.T_kf0_frame, kf0.keyframe.median_depth)
        pose = tr.T_world_frame if tr.ok else last_good
        return FrameResult(idx, float(frame.timestamp), pose.copy(),
                           FrameStatus.INIT if tr.ok else FrameStatus.LOST, track=tr)

    def _start_map(self, frame: Frame, idx: int, kf0: MapKeyframe, dec: InitDecision,
                   tr: TrackResult, timings: Dict[str, float]) -> FrameResult:
        """Apply a ``"start"`` decision: keyframe 0 takes the SfM's primitives, the
        re-tracked frames' results their poses and statuses (:meth:`track`), and
        this frame becomes keyframe 1."""
        kf0.keyframe = dec.keyframe0
        self._map.adopt_retracked(kf0, dec.retracked, self._frames)
        self._motion.set_poses(dec.T_world_kf1, dec.T_world_last)
        self._n_lost = 0
        return self._new_keyframe(frame, idx, dec.T_world_kf1, timings, track=tr)

    def _track(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of an initialised segment: tracked against the latest keyframe
        (or relocalised against an older one), then the keyframe decision."""
        latest = self._map.latest
        ref = latest
        t = time.perf_counter()
        tr = self._tracker.track(latest.keyframe, frame.image, retry=latest)
        if not tr.ok and self._update_pending:
            # lost against the map before its update: tracked again after it (the
            # wait is mapping's time, not tracking's)
            tracked = time.perf_counter() - t
            self._sync(timings)
            t = time.perf_counter() - tracked
            tr = self._tracker.track(latest.keyframe, frame.image, retry=latest)
        relocalised = False
        if not tr.ok:
            older = [self._map.kfs[k] for k in reversed(self._map.seg_kfs[-self.config.window:-1])]
            tr_old, kf_old = self._tracker.relocalise(older, frame.image)
            if tr_old is not None:
                tr, ref, relocalised = tr_old, kf_old, True
        timings["track"] = time.perf_counter() - t
        if not tr.ok:
            return self._lost(frame, idx, tr, timings)
        was_lost = self._n_lost > 0
        self._n_lost = 0
        self._motion.accept(tr)
        T_ref_f = invert_pose(ref.keyframe.T_world_kf) @ tr.T_world_frame
        self._map.anchors[idx] = (ref.index, T_ref_f, ref.keyframe.median_depth)
        status = FrameStatus.RELOCALISED if (was_lost or relocalised) else FrameStatus.OK
        # tracked against an older keyframe: make it a keyframe to re-anchor the map
        if ref is not latest or self._tracker.wants_keyframe(tr, T_ref_f, latest):
            if ref is latest and self._update_pending:
                tr, T_ref_f, res = self._redecided(frame, idx, tr, timings)
            else:
                res = self._new_keyframe(frame, idx, tr.T_world_frame, timings, track=tr)
            if res is not None:
                return res
        if ref is latest:
            self._map.add_candidate(SupportCandidate(idx, np.asarray(frame.image), T_ref_f,
                                                     np.asarray(tr.brightness, float)))
        return FrameResult(idx, float(frame.timestamp), tr.T_world_frame.copy(), status,
                           track=tr)

    def _lost(self, frame: Frame, idx: int, tr: TrackResult,
              timings: Dict[str, float]) -> FrameResult:
        """A frame not tracked: ``LOST`` at the last good pose, or after
        ``max_lost_frames`` the map re-initialised."""
        self._n_lost += 1
        log.info("frame %d lost (%s)", idx, tr.reason)
        if self._n_lost >= self.config.max_lost_frames:
            log.warning("frame %d: %d frames lost; re-initialising the map", idx,
                        self._n_lost)
            return self._reinitialise(frame, idx, timings)
        return FrameResult(idx, float(frame.timestamp), self._motion.last_good.copy(),
                           FrameStatus.LOST, track=tr)

    def _reinitialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        grey = np.asarray(frame.image, dtype=np.float64)
        if float(np.std(grey)) < 1e-3 * max(float(np.max(np.abs(grey))), 1.0):
            # a featureless frame cannot start a map: stay lost, retry on the next frame
            return FrameResult(idx, float(frame.timestamp), self._motion.last_good.copy(),
                               FrameStatus.LOST)
        self._sync(timings)
        med = self._map.latest.keyframe.median_depth
        self._map.segment += 1
        if self._backend is not None:
            self._backend.reset()
        self._live.reset_next = True
        return self._start(frame, idx, self._motion.last_good.copy(), timings, median_depth=med)

    def _new_keyframe(self, frame: Frame, idx: int, T_world: np.ndarray,
                      timings: Dict[str, float], track: Optional[TrackResult],
                      prims: Optional[PrimitiveSet] = None):
        """Make frame ``idx`` (at ``T_world``) a keyframe (:class:`KeyframeMaker`;
        ``prims``: its front-end primitives, already made), then loop closure
        and the window update (live: sent to the worker).  A pending update is
        applied first: the keyframe is made on the updated map (the frame's pose
        moved with the keyframe it was tracked against).  None when the render
        gives no scale."""
        if self._sync(timings) and idx in self._map.anchors:
            T_world = nearest_rigid(self._map.frame_pose(*self._map.anchors[idx]))
        k = self._map.next_index
        made = self._maker.rendered(frame, idx, k, T_world, self._map.window_kfs(), timings,
                                    prims=prims)
        if made is None:
            return None
        keyframe, weights = made
        self._map.add(MapKeyframe(k, idx, np.asarray(frame.image), keyframe, self._map.segment,
                                  prior_weights=weights))
        self._map.anchors.pop(idx, None)
        if self._worker is not None:
            self._submit(k)
            if self._wait:
                self._sync(timings)
            T_new = self._map.kfs[k].keyframe.T_world_kf
            return FrameResult(idx, float(frame.timestamp), T_new.copy(), FrameStatus.KEYFRAME,
                               keyframe_index=k, track=track)
        self._backend.add_landmarks(self._map.window_kfs(extra=1), self._map.segment, timings)
        closed = self._close_loop(timings)
        if self._backend.map(self._map.window_kfs(extra=1), self._map.candidates,
                             self._map.segment, closed, timings):
            self._map.seg_kfs = self._map.seg_kfs[-2:]
        self._map.candidates.clear()
        self._map.retire_outside_window()
        T_new = self._map.kfs[k].keyframe.T_world_kf
        if self._loops is not None:
            self._loops.update_poses(self._map.live_poses())
        # the smoothed pose of the new keyframe replaces the tracked one
        self._motion.to_keyframe(T_new)
        return FrameResult(idx, float(frame.timestamp), T_new.copy(), FrameStatus.KEYFRAME,
                           keyframe_index=k, track=track)

    # ------------------------------------------------------------ live mapping
    def _redecided(self, frame: Frame, idx: int, tr: TrackResult, timings: Dict[str, float]
                   ) -> Tuple[TrackResult, np.ndarray, Optional[FrameResult]]:
        """Frame ``idx`` wants to be a keyframe, decided against the latest
        keyframe before its pending update: its front-end primitives are made
        while the worker solves, then the update is applied, the frame is
        tracked again against the updated keyframe and the decision taken again
        (an unrefined keyframe tracks worse and would ask for keyframes sooner);
        a kept keyframe is rendered from the updated map (:meth:`_new_keyframe`).
        Returns ``(track result, T_latest_frame, keyframe FrameResult or None)``."""
        latest = self._map.latest
        t = time.perf_counter()
        prims = self._maker.primify(frame)
        timings["frontend"] = time.perf_counter() - t
        ref, _, median_then = self._map.anchors[idx]
        self._sync(timings)
        t = time.perf_counter()
        T0 = self._map.frame_pose(*self._map.anchors[idx])    # moved with the update
        tr2 = track_frame(latest.keyframe, frame.image, T0, tr.brightness, self.config.tracker)
        timings["track"] = timings.get("track", 0.0) + time.perf_counter() - t
        if tr2.ok:
            tr = tr2
            self._motion.replace_last(tr)
            T_ref_f = invert_pose(latest.keyframe.T_world_kf) @ tr.T_world_frame
        else:
            T_ref_f = self._map.anchors[idx][1].copy()
            T_ref_f[:3, 3] *= latest.keyframe.median_depth / median_then
        self._map.anchors[idx] = (ref, T_ref_f, latest.keyframe.median_depth)
        if not self._tracker.wants_keyframe(tr, T_ref_f, latest):
            return tr, T_ref_f, None
        T_world = nearest_rigid(latest.keyframe.T_world_kf @ T_ref_f)
        return tr, T_ref_f, self._new_keyframe(frame, idx, T_world, timings, tr, prims=prims)

    def _submit(self, k: int) -> None:
        """Send new keyframe ``k``'s back-end job to the worker; the next frames
        are tracked against ``k`` as made (brightness relative to it: zero)."""
        window = self._map.window_kfs(extra=1)
        for kf in window:
            adopt_selection(kf, self.config)
        job = self._worker.job(window, self._map.candidates, self._map.segment,
                               self._live.reset_next)
        self._worker.submit(job)
        self._live.reset_next = False
        kf = self._map.kfs[k].keyframe
        self._live.pending = (k, kf.T_world_kf.copy(), float(kf.median_depth), len(self._frames))
        self._map.candidates.clear()
        self._motion.brightness = np.zeros(2)

    @property
    def _update_pending(self) -> bool:
        """Whether a window update is in the worker (live mapping)."""
        return self._worker is not None and self._worker.pending

    def _sync(self, timings: Optional[Dict[str, float]] = None) -> bool:
        """Wait for the pending window update and apply it (:meth:`_apply`);
        its seconds (waiting included) in ``timings["mapping"]``.  Returns
        whether an update was applied."""
        if not self._update_pending:
            return False
        t = time.perf_counter()
        self._apply(self._worker.receive())
        if timings is not None:
            timings["mapping"] = timings.get("mapping", 0.0) + time.perf_counter() - t
        return True

    def _apply(self, upd: MappingUpdate) -> None:
        """A worker's update applied as the inline back end applies it: the
        refreshed keyframes (:func:`with_shape_values`), supporting frames and
        window restart, then retirement and the motion model (frames tracked
        since the job was sent: moved with their keyframe's similarity)."""
        k, T_old, med_old, n_sent = self._live.pending
        for j, (T, th) in sorted(upd.keyframes.items()):
            mk = self._map.kfs[j]
            mk.keyframe = with_shape_values(mk.keyframe, th, self.config.primitive_model, T)
            self._worker.synced(j, mk.keyframe)
        self._map.support_pose.update(upd.support_pose)
        if upd.restarted:
            self._map.seg_kfs = self._map.seg_kfs[-2:]
        self._map.retire_outside_window()
        T_new, med_new = self._map.kfs[k].T_world_kf, self._map.kfs[k].median_depth
        if len(self._frames) == n_sent:     # nothing tracked meanwhile: as inline
            self._motion.to_keyframe(T_new)
        else:
            W = sim3(T_new[:3, :3], T_new[:3, 3], med_new / med_old) @ invert_pose(T_old)
            self._motion.move(lambda T: nearest_rigid(moved_frame(W, T)))
            for c in self._map.candidates:
                c.T_kf_frame = c.T_kf_frame.copy()
                c.T_kf_frame[:3, 3] *= med_new / med_old
        self._live.record(upd, len(self._frames) - n_sent)

    def _close_loop(self, timings: Dict[str, float]) -> bool:
        """Register the new keyframe (and, in a new segment, its keyframe 0) with
        the loop closer; apply an accepted loop's correction.  True when one was
        applied."""
        if self._loops is None:
            return False
        t = time.perf_counter()
        landmarks = self._backend.landmarks
        corr = self._loops.add_keyframes(self._map.segment, self._map.segment_live(), landmarks)
        if corr is not None:
            self._map.apply_loop_correction(corr, self._motion)
            if landmarks is not None:     # moved with the map, then fused
                landmarks.apply_similarity(corr.W_new_old)
                landmarks.reobserve(self._map.seg_kfs[-1])
        timings["loop"] = time.perf_counter() - t
        return corr is not None
