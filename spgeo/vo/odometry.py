"""Keyframe-based monocular visual odometry on SuperPrimitives: the per-frame state
machine (initialise, track, lose, re-initialise; docs/design.md §5.1, which also
names the objects it drives: map, motion model, tracking decision, keyframe policy,
initialiser, keyframe builder, mapping port, and the read side it owns).
"""
from __future__ import annotations

import functools
import logging
import time
from typing import Dict, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from ..primitives import PrimitiveSet
from ..frontend import PrimitiveFrontEnd, build_frontend
from ..geometry import invert_pose, nearest_rigid
from ..images import featureless
from ..validation import check_camera
from .config import OdometryConfig
from .frame_tracker import FrameTracker
from .initialisation import FAILED, START, InitDecision, Initialiser
from .keyframe_builder import KeyframeBuilder
from .keyframe_policy import AFTER_UPDATE, KEYFRAME, KeyframePolicy
from .keyframe_store import KeyframeStore
from .map import KeyframeMap, MapKeyframe, SupportCandidate
from .map_entry import MapEntry
from .mapping_port import MappingPort, apply_pending_update, make_port
from .motion import MotionModel
from .processing import checked_frame, opencv_threads
from .readout import OdometryReadout, ReadSide
from .result import FrameLog, FrameResult, FrameStatus, frame_result, timed
from .saved_map import SavedMap
from .tracking import TrackResult

__all__ = ["Odometry"]

log = logging.getLogger(__name__)


class Odometry(ReadSide):
    """Streaming monocular VO (module docstring).

    Args:
        camera: intrinsics of the input frames (:attr:`input_camera`).  The VO works
            at ``config.processing_size_for(camera.size)`` (:attr:`camera`):
            :meth:`track` resizes frames of the input size as ``spgeo vo`` does.
        config: :class:`OdometryConfig`.
        frontend: the :class:`PrimitiveFrontEnd` that primifies keyframes (its
            working size: the processing size, or None for the image's); default
            None: the classical front-end at the processing size (``spgeo vo``'s).
        store: where keyframes that left the window keep their image and
            primitives (:class:`~spgeo.vo.keyframe_store.KeyframeStore`;
            default None: a temporary folder, removed with the odometry).
        wait_for_mapper: with live mapping, apply each update before the next frame
            (lead 0): the numbers of ``"inline"`` mapping, through the worker (tests).
        port: the :class:`~spgeo.vo.mapping_port.MappingPort` (default None: the
            one of ``config.mapping.mode``, :func:`~spgeo.vo.mapping_port.make_port`).
        saved_map: a :class:`~spgeo.vo.saved_map.SavedMap` to continue in (the first
            frames relocalised into it, :mod:`spgeo.vo.map_entry`); ``InputError``
            when it does not fit (camera, primitive model, units).

    Attributes:
        readout: the :class:`~spgeo.vo.readout.OdometryReadout`, whose members
            (:meth:`result`, :meth:`report`, :meth:`save`, ...) it forwards (``ReadSide``).

    Mapping (docs/design.md §5.1): reads apply the pending update first; :meth:`close`
    (or ``with``) stops a worker.  Memory: after a frame its :class:`FrameResult` and
    anchor stay; keyframes leaving the window go to the store, their cached features away.
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig = OdometryConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None,
                 store: Optional[KeyframeStore] = None,
                 wait_for_mapper: bool = False, port: Optional[MappingPort] = None,
                 saved_map: Optional[SavedMap] = None) -> None:
        if not isinstance(config, OdometryConfig):
            raise TypeError(f"Odometry: config must be an OdometryConfig, got "
                            f"{type(config).__name__}")
        self.input_camera = check_camera(camera, "Odometry: camera")
        self.camera = self.input_camera.resized(*config.processing_size_for(camera.size))
        frontend = build_frontend("classical", self.camera.size) if frontend is None else frontend
        self.config, self.frontend = config, frontend
        self._frames = FrameLog()
        self._map = KeyframeMap(config.window, config.keyframe_levels, config.n_support, store)
        self._tracker = FrameTracker(self.camera, config)
        self._motion = MotionModel()
        self._n_lost = 0
        self._port = port if port is not None else make_port(self.camera, config,
                                                              wait_for_mapper)
        self._policy = KeyframePolicy(config.keyframe, self._port)
        self._initialiser = Initialiser(config, self.camera, solver=self._port,
                                        policy=self._policy)
        self._builder = KeyframeBuilder(self.camera, config, frontend)
        self._sync = functools.partial(apply_pending_update, self._port, self._map, self._motion,
                                       self._frames)
        self.readout = OdometryReadout(self.camera, config, frontend, self._frames, self._map,
                                       self._port, self._initialiser, self._builder,
                                       self._sync, type(self).__name__)
        if saved_map is not None:
            saved_map.check_fits(self.camera, config.primitive_model, self.units, "saved map")
        self._entry = None if saved_map is None else MapEntry(saved_map, self._tracker, config)

    # ------------------------------------------------------------ public API
    def track(self, frame: Frame) -> FrameResult:
        """Process the next frame (a :class:`~spgeo.frame.Frame` at the input
        camera's size, resized here by :func:`~spgeo.vo.processing.resize_for_vo`,
        or already at the processing size; its depth is read only by a
        depth-using front-end).

        Returns the frame's online :class:`FrameResult` (also in :attr:`frames`),
        final except while its segment waits for keyframe 1: the call that makes
        keyframe 1 rewrites the frames it re-tracks once, in place (docs/design.md
        §5.1, *Initialisation*).  The trajectory's authority is :meth:`result` (it
        follows the map's smoothed poses and scales).

        Raises:
            TypeError: ``frame`` is not a :class:`~spgeo.frame.Frame`.
            InputError: (a ``ValueError``) a check of
                :func:`~spgeo.vo.processing.checked_frame` failed (image size or camera,
                NaN / inf, a timestamp not after the previous); the frame is not processed.
        """
        with opencv_threads(1):
            t0 = time.perf_counter()
            idx = len(self._frames)
            frame = checked_frame(frame, idx, self.camera, self.input_camera,
                                  bool(self.frontend.uses_depth),
                                  self._frames[-1].timestamp if self._frames else None)
            timings: Dict[str, float] = {}
            res = self._process(frame, idx, timings)
            timings["total"] = time.perf_counter() - t0
            res.timings = timings
            self._frames.append(res)
            return res

    def close(self) -> None:
        """Stop the mapping worker, if any (a pending update is dropped: call
        :meth:`result` first to keep it); idempotent."""
        self._port.close()

    def __enter__(self) -> "Odometry":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ stages
    def _process(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """One processing step of frame ``idx`` (a frame caught up again too)."""
        if self._port.due(self._frames.steps):
            self._sync(timings)
        self._port.note_frame()
        if self._entry is not None:
            res = self._enter(frame, idx, timings)
        elif idx == 0:
            res = self._start(frame, idx, np.eye(4), timings)
        elif not self._map.tracking:
            res = self._initialise(frame, idx, timings)
        else:
            res = self._track(frame, idx, timings)
        res.segment = self._map.segment
        self._frames.steps += 1
        return res

    def _start(self, frame: Frame, idx: int, T_world: np.ndarray,
               timings: Dict[str, float], median_depth: Optional[float] = None) -> FrameResult:
        """Keyframe 0 of a map segment at ``T_world``; with sensor depth it comes with
        its scale (tracked against at once, its shapes' priors as a render's)."""
        kf = self._builder.first(frame, T_world, timings, median_depth)
        k, depth = self._map.next_index, bool(self.frontend.uses_depth)
        w = np.full(len(kf.primitives), self.config.render_prior_weight) if depth else None
        self._map.add(MapKeyframe(k, idx, np.asarray(frame.image), kf, self._map.segment,
                                  prior_weights=w), new_segment=True, scaled=depth)
        self._map.retire_outside_window()
        self._map.take_candidates()
        self._initialiser.reset()
        self._motion.reset(T_world, float(frame.timestamp))
        self._n_lost = 0
        status = FrameStatus.KEYFRAME if idx == 0 else FrameStatus.REINIT
        return frame_result(frame, idx, T_world, status, keyframe_index=k)

    def _enter(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of a run entering a saved map (:class:`MapEntry`): ``LOST`` until
        placed, then ``RELOCALISED`` against the saved keyframe, the newest of the
        segment's (saved) keyframes; given up, a map of the run's own."""
        with timed(timings, "track"):
            got = self._entry.step(frame.image, self._map.next_index, self._map.segment)
        if got is None and not self._entry.given_up:
            return frame_result(frame, idx, np.eye(4), FrameStatus.LOST)
        self._entry = None
        if got is None:
            return self._start(frame, idx, np.eye(4), timings)
        kfs, tr, self._map.landmarks = got
        for j, k in enumerate(kfs):
            self._map.add(k, new_segment=j == 0, scaled=True)
        kf = kfs[-1]
        self._motion.reset(tr.T_world_frame, float(frame.timestamp))
        self._motion.accept(tr, float(frame.timestamp))     # its brightness, no velocity
        self._map.anchor(idx, kf.index, invert_pose(kf.T_world_kf) @ tr.T_world_frame,
                         kf.median_depth)
        return frame_result(frame, idx, tr.T_world_frame, FrameStatus.RELOCALISED, track=tr)

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of a segment with only keyframe 0: tracked against it (no features: no
        depth yet), the :class:`Initialiser`'s decision applied; the segment starts again
        here when none of ``max_lost_frames`` or more frames since tracked (a foreign view)."""
        kf0 = self._map.kfs[self._map.seg_kfs[0]]
        with timed(timings, "track"):
            tr = self._tracked(kf0, frame, features=False)
        if tr.ok:
            self._motion.accept(tr, float(frame.timestamp))
        self._n_lost = 0 if tr.ok else self._n_lost + 1
        dec = self._initialiser.step(frame.image, idx, kf0, tr, self._motion.brightness,
                                     self._map.segment, timings)
        if dec.action == START:
            res1 = self._start_map(frame, idx, kf0, dec, timings)
            if dec.keyframe1 == idx:
                return res1
            self._catch_up(dec.since, timings)      # keyframe 1 is an earlier frame
            return (self._track if self._map.tracking else self._initialise)(
                frame, idx, timings)
        last_good = self._motion.last_good
        self._n_lost += int(dec.action == FAILED)
        never = self._n_lost >= idx - kf0.frame >= self.config.max_lost_frames  # none tracked
        if not tr.ok and never and self._initialiser.solving is None:
            return self._reinitialise(frame, idx, timings, tr, "keyframe 0 never tracked")
        if dec.action == FAILED:
            return frame_result(frame, idx, last_good, FrameStatus.LOST, track=tr)
        if tr.ok:   # waiting for keyframe 1: INIT at the pose tracked against keyframe 0
            self._map.anchor(idx, kf0.index, dec.T_kf0_frame, kf0.keyframe.median_depth)
        return frame_result(frame, idx, tr.T_world_frame if tr.ok else last_good,
                            FrameStatus.INIT if tr.ok else FrameStatus.LOST, track=tr)

    def _start_map(self, frame: Frame, idx: int, kf0: MapKeyframe, dec: InitDecision,
                   timings: Dict[str, float]) -> Optional[FrameResult]:
        """A ``"start"`` decision: keyframe 0 takes the SfM's primitives, the re-tracked
        frames their poses and statuses, and frame ``dec.keyframe1`` (this one, or an earlier
        one solved beside the tracker) becomes keyframe 1; its result (None: no scale)."""
        j = dec.keyframe1
        frame1 = frame if j == idx else Frame(dec.image1, self.camera, self._frames[j].timestamp)
        self._map.replace_keyframe(kf0.index, dec.keyframe0)
        self._map.adopt_retracked(kf0, dec.retracked)
        self._frames.rewrite_retracked(dec.retracked, FrameStatus.INIT)
        good = [kf0.frame] + [r.frame for r in dec.retracked if r.ok]
        self._motion.set_poses(dec.T_world_kf1, dec.T_world_last, float(frame1.timestamp),
                               self._frames[good[-1]].timestamp)
        self._n_lost = 0
        res1 = self._new_keyframe(frame1, j, dec.T_world_kf1, timings, track=dec.track1)
        if j != idx and res1 is not None:     # its returned result rewritten in place
            self._frames[j].rewrite(res1.status, res1.T_world_cam, res1.track, res1.keyframe_index)
        return res1

    def _catch_up(self, since: list, timings: Dict[str, float]) -> None:
        """The frames (``(number, image)``) buffered while keyframe 1 was solved, processed
        again as if it had landed at once (keyframes made, the back end waited for)."""
        with self._port.catching_up():
            for i, image in since:
                self._frames[i].take(self._process(
                    Frame(image, self.camera, self._frames[i].timestamp), i, timings))

    def _tracked(self, kf: MapKeyframe, frame: Frame, features: bool = True) -> TrackResult:
        """``frame`` tracked against ``kf`` from the motion model's guesses and the map's
        landmarks (:meth:`FrameTracker.track`; None before a segment's first update)."""
        return self._tracker.track(kf, frame.image, self._motion.guesses(frame.timestamp),
                                   self._motion.brightness, features, self._map.landmarks)

    def _track(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of an initialised segment: tracked against the latest keyframe
        (or relocalised against an older one), then the keyframe policy's decision."""
        latest = ref = self._map.latest
        with timed(timings, "track"):
            tr = self._tracked(latest, frame)
        if not tr.ok and self._sync(timings):   # lost against the pending map: again after it
            with timed(timings, "track"):
                tr = self._tracked(latest, frame)
        if not tr.ok:
            with timed(timings, "track"):
                tr_old, kf_old = self._tracker.relocalise(
                    self._map.older_in_window(), frame.image, self._motion, self._map.landmarks)
            if tr_old is not None:
                tr, ref = tr_old, kf_old
        if not tr.ok:
            return self._lost(frame, idx, tr, timings)
        was_lost = self._n_lost > 0
        self._n_lost = 0
        self._motion.accept(tr, float(frame.timestamp))
        T_ref_f = invert_pose(ref.keyframe.T_world_kf) @ tr.T_world_frame
        self._map.anchor(idx, ref.index, T_ref_f, ref.keyframe.median_depth)
        status = FrameStatus.RELOCALISED if (was_lost or ref is not latest) else FrameStatus.OK
        decision = self._policy.decide(tr, T_ref_f, ref, latest)
        res = None
        if decision == AFTER_UPDATE:
            tr, T_ref_f, res = self._redecided(frame, idx, tr, timings)
        elif decision == KEYFRAME:
            res = self._new_keyframe(frame, idx, tr.T_world_frame, timings, track=tr)
        if res is not None:
            return res
        if ref is latest:
            self._map.add_candidate(SupportCandidate(idx, np.asarray(frame.image), T_ref_f,
                                                     np.asarray(tr.brightness, float)))
        return frame_result(frame, idx, tr.T_world_frame, status, track=tr)

    def _lost(self, frame: Frame, idx: int, tr: TrackResult,
              timings: Dict[str, float]) -> FrameResult:
        """A frame not tracked: ``LOST`` at the last good pose, or after
        ``max_lost_frames`` the map re-initialised (:meth:`_reinitialise`)."""
        self._n_lost += 1
        log.info("frame %d lost (%s)", idx, tr.reason)
        if self._n_lost < self.config.max_lost_frames:
            return frame_result(frame, idx, self._motion.last_good, FrameStatus.LOST, track=tr)
        return self._reinitialise(frame, idx, timings, tr, f"{self._n_lost} frames lost")

    def _reinitialise(self, frame: Frame, idx: int, timings: Dict[str, float],
                      tr: TrackResult, why: str) -> FrameResult:
        """A new map segment from this frame at the last good pose (a featureless
        frame stays lost)."""
        log.warning("frame %d: %s; re-initialising the map", idx, why)
        if featureless(frame.image):
            return frame_result(frame, idx, self._motion.last_good, FrameStatus.LOST, track=tr)
        self._sync(timings)
        med = self._map.latest.keyframe.median_depth
        self._map.begin_segment()
        self._port.restart()
        return self._start(frame, idx, self._motion.last_good.copy(), timings, median_depth=med)

    def _new_keyframe(self, frame: Frame, idx: int, T_world: np.ndarray,
                      timings: Dict[str, float], track: Optional[TrackResult],
                      prims: Optional[PrimitiveSet] = None) -> Optional[FrameResult]:
        """Make frame ``idx`` (at ``T_world``) a keyframe (:class:`KeyframeBuilder`;
        ``prims``: its primitives, already made) and send its job to the port, on
        the map updated first (the frame's pose moved with the keyframe it was
        tracked against).  None when the render gives no scale."""
        if self._sync(timings) and idx in self._map.anchors:
            T_world = nearest_rigid(self._map.frame_pose(*self._map.anchors[idx]))
        k = self._map.next_index
        made = self._builder.rendered(frame, idx, k, T_world, self._map.window_kfs(), timings,
                                    prims=prims)
        if made is None:
            return None
        keyframe, weights = made
        self._map.add(MapKeyframe(k, idx, np.asarray(frame.image), keyframe, self._map.segment,
                                  prior_weights=weights))
        self._port.send(self._map.window_kfs(extra=1), self._map.take_candidates(),
                        self._map.segment, self._frames.steps)
        self._motion.brightness = np.zeros(2)    # the next frames: relative to keyframe k
        if self._port.due(self._frames.steps):
            self._sync(timings)
        return frame_result(frame, idx, self._map.kfs[k].keyframe.T_world_kf,
                            FrameStatus.KEYFRAME, keyframe_index=k, track=track)

    def _redecided(self, frame: Frame, idx: int, tr: TrackResult, timings: Dict[str, float]
                   ) -> Tuple[TrackResult, np.ndarray, Optional[FrameResult]]:
        """A keyframe wanted before the latest keyframe's update (design.md §5.1):
        primitives made, update applied, tracked again from its pose moved with the
        update and decided again (:meth:`KeyframePolicy.crosses`).  Returns
        ``(track result, T_latest_frame, keyframe FrameResult or None)``."""
        latest = self._map.latest
        with timed(timings, "frontend"):
            prims = self._builder.primify(frame)
        self._sync(timings)
        T_ref_f = self._map.relative_pose(*self._map.anchors[idx])    # moved with the update
        with timed(timings, "track"):
            tr2 = self._tracker.track(latest, frame.image, [lambda: latest.keyframe.T_world_kf
                                                            @ T_ref_f], tr.brightness)
        if tr2.ok:
            tr = tr2
            self._motion.replace_last(tr)
            T_ref_f = invert_pose(latest.keyframe.T_world_kf) @ tr.T_world_frame
        self._map.anchor(idx, latest.index, T_ref_f, latest.keyframe.median_depth)
        if not self._policy.crosses(tr, T_ref_f, latest):
            return tr, T_ref_f, None
        T_world = nearest_rigid(latest.keyframe.T_world_kf @ T_ref_f)
        return tr, T_ref_f, self._new_keyframe(frame, idx, T_world, timings, tr, prims=prims)
