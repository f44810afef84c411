"""The mapping port (docs/design.md §5.1): how :class:`spgeo.vo.Odometry` hands a new
keyframe's back end (:class:`~spgeo.vo.backend.WindowBackend`: landmarks, loop closure,
the window smoother) its job, and when the update comes back to the map.

One protocol wherever the back end runs: :meth:`MappingPort.send` makes a
:class:`~spgeo.vo.backend.MappingJob` of the window (copies of the keyframes the back
end has not seen), :meth:`MappingPort.apply_pending` receives the
:class:`~spgeo.vo.backend.MappingUpdate` and applies it, the one way every update is
applied: to the caller's map (:meth:`spgeo.vo.map.KeyframeMap.apply_update`) and
motion model, telling itself which keyframes now equal the back end's.  The back end
keeps its own copies of the window, so the caller's keyframes change only when it
applies an update.

* :class:`InProcessPort` (``OdometryConfig.mapping.mode="inline"``): the back end in this
  process, run when the update is received.
* :class:`WorkerPort` (``"live"``): the back end in the mapping worker process
  (:mod:`spgeo.vo.mapping_worker`), solving while the next frames are tracked.

The schedule (:meth:`MappingPort.due`).  With ``OdometryConfig.mapping.schedule=
"fixed"`` (recorded input) an update is applied before the frame that is ``lead``
frames after its keyframe (``mode="inline"``: ``lead`` 0, i.e. before the next
frame), waited for when it is not ready, so the trajectory is the same on any
machine under any load; a keyframe wanted while an update is pending applies it
first (waiting).  With ``"ready"`` (a live camera, whose input already depends on
timing) the tracker never waits for the back end: an update is applied at the first
frame that finds it ready, whatever the lead, and a keyframe wanted while it is not
ready is deferred (:class:`~spgeo.vo.keyframe_policy.KeyframePolicy`,
:meth:`MappingPort.update_available`): the frame stays tracked
against the latest keyframe, and a later frame makes the keyframe.  In both
schedules a frame lost against the pending map, a new segment, or a call that reads
the map applies the update, waiting for it.
"""
from __future__ import annotations

import contextlib
import dataclasses
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose
from ..similarity import sim3
from .backend import MappingJob, MappingUpdate, WindowBackend
from .config import OdometryConfig
from .initialisation import InitJob, InitSolution
from .map import KeyframeMap, MapKeyframe, SupportCandidate
from .mapping_worker import MappingWorker
from .motion import MotionChange, MotionModel
from .result import FrameLog, add_seconds
from .smoother import adopt_selection, choose_support
from .tracking import Keyframe

__all__ = ["MappingPort", "InProcessPort", "WorkerPort", "PendingJob", "MappingRecord",
           "make_port", "apply_pending_update"]


@dataclass(frozen=True)
class PendingJob:
    """The job in flight: its keyframe ``keyframe`` with that keyframe's
    ``T_world_kf`` and median depth when sent, and ``n_frames`` processed then (the
    keyframe's frame number)."""

    keyframe: int
    T_world_kf: np.ndarray
    median_depth: float
    n_frames: int


@dataclass
class MappingRecord:
    """What the port did (one :class:`~spgeo.vo.Odometry`).

    Attributes:
        pending: the :class:`PendingJob` in flight, or None.
        reset_next: the next job restarts the smoother (a new segment).
        older_map_frames: frames tracked while an update was pending.
        deferred_keyframes: keyframe decisions deferred because the update was not
            ready (``"ready"`` schedule).
        latencies: per applied update, the frames processed between sending the
            job and applying its update.
        reports: the mapper's report entries, in order.
        landmarks: the latest landmark report (None without landmarks).
        loops: the loop closer's latest report (None without loop closure).
        seconds: the back end's seconds per stage.
        peak_rss_mib: the back end's process's peak resident memory (MiB), as last reported.
    """

    pending: Optional[PendingJob] = None
    reset_next: bool = False
    older_map_frames: int = 0
    deferred_keyframes: int = 0
    latencies: List[int] = field(default_factory=list)
    reports: List[dict] = field(default_factory=list)
    landmarks: Optional[dict] = None
    loops: Optional[dict] = None
    seconds: Dict[str, float] = field(default_factory=dict)
    peak_rss_mib: Optional[float] = None

    def lead(self, n_frames: int) -> int:
        """Frames processed since the pending job was sent, when ``n_frames``
        have been (0 when none is pending)."""
        return 0 if self.pending is None else n_frames - self.pending.n_frames

    def record(self, upd: MappingUpdate, latency: int) -> None:
        """An applied update, ``latency`` frames after its job was sent."""
        self.pending = None
        self.latencies.append(int(latency))
        self.reports.extend(upd.reports)
        self.landmarks, self.loops = upd.landmarks, upd.loops
        self.peak_rss_mib = upd.peak_rss_mib
        for key, sec in upd.timings.items():
            self.seconds[key] = self.seconds.get(key, 0.0) + float(sec)

    def defer_keyframe(self) -> None:
        """A keyframe decision deferred (:class:`~spgeo.vo.keyframe_policy.KeyframePolicy`)."""
        self.deferred_keyframes += 1

    def report(self) -> dict:
        """JSON-ready: updates applied, frames tracked against an older map,
        latency in frames (mean, max) and the back end's seconds per stage."""
        lat = self.latencies
        return {"updates": len(lat), "frames_tracked_against_older_map": self.older_map_frames,
                "keyframes_deferred": self.deferred_keyframes,
                "latency_frames_mean": float(np.mean(lat)) if lat else None,
                "latency_frames_max": int(max(lat)) if lat else None,
                "worker_seconds": dict(self.seconds),
                "worker_peak_rss_mib": self.peak_rss_mib}


class MappingPort:
    """The protocol (module docstring); :class:`InProcessPort` and
    :class:`WorkerPort` say where the back end runs.

    Args:
        config: the run's :class:`OdometryConfig`.
        lead: frames after its keyframe at which an update is applied (>= 0).
        schedule: ``"fixed"`` or ``"ready"`` (module docstring).

    Attributes:
        record: the :class:`MappingRecord`.
    """

    def __init__(self, config: OdometryConfig, lead: int, schedule: str) -> None:
        self.config, self.lead, self.schedule = config, int(lead), schedule
        self.record = MappingRecord()
        self._sent: Dict[int, Keyframe] = {}
        self._catching_up = False

    # ------------------------------------------------------------ protocol
    @property
    def pending(self) -> bool:
        """Whether an update is in flight."""
        return self.record.pending is not None

    def send(self, window: Sequence[MapKeyframe], candidates: Sequence[SupportCandidate],
             segment: int, n_frames: int) -> None:
        """Send the job of ``window`` (the segment's window and the keyframe
        leaving it, oldest first; the new keyframe last, made at frame
        ``n_frames``) with the previous keyframe's supporting-frame
        ``candidates``: the keyframes whose :class:`Keyframe` the back end has not
        seen go as copies (without cached mapping pixels).  Raises
        ``RuntimeError`` when an update is still pending (one at a time)."""
        if self.pending:
            raise RuntimeError("MappingPort.send: an update is still pending (apply it first)")
        for kf in window:
            adopt_selection(kf, self.config)
        send = [dataclasses.replace(kf, map_pixels=None) for kf in window
                if self._sent.get(kf.index) is not kf.keyframe]
        self._sent = {kf.index: kf.keyframe for kf in window}
        chosen = choose_support(candidates, self.config.n_support)   # the mapper's choice
        job = MappingJob([kf.index for kf in window], send, chosen, segment,
                         self.record.reset_next)
        self._submit(job)
        self.record.reset_next = False
        new = window[-1].keyframe
        self.record.pending = PendingJob(window[-1].index, new.T_world_kf.copy(),
                                         float(new.median_depth), int(n_frames))

    def restart(self) -> None:
        """The next job restarts the smoother (a new map segment)."""
        self.record.reset_next = True

    def due(self, n_frames: int) -> bool:
        """Whether the pending update is to be applied before frame ``n_frames``
        (module docstring)."""
        if not self.pending:
            return False
        if self.schedule == "ready":
            return self._ready()
        return self.record.lead(n_frames) >= self.lead

    def update_available(self) -> bool:
        """Whether the schedule lets a keyframe wanted now wait for the pending
        update (module docstring): on ``"fixed"`` always (it is waited for), on
        ``"ready"`` only when it is ready (the tracker never waits); the
        :class:`~spgeo.vo.keyframe_policy.KeyframePolicy` defers the keyframe
        otherwise; always while :meth:`catching_up`."""
        return self.schedule != "ready" or self._catching_up or self._ready()

    @contextlib.contextmanager
    def catching_up(self):
        """Within: the frames of a late keyframe 1 processed again (``Odometry``),
        on either schedule a keyframe wanted while an update is pending waits for
        it, as on ``"fixed"``: the frames caught up make the keyframes they would
        have made had the keyframe-1 solve landed at once."""
        self._catching_up = True
        try:
            yield
        finally:
            self._catching_up = False

    def defer_keyframe(self) -> None:
        """A keyframe decision deferred (:meth:`MappingRecord.defer_keyframe`)."""
        self.record.defer_keyframe()

    def note_frame(self) -> None:
        """A frame is tracked now (counted when an update is pending)."""
        if self.pending:
            self.record.older_map_frames += 1

    def receive(self, n_frames: int) -> Tuple[MappingUpdate, PendingJob, Dict[str, float]]:
        """The pending update (waits for it), recorded as applied when
        ``n_frames`` have been processed: ``(update, its PendingJob, seconds it
        cost the caller's thread per stage)``."""
        job = self.record.pending
        upd, seconds = self._receive()
        self.record.record(upd, n_frames - job.n_frames)
        return upd, job, seconds

    def apply_pending(self, kmap: KeyframeMap, n_frames: int
                      ) -> Tuple[Dict[str, float], MotionChange]:
        """The one apply of the pending update (:meth:`receive`, waiting for it),
        when ``n_frames`` have been processed: the map's part
        (:meth:`KeyframeMap.apply_update`), :meth:`synced` for the keyframes that
        now equal the back end's.  With no frame tracked since the job was sent
        the motion model restarts at the new keyframe's smoothed pose; else what
        was tracked meanwhile (motion, candidates) moves with the new keyframe's
        similarity (:meth:`KeyframeMap.apply_similarity`).  Returns the seconds it
        cost the caller's thread per stage and the caller's
        :class:`~spgeo.vo.motion.MotionChange`."""
        upd, job, seconds = self.receive(n_frames)
        tracked_since = n_frames > job.n_frames
        changed, W_loop = kmap.apply_update(upd, self.config.primitive_model,
                                            not tracked_since)
        for j, kf in changed.items():
            self.synced(j, kf)
        new = kmap.kfs[job.keyframe]
        if not tracked_since:
            return seconds, MotionChange([] if W_loop is None else [W_loop], new.T_world_kf)
        s = new.median_depth / job.median_depth
        W = sim3(new.T_world_kf[:3, :3], new.T_world_kf[:3, 3], s) @ invert_pose(job.T_world_kf)
        W_new = kmap.apply_similarity({job.keyframe: W}, s)
        return seconds, MotionChange([w for w in (W_loop, W_new) if w is not None])

    def synced(self, k: int, keyframe: Keyframe) -> None:
        """Keyframe ``k``'s :class:`Keyframe` is now ``keyframe``, equal to the
        back end's copy (an update applied)."""
        self._sent[k] = keyframe

    # ------------------------------------------------------------ initialisation
    def solve_init(self, job: InitJob) -> Optional[InitSolution]:
        """The keyframe-1 solve of a map's initialisation
        (:class:`~spgeo.vo.initialisation.Initialiser`'s solver).  On the
        ``"fixed"`` schedule it runs here, now, and its solution is returned; on
        the ``"ready"`` schedule it is sent where the back end runs (with
        ``ahead``: keyframe 0 solved and the buffer re-tracked there too) and
        None is returned: :meth:`init_result` gives it to a later frame, and the
        tracker goes on meanwhile."""
        if self.schedule != "ready":
            return job.run()
        self._submit_init(dataclasses.replace(job, ahead=True))
        return None

    def init_result(self) -> Optional[InitSolution]:
        """The solution of the solve sent by :meth:`solve_init`, or None while
        it is not ready."""
        return self._init_result()

    def _submit_init(self, job: InitJob) -> None:
        raise NotImplementedError

    def _init_result(self) -> Optional[InitSolution]:
        raise NotImplementedError

    # ------------------------------------------------------------ place
    @property
    def backend(self) -> WindowBackend:
        """The :class:`WindowBackend` (in this process only; else ``RuntimeError``)."""
        raise RuntimeError("the window smoother is in the mapping worker process "
                           "(OdometryConfig.mapping.mode='live'); use mode='inline' to reach it")

    def report(self) -> dict:
        """Entries of :meth:`spgeo.vo.Odometry.report` that only this port has."""
        return {}

    def close(self) -> None:
        """Stop the back end's process, if any; a pending update is dropped (the
        map stays as it is and readable); idempotent."""
        self._close()
        self.record.pending = None

    def _close(self) -> None:
        """Stop what runs the back end (nothing in this process)."""

    def _submit(self, job: MappingJob) -> None:
        raise NotImplementedError

    def _ready(self) -> bool:
        raise NotImplementedError

    def _receive(self) -> Tuple[MappingUpdate, Dict[str, float]]:
        raise NotImplementedError


class InProcessPort(MappingPort):
    """The back end in this process, run when its update is received (its
    stages' seconds are the caller's).  Default ``lead`` 0: the update before
    the next frame (``OdometryConfig.mapping.mode="inline"``)."""

    def __init__(self, camera: PinholeCamera, config: OdometryConfig, lead: int = 0,
                 schedule: str = "fixed") -> None:
        super().__init__(config, lead, schedule)
        self._backend = WindowBackend(camera, config)
        self._job: Optional[MappingJob] = None
        self._init_job: Optional[InitJob] = None

    @property
    def backend(self) -> WindowBackend:
        return self._backend

    def _submit(self, job: MappingJob) -> None:
        self._job = job

    def _ready(self) -> bool:
        return True

    def _receive(self) -> Tuple[MappingUpdate, Dict[str, float]]:
        job, self._job = self._job, None
        upd = self._backend.run(job)
        return upd, dict(upd.timings)

    def _submit_init(self, job: InitJob) -> None:
        self._init_job = job

    def _init_result(self) -> Optional[InitSolution]:
        job, self._init_job = self._init_job, None
        return None if job is None else job.run()


class WorkerPort(MappingPort):
    """The back end in the mapping worker process
    (:class:`~spgeo.vo.mapping_worker.MappingWorker`); the caller's thread pays
    only the wait for an update that is not ready (``"mapping"`` seconds)."""

    def __init__(self, camera: PinholeCamera, config: OdometryConfig, lead: int,
                 schedule: str) -> None:
        super().__init__(config, lead, schedule)
        self.worker = MappingWorker(camera, config)

    def report(self) -> dict:
        return {"mapping_worker": self.record.report()}

    def _close(self) -> None:
        self.worker.close()

    def _submit(self, job: MappingJob) -> None:
        self.worker.submit(job)

    def _ready(self) -> bool:
        return self.worker.ready()

    def _receive(self) -> Tuple[MappingUpdate, Dict[str, float]]:
        t = time.perf_counter()
        upd = self.worker.receive()
        return upd, {"mapping": time.perf_counter() - t}

    def _submit_init(self, job: InitJob) -> None:
        self.worker.submit(job)

    def _init_result(self) -> Optional[InitSolution]:
        return self.worker.receive() if self.worker.ready() else None


def make_port(camera: PinholeCamera, config: OdometryConfig, wait: bool = False) -> MappingPort:
    """The port of ``config.mapping.mode`` (module docstring): ``"inline"`` an
    :class:`InProcessPort` (lead 0), ``"live"`` a :class:`WorkerPort` with
    ``config.mapping.lead`` and ``config.mapping.schedule`` (``wait``: lead 0,
    the inline numbers through the worker)."""
    if config.mapping.mode == "inline":
        return InProcessPort(camera, config)
    lead = 0 if wait else config.mapping.lead
    return WorkerPort(camera, config, lead, config.mapping.schedule)


def apply_pending_update(port: MappingPort, kmap: KeyframeMap, motion: MotionModel,
                         frames: FrameLog, timings: Optional[Dict[str, float]] = None) -> bool:
    """A VO's one apply of ``port``'s pending update, waiting for it: the map's part and
    the port's (:meth:`MappingPort.apply_pending`, ``frames.steps`` frames processed:
    :class:`~spgeo.vo.result.FrameLog`),
    then ``motion`` follows (:meth:`MotionModel.follow`); the seconds it cost this thread
    are added to ``timings``.  Returns whether an update was applied.
    :class:`spgeo.vo.Odometry` and its read side call it through a
    ``functools.partial`` of the odometry's parts (no reference back to the odometry)."""
    if not port.pending:
        return False
    seconds, change = port.apply_pending(kmap, frames.steps)
    motion.follow(change)
    add_seconds({} if timings is None else timings, seconds)
    return True
