"""Keyframe-based monocular visual odometry on SuperPrimitives (docs/design.md §5):
the per-frame state machine (initialise, track, lose, re-initialise).

One call per frame (:meth:`Odometry.track`); the states and their rules are stated
in docs/design.md §5.1, options are :class:`~spgeo.vo.config.OdometryConfig`'s.
``Odometry`` drives them over the objects that own the state: the keyframe map
(:class:`spgeo.vo.map.KeyframeMap`), the frame tracker
(:class:`spgeo.vo.frame_tracker.FrameTracker`: the motion model's guesses, the
retries, relocalisation, the keyframe decision), the initialiser
(:class:`spgeo.vo.initialisation.Initialiser`, whose
:class:`~spgeo.vo.initialisation.InitDecision` ``Odometry`` applies), the keyframe
maker (:class:`spgeo.vo.keyframing.KeyframeMaker`) and the mapping port
(:mod:`spgeo.vo.mapping_port`: where and when a new keyframe's back end runs).

Ablations: ``OdometryConfig.primitive_model`` (docs/design.md §5); oracle normals:
the ``"depth"`` front-end.
"""
from __future__ import annotations

import logging
import time
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from ..primitives import PrimitiveSet
from ..frontend import PrimitiveFrontEnd
from ..geometry import invert_pose, nearest_rigid
from ..validation import check_camera
from .config import OdometryConfig
from .initialisation import FAILED, START, InitDecision, Initialiser
from .keyframe_store import KeyframeStore
from .frame_tracker import FrameTracker
from .keyframing import KeyframeMaker
from .map import KeyframeMap, MapKeyframe, SupportCandidate
from .mapping_port import MappingPort, make_port
from .processing import checked_frame, opencv_threads
from .readout import OdometryReadout
from .result import FrameResult, FrameStatus, add_seconds, frame_result, timed
from .tracking import TrackResult, track_frame

__all__ = ["Odometry", "MAX_LEAD_FRAMES"]

#: the default of ``OdometryConfig.mapping_lead`` (its name before the mapping port)
MAX_LEAD_FRAMES = OdometryConfig.mapping_lead

log = logging.getLogger(__name__)


class Odometry(OdometryReadout):
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
        wait_for_mapper: with live mapping, apply each update before the next
            frame (lead 0): the numbers of ``"inline"`` mapping, through the
            worker (its tests).
        port: the :class:`~spgeo.vo.mapping_port.MappingPort` (default None: the
            one of ``config.mapping``, :func:`~spgeo.vo.mapping_port.make_port`).

    Mapping: docs/design.md §5.1, *The mapping port*; reads apply the pending
    update first; :meth:`close` (or ``with``) stops a worker.  Memory: after a frame
    only its :class:`FrameResult` and anchor stay; keyframes outside the window are
    retired to the store (:meth:`spgeo.vo.map.MapKeyframe.retire`).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig = OdometryConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None,
                 store: Optional[KeyframeStore] = None,
                 wait_for_mapper: bool = False, port: Optional[MappingPort] = None) -> None:
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
        self._n_lost = 0
        self._port = port if port is not None else make_port(self.camera, config,
                                                              wait_for_mapper)
        self._initialiser = Initialiser(config, self.camera, frontend.uses_depth,
                                        solver=self._port)
        self._maker = KeyframeMaker(self.camera, config, frontend)

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
        and ``T_world_cam`` rewritten once, in place, by the call that creates
        keyframe 1: re-tracked against the solved keyframe 0 (``INIT`` or
        ``LOST``); on the ``"ready"`` schedule keyframe 1 may be such an earlier
        frame (``KEYFRAME``), and the frames after it are re-tracked against it
        (``OK`` or ``LOST``).  The trajectory's authority is
        :meth:`result` (it follows the map's smoothed poses and scales).

        Raises:
            TypeError: ``frame`` is not a :class:`~spgeo.frame.Frame`.
            InputError: (a ``ValueError``) the image's (H, W) is neither the input
                camera's nor the processing camera's, the frame's camera is not that
                camera, the image holds NaN / inf, or the timestamp is not finite or
                not strictly after the previous frame's (seconds, or frame numbers
                for data without time); the frame is not processed (checked_frame).
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
        if self._port.due(idx):
            self._sync(timings)
        self._port.note_frame()
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

    def close(self) -> None:
        """Stop the mapping worker, if any (a pending update is dropped: call
        :meth:`result` first to keep it); idempotent."""
        self._port.close()

    def __enter__(self) -> "Odometry":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ stages
    def _start(self, frame: Frame, idx: int, T_world: np.ndarray,
               timings: Dict[str, float], median_depth: Optional[float] = None) -> FrameResult:
        """Keyframe 0 of a map segment at ``T_world``."""
        kf = self._maker.first(frame, T_world, timings, median_depth)
        k = self._map.next_index
        self._map.add(MapKeyframe(k, idx, np.asarray(frame.image), kf, self._map.segment),
                      new_segment=True)
        self._map.retire_outside_window()
        self._map.take_candidates()
        self._initialiser.reset()
        self._motion.reset(T_world, float(frame.timestamp))
        self._n_lost = 0
        status = FrameStatus.KEYFRAME if idx == 0 else FrameStatus.REINIT
        return frame_result(frame, idx, T_world, status, keyframe_index=k)

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of a segment with only keyframe 0: tracked against it, then
        the :class:`Initialiser`'s decision applied."""
        kf0 = self._map.kfs[self._map.seg_kfs[0]]
        with timed(timings, "track"):
            tr = self._tracker.track(kf0.keyframe, frame.image, timestamp=frame.timestamp)
        if tr.ok:
            self._motion.accept(tr, float(frame.timestamp))
        self._n_lost = 0 if tr.ok else self._n_lost + 1
        dec = self._initialiser.step(frame.image, idx, kf0, tr, self._motion.brightness,
                                     self._map.segment, timings)
        if dec.action == START:
            return self._start_map(frame, idx, kf0, dec, timings)
        last_good = self._motion.last_good
        if dec.action == FAILED:
            self._n_lost += 1
            return frame_result(frame, idx, last_good, FrameStatus.LOST, track=tr)
        if tr.ok:   # waiting for keyframe 1: INIT at the pose tracked against keyframe 0
            self._map.anchor(idx, kf0.index, dec.T_kf0_frame, kf0.keyframe.median_depth)
        return frame_result(frame, idx, tr.T_world_frame if tr.ok else last_good,
                            FrameStatus.INIT if tr.ok else FrameStatus.LOST, track=tr)

    def _start_map(self, frame: Frame, idx: int, kf0: MapKeyframe, dec: InitDecision,
                   timings: Dict[str, float]) -> FrameResult:
        """A ``"start"`` decision: keyframe 0 takes the SfM's primitives, the
        re-tracked frames their poses and statuses, this frame is keyframe 1; or
        (solved beside the tracker) an earlier frame is, rewritten in place, the
        frames after it are tracked again against it (``OK``, else left ``INIT``)
        and this frame is tracked against it."""
        j = dec.keyframe1
        frame1 = frame if j == idx else Frame(dec.image1, self.camera, self._frames[j].timestamp)
        self._map.replace_keyframe(kf0.index, dec.keyframe0)
        self._map.adopt_retracked(kf0, dec.retracked, self._frames)
        good = [kf0.frame] + [r.frame for r in dec.retracked if r.ok]
        t_last = self._frames[good[-1]].timestamp
        self._motion.set_poses(dec.T_world_kf1, dec.T_world_last, float(frame1.timestamp), t_last)
        self._n_lost = 0
        res1 = self._new_keyframe(frame1, j, dec.T_world_kf1, timings, track=dec.track1)
        if j == idx:
            return res1
        if res1 is not None:
            self._frames[j].rewrite(res1.status, res1.T_world_cam, res1.track, res1.keyframe_index)
        with timed(timings, "init"):
            since = self._tracker.retrack(self._map.latest, [(i, image, self._frames[i].timestamp)
                                                             for i, image in dec.since])
        self._map.adopt_retracked(self._map.latest, [r for r in since if r.ok], self._frames,
                                  FrameStatus.OK)
        return self._track(frame, idx, timings)

    def _track(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        """A frame of an initialised segment: tracked against the latest keyframe
        (or relocalised against an older one), then the keyframe decision."""
        latest = ref = self._map.latest
        t = time.perf_counter()
        tr = self._tracker.track(latest.keyframe, frame.image, latest, frame.timestamp)
        if not tr.ok and self._port.pending:
            # lost against the pending map: tracked again after the update (a wait of mapping's)
            tracked = time.perf_counter() - t
            self._sync(timings)
            t = time.perf_counter() - tracked
            tr = self._tracker.track(latest.keyframe, frame.image, latest, frame.timestamp)
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
        self._motion.accept(tr, float(frame.timestamp))
        T_ref_f = invert_pose(ref.keyframe.T_world_kf) @ tr.T_world_frame
        self._map.anchor(idx, ref.index, T_ref_f, ref.keyframe.median_depth)
        status = FrameStatus.RELOCALISED if (was_lost or relocalised) else FrameStatus.OK
        # tracked against an older keyframe: make it a keyframe to re-anchor the map
        if ((ref is not latest or self._tracker.wants_keyframe(tr, T_ref_f, latest))
                and not self._port.defers_keyframe()):
            if ref is latest and self._port.pending:
                tr, T_ref_f, res = self._redecided(frame, idx, tr, timings)
            else:
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
        ``max_lost_frames`` the map re-initialised (not from a featureless
        frame: it stays lost and the next frame tries again)."""
        self._n_lost += 1
        log.info("frame %d lost (%s)", idx, tr.reason)
        if self._n_lost < self.config.max_lost_frames:
            return frame_result(frame, idx, self._motion.last_good, FrameStatus.LOST, track=tr)
        log.warning("frame %d: %d frames lost; re-initialising the map", idx, self._n_lost)
        grey = np.asarray(frame.image, dtype=np.float64)
        if float(np.std(grey)) < 1e-3 * max(float(np.max(np.abs(grey))), 1.0):
            return frame_result(frame, idx, self._motion.last_good, FrameStatus.LOST)
        self._sync(timings)
        med = self._map.latest.keyframe.median_depth
        self._map.begin_segment()
        self._port.restart()
        return self._start(frame, idx, self._motion.last_good.copy(), timings, median_depth=med)

    def _new_keyframe(self, frame: Frame, idx: int, T_world: np.ndarray,
                      timings: Dict[str, float], track: Optional[TrackResult],
                      prims: Optional[PrimitiveSet] = None) -> Optional[FrameResult]:
        """Make frame ``idx`` (at ``T_world``) a keyframe (:class:`KeyframeMaker`;
        ``prims``: its primitives, already made) and send its job to the port, on
        the map updated first (the frame's pose moved with the keyframe it was
        tracked against).  None when the render gives no scale."""
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
        self._port.send(self._map.window_kfs(extra=1), self._map.take_candidates(),
                        self._map.segment, len(self._frames))
        self._motion.brightness = np.zeros(2)    # the next frames: relative to keyframe k
        if self._port.due(len(self._frames)):
            self._sync(timings)
        return frame_result(frame, idx, self._map.kfs[k].keyframe.T_world_kf,
                            FrameStatus.KEYFRAME, keyframe_index=k, track=track)

    def _redecided(self, frame: Frame, idx: int, tr: TrackResult, timings: Dict[str, float]
                   ) -> Tuple[TrackResult, np.ndarray, Optional[FrameResult]]:
        """A keyframe wanted before the latest keyframe's update (design.md §5.1):
        primitives made, update applied, tracked and decided again.  Returns
        ``(track result, T_latest_frame, keyframe FrameResult or None)``."""
        latest = self._map.latest
        with timed(timings, "frontend"):
            prims = self._maker.primify(frame)
        ref, _, median_then = self._map.anchors[idx]
        self._sync(timings)
        T0 = self._map.frame_pose(*self._map.anchors[idx])    # moved with the update
        with timed(timings, "track"):
            tr2 = track_frame(latest.keyframe, frame.image, T0, tr.brightness, self.config.tracker)
        if tr2.ok:
            tr = tr2
            self._motion.replace_last(tr)
            T_ref_f = invert_pose(latest.keyframe.T_world_kf) @ tr.T_world_frame
        else:
            T_ref_f = self._map.anchors[idx][1].copy()
            T_ref_f[:3, 3] *= latest.keyframe.median_depth / median_then
        self._map.anchor(idx, ref, T_ref_f, latest.keyframe.median_depth)
        if not self._tracker.wants_keyframe(tr, T_ref_f, latest):
            return tr, T_ref_f, None
        T_world = nearest_rigid(latest.keyframe.T_world_kf @ T_ref_f)
        return tr, T_ref_f, self._new_keyframe(frame, idx, T_world, timings, tr, prims=prims)

    def _sync(self, timings: Optional[Dict[str, float]] = None) -> bool:
        """Apply the pending update to the map and the motion model, waiting for it
        (:meth:`MappingPort.apply_pending`); the seconds it cost this thread go to
        ``timings``.  Returns whether an update was applied."""
        if not self._port.pending:
            return False
        seconds = self._port.apply_pending(self._map, self._motion, len(self._frames))
        add_seconds({} if timings is None else timings, seconds)
        return True
