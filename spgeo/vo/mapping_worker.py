"""The mapping worker: the VO's back end (:class:`~spgeo.vo.backend.WindowBackend`:
landmarks and the window smoother) in a second process, so that tracking goes on
while the window is solved (docs/design.md §5.1, *Mapping off the tracking path*).

Why a process and not a thread: GTSAM's Python wrapper holds the interpreter lock
for the whole smoother update (``python scripts/gil_during_solve.py``; docs/history.md,
issue 32), so a mapper thread would only take turns with the tracker.

Protocol (one update in flight at a time):

* :meth:`MappingWorker.submit` sends a :class:`MappingJob`: the segment's window
  (keyframe indices, oldest first), the keyframes whose current state the worker
  has not seen (in practice the new keyframe, pickled without its derived data,
  :meth:`Keyframe.__getstate__ <spgeo.vo.tracking.Keyframe.__getstate__>`), the
  supporting frames the mapper will use, the segment and whether the smoother
  restarts.
* The worker keeps its own copies of the window's keyframes, runs the back end on
  them and answers a :class:`MappingUpdate`: each refreshed keyframe's pose and
  shape values, the supporting frames' poses, whether the window restarted, the
  mapper's report and the back end's seconds.
* The caller applies the update to its keyframes with the same
  :func:`~spgeo.vo.keyframe.with_shape_values` and tells :meth:`MappingWorker.synced`
  which :class:`~spgeo.vo.tracking.Keyframe` objects now equal the worker's.

Both copies then hold equal numbers: a caller that waits for every update before
the next frame computes what the inline back end computes, bit for bit
(tests/test_mapping_worker.py).  The worker is a fresh interpreter
(``python -c``, the parent's ``sys.path``; no fork of a threaded parent, and unlike
``multiprocessing``'s ``spawn`` it does not import the caller's main script), talking
over two pipes with :class:`multiprocessing.connection.Connection` (pickle).
"""
from __future__ import annotations

import dataclasses
import logging
import os
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from .config import OdometryConfig
from .map import MapKeyframe, SupportCandidate
from .smoother import choose_support
from .tracking import Keyframe

__all__ = ["MappingJob", "MappingUpdate", "MappingWorker", "MappingWorkerError", "LiveMapping"]

log = logging.getLogger(__name__)

#: seconds a closing worker is given to finish before it is terminated
CLOSE_TIMEOUT = 5.0


class MappingWorkerError(RuntimeError):
    """The mapping worker failed (its traceback in the message) or died."""


@dataclass
class MappingJob:
    """One back-end update (module docstring).

    Attributes:
        window: keyframe indices of the segment's window and the keyframe leaving
            it, oldest first (the newest is the new keyframe).
        keyframes: the window keyframes whose state the worker lacks (copies
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
    """The worker's answer to a :class:`MappingJob`.

    Attributes:
        keyframes: keyframe index -> ``(T_world_kf, shape values)`` written by the
            smoother (:attr:`spgeo.vo.smoother.WindowMapper.refreshed`).
        support_pose: frame number -> smoothed ``T_world_frame`` of supporting frames.
        restarted: the window restarted from its last two keyframes.
        reports: the mapper's new report entries.
        timings: the back end's seconds (``landmarks``, ``mapping``).
        landmarks: the landmark map's report after the update (None without).
        peak_rss_mib: the worker's peak resident memory so far (MiB; None
            where ``/proc`` is absent).
    """

    keyframes: Dict[int, Tuple[np.ndarray, np.ndarray]]
    support_pose: Dict[int, np.ndarray]
    restarted: bool
    reports: List[dict] = field(default_factory=list)
    timings: Dict[str, float] = field(default_factory=dict)
    landmarks: Optional[dict] = None
    peak_rss_mib: Optional[float] = None


def _peak_rss_mib() -> Optional[float]:
    """This process's peak resident set size, MiB: ``VmHWM`` of
    ``/proc/self/status`` (not ``ru_maxrss``, which keeps the forked parent's
    peak across ``exec``); None where it cannot be read."""
    try:
        with open("/proc/self/status", "rb") as fh:
            for line in fh:
                if line.startswith(b"VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def run_job(backend, copies: Dict[int, MapKeyframe], job: MappingJob) -> MappingUpdate:
    """Apply ``job`` to the worker's keyframe ``copies`` (updated in place: new
    states in, keyframes out of the window dropped) and run ``backend`` (a
    :class:`~spgeo.vo.backend.WindowBackend`) on them."""
    for kf in job.keyframes:
        copies[kf.index] = kf
    missing = [k for k in job.window if k not in copies]
    if missing:
        raise MappingWorkerError(f"mapping job without keyframes {missing}")
    for k in [k for k in copies if k not in job.window]:
        del copies[k]
    if job.reset:
        backend.reset()
    kfs = [copies[k] for k in job.window]
    timings: Dict[str, float] = {}
    n_reports = len(backend.mapper.reports)
    backend.add_landmarks(kfs, job.segment, timings)
    restarted = backend.map(kfs, job.candidates, job.segment, False, timings)
    return MappingUpdate(dict(backend.mapper.refreshed), dict(backend.mapper.refreshed_support),
                         restarted, backend.mapper.reports[n_reports:], timings,
                         backend.landmarks_report(), _peak_rss_mib())


def serve(jobs, updates) -> None:
    """The worker process's loop over two :class:`multiprocessing.connection.Connection`
    ends: the camera and configuration first, then jobs until ``None`` or the
    caller's end closes; one thread for OpenCV and numba (the other core
    tracks); an exception is sent back as text.  Ctrl-C is the caller's to
    handle (ignored here: a run ended early still gets its last update)."""
    import signal

    import cv2

    from .backend import WindowBackend

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):    # pragma: no cover - numba is optional
        pass
    try:
        camera, config = jobs.recv()
        backend = WindowBackend(camera, config)
        copies: Dict[int, MapKeyframe] = {}
        updates.send(("ready", None))
        while True:
            job = jobs.recv()
            if job is None:
                return
            try:
                answer = ("ok", run_job(backend, copies, job))
            except Exception:      # noqa: BLE001 - every failure goes back to the caller
                answer = ("error", traceback.format_exc())
            updates.send(answer)
    except (EOFError, OSError):     # the caller is gone (it exited or closed its ends)
        return


def _worker_main(job_fd: int, update_fd: int) -> None:
    """Entry point of the worker process (``python -c``; see :class:`MappingWorker`)."""
    serve(Connection(job_fd, writable=False), Connection(update_fd, readable=False))


class MappingWorker:
    """The client side of the mapping worker process (module docstring).

    Args:
        camera: the processing camera.
        config: the run's :class:`OdometryConfig`.

    The process starts here and imports in the background; the first
    :meth:`receive` waits for it.  :meth:`close` stops it (also at garbage
    collection; at interpreter exit it reads the end of its pipe and exits).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig) -> None:
        job_r, job_w = os.pipe()
        upd_r, upd_w = os.pipe()
        code = (f"from {__name__} import _worker_main; _worker_main({job_r}, {upd_w})")
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([p for p in sys.path if p]
                                            + [env.get("PYTHONPATH", "")])
        try:
            self._proc = subprocess.Popen([sys.executable, "-c", code], pass_fds=(job_r, upd_w),
                                          stdin=subprocess.DEVNULL, env=env)
        finally:
            os.close(job_r)
            os.close(upd_w)
        self._jobs = Connection(job_w, readable=False)
        self._updates = Connection(upd_r, writable=False)
        self._jobs.send((camera, config))
        self._ready = False
        self._sent: Dict[int, Keyframe] = {}
        self.pending = False
        self.config = config

    def job(self, window: Sequence[MapKeyframe], candidates: Sequence[SupportCandidate],
            segment: int, reset: bool) -> MappingJob:
        """The job of the window ``window`` (oldest first, the new keyframe last):
        the keyframes whose :class:`Keyframe` object is not the one last sent or
        synced go with it (copies without cached mapping pixels)."""
        send = [dataclasses.replace(kf, map_pixels=None) for kf in window
                if self._sent.get(kf.index) is not kf.keyframe]
        for kf in window:
            self._sent[kf.index] = kf.keyframe
        keep = {kf.index for kf in window}
        self._sent = {k: v for k, v in self._sent.items() if k in keep}
        chosen = choose_support(candidates, self.config.n_support)   # the mapper's choice
        return MappingJob([kf.index for kf in window], send, chosen, segment, reset)

    def synced(self, k: int, keyframe: Keyframe) -> None:
        """Keyframe ``k``'s :class:`Keyframe` is now ``keyframe``, equal to the
        worker's copy (an update applied)."""
        self._sent[k] = keyframe

    def submit(self, job: MappingJob) -> None:
        """Send ``job``; raises :class:`MappingWorkerError` when one is pending or
        the worker is gone."""
        if self.pending:
            raise MappingWorkerError("a mapping job is already pending")
        try:
            self._jobs.send(job)
        except (OSError, EOFError) as exc:
            raise MappingWorkerError(f"the mapping worker is gone ({exc})") from exc
        self.pending = True

    def ready(self) -> bool:
        """Whether the pending job's update can be received without waiting."""
        if not self.pending or not self._started(block=False):
            return False
        return self._updates.poll()

    def receive(self) -> MappingUpdate:
        """The pending job's update (waits for it).  Raises
        :class:`MappingWorkerError` with the worker's traceback when the job
        failed, or when the worker died."""
        if not self.pending:
            raise MappingWorkerError("no mapping job is pending")
        self._started(block=True)
        status, payload = self._recv()
        self.pending = False
        if status == "error":
            raise MappingWorkerError(f"the mapping worker failed:\n{payload}")
        return payload

    def _started(self, block: bool) -> bool:
        """Whether the worker said it is ready (its first message), waiting for
        it with ``block``."""
        if not self._ready and (block or self._updates.poll()):
            status, _ = self._recv()
            if status != "ready":      # pragma: no cover - protocol error
                raise MappingWorkerError(f"the mapping worker sent {status!r} first")
            self._ready = True
        return self._ready

    def _recv(self):
        while not self._updates.poll(1.0):
            if self._proc.poll() is not None:
                raise MappingWorkerError(f"the mapping worker exited (code "
                                         f"{self._proc.returncode}; its error is above, on "
                                         "standard error)")
        try:
            return self._updates.recv()
        except (EOFError, OSError) as exc:
            raise MappingWorkerError(f"the mapping worker is gone ({exc}; its error is on "
                                     "standard error)") from exc

    def close(self) -> None:
        """Stop the worker (a pending job is dropped); idempotent."""
        if self._proc is None:
            return
        try:
            self._jobs.send(None)
        except (OSError, EOFError):
            pass
        try:
            self._proc.wait(CLOSE_TIMEOUT)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(CLOSE_TIMEOUT)
        self._jobs.close()
        self._updates.close()
        self._proc, self.pending = None, False

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:      # noqa: BLE001 - interpreter shutdown
            pass


@dataclass
class LiveMapping:
    """The caller's record of live mapping (one :class:`~spgeo.vo.Odometry`).

    Attributes:
        pending: the job in flight: ``(keyframe index, its T_world_kf and median
            depth when sent, number of frames processed then)``, or None.
        reset_next: the next job restarts the smoother (a new segment).
        older_map_frames: frames tracked while an update was pending.
        latencies: per applied update, the frames processed between sending the
            job and applying its update.
        reports: the mapper's report entries, in order.
        landmarks: the latest landmark report (None without landmarks).
        seconds: the back end's seconds per stage in the worker.
        worker_peak_rss_mib: the worker's peak resident memory (MiB), as last reported.
    """

    pending: Optional[tuple] = None
    reset_next: bool = False
    older_map_frames: int = 0
    latencies: List[int] = field(default_factory=list)
    reports: List[dict] = field(default_factory=list)
    landmarks: Optional[dict] = None
    seconds: Dict[str, float] = field(default_factory=dict)
    worker_peak_rss_mib: Optional[float] = None

    def lead(self, n_frames: int) -> int:
        """Frames processed since the pending job was sent, when ``n_frames``
        have been (0 when none is pending)."""
        return 0 if self.pending is None else n_frames - self.pending[3]

    def record(self, upd: MappingUpdate, latency: int) -> None:
        """An applied update, ``latency`` frames after its job was sent."""
        self.pending = None
        self.latencies.append(int(latency))
        self.reports.extend(upd.reports)
        self.landmarks = upd.landmarks
        self.worker_peak_rss_mib = upd.peak_rss_mib
        for key, sec in upd.timings.items():
            self.seconds[key] = self.seconds.get(key, 0.0) + float(sec)

    def report(self) -> dict:
        """JSON-ready: updates applied, frames tracked against an older map,
        latency in frames (mean, max) and the worker's seconds per stage."""
        lat = self.latencies
        return {"updates": len(lat), "frames_tracked_against_older_map": self.older_map_frames,
                "latency_frames_mean": float(np.mean(lat)) if lat else None,
                "latency_frames_max": int(max(lat)) if lat else None,
                "worker_seconds": dict(self.seconds),
                "worker_peak_rss_mib": self.worker_peak_rss_mib}
