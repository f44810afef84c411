"""The mapping worker: the VO's back end (:class:`~spgeo.vo.backend.WindowBackend`:
landmarks, loop closure and the window smoother) in a second process, so that tracking
goes on while the window is solved (docs/design.md §5.1, *The mapping port*); the
caller reaches it through :class:`spgeo.vo.mapping_port.MappingPort`.

Why a process and not a thread: GTSAM's Python wrapper holds the interpreter lock
for the whole smoother update (``python scripts/gil_during_solve.py``; docs/history.md,
issue 32), so a mapper thread would only take turns with the tracker.

A map's initialisation may also send its keyframe-1 solve (an
:class:`~spgeo.vo.initialisation.InitJob`, run by its own ``run``) while the worker
has no window yet (:meth:`spgeo.vo.mapping_port.MappingPort.solve_init`).

Protocol (one job in flight at a time): :meth:`MappingWorker.submit` sends a
:class:`~spgeo.vo.backend.MappingJob` (its keyframes pickled without their derived
data, :meth:`Keyframe.__getstate__ <spgeo.vo.tracking.Keyframe.__getstate__>`); the
worker runs :meth:`WindowBackend.run <spgeo.vo.backend.WindowBackend.run>` on its own
copies of the window's keyframes and answers the
:class:`~spgeo.vo.backend.MappingUpdate`, which :meth:`MappingWorker.receive` returns.
The worker is a fresh interpreter (``python -P -c``, the parent's ``sys.path``: it
imports the modules the parent imported; no fork of a threaded parent, and unlike
``multiprocessing``'s ``spawn`` it does not import the caller's main script), talking
over two pipes with :class:`multiprocessing.connection.Connection` (pickle).
"""
from __future__ import annotations

import logging
import os
import subprocess
import sys
import traceback
from multiprocessing.connection import Connection

from ..camera import PinholeCamera
from .backend import MappingJob, MappingUpdate, WindowBackend
from .config import OdometryConfig
from .initialisation import InitJob

__all__ = ["MappingJob", "MappingUpdate", "MappingWorker", "MappingWorkerError"]

log = logging.getLogger(__name__)

#: seconds a closing worker is given to finish before it is terminated
CLOSE_TIMEOUT = 5.0


class MappingWorkerError(RuntimeError):
    """The mapping worker failed (its traceback in the message) or died."""


def serve(jobs, updates) -> None:
    """The worker process's loop over two :class:`multiprocessing.connection.Connection`
    ends: the camera and configuration first, then jobs until ``None`` or the
    caller's end closes; one thread for OpenCV and numba (the other core
    tracks); an exception is sent back as text.  Ctrl-C is the caller's to
    handle (ignored here: a run ended early still gets its last update)."""
    import signal

    import cv2

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
        updates.send(("ready", None))
        while True:
            job = jobs.recv()
            if job is None:
                return
            try:
                answer = ("ok", job.run() if isinstance(job, InitJob) else backend.run(job))
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
        # this process's import path, in order ('' is the directory it was read in); -P:
        # no working directory in front of it, so the worker imports the spgeo this
        # process imported even when the caller runs from another checkout
        env["PYTHONPATH"] = os.pathsep.join([p or os.getcwd() for p in sys.path]
                                            + [env.get("PYTHONPATH", "")])
        try:
            self._proc = subprocess.Popen([sys.executable, "-P", "-c", code],
                                          pass_fds=(job_r, upd_w), stdin=subprocess.DEVNULL,
                                          env=env)
        finally:
            os.close(job_r)
            os.close(upd_w)
        self._jobs = Connection(job_w, readable=False)
        self._updates = Connection(upd_r, writable=False)
        self._jobs.send((camera, config))
        self._ready = False
        self.pending = False

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
