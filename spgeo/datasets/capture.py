"""Capture apart from tracking: a thread that reads a live source into a bounded ring.

A live camera gives a frame every period whether or not the consumer is ready.
:class:`CaptureRing` reads the source (``cv2.VideoCapture.read``, decoding, the
colour conversion: whatever iterating the source does) in its own thread, so that
this work overlaps the consumer's, and holds the newest ``capacity`` frames: when a
frame arrives while the ring is full, the *oldest* waiting frame is dropped (the
consumer then sees the newest frames, with a gap its motion model bridges).  Every
dropped frame is recorded (its name, timestamp and arrival number) and reported
(:meth:`CaptureRing.report`, ``report.json``'s ``"capture"``): never silent.

Frames a driver drops before the source gives them are not seen here; the source's
own report (if any) holds them.

Iterating a :class:`CaptureRing` starts the thread; the iteration ends when the
source ends and the ring is empty.  Leaving the iteration early (``break``, an
exception, :meth:`CaptureRing.close`) stops the thread, which closes the source's
iterator (a camera releases its device).  An exception raised by the source is
raised by the consumer's iteration.  A ring is iterated once.
"""
from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import Deque, Iterable, Iterator, List, Optional, Tuple

from ..frame import Frame

__all__ = ["CaptureRing", "DroppedFrame", "longest_run"]


@dataclass(frozen=True)
class DroppedFrame:
    """A frame the ring dropped: its ``name``, ``timestamp`` and ``arrival``
    (0-based count of the frames the source gave)."""

    name: str
    timestamp: float
    arrival: int

    def to_dict(self) -> dict:
        return {"name": self.name, "timestamp": self.timestamp, "arrival": self.arrival}


def longest_run(numbers: Iterable[int]) -> int:
    """The longest run of consecutive integers in ``numbers`` (sorted or not; 0
    when empty)."""
    best = run = 0
    prev: Optional[int] = None
    for n in sorted(set(int(x) for x in numbers)):
        run = run + 1 if prev is not None and n == prev + 1 else 1
        best, prev = max(best, run), n
    return best


class CaptureRing:
    """Frames of ``source`` read by a capture thread into a ring of ``capacity``
    frames (module docstring).

    Args:
        source: an iterable of :class:`~spgeo.frame.Frame` in time order (a
            :class:`~spgeo.datasets.CameraStream`, a simulated camera).
        capacity: frames the ring holds (>= 1).

    Attributes:
        camera: the source's ``camera`` (None when it has none).
        dropped: the :class:`DroppedFrame` records, in arrival order.
        arrived: frames the source gave so far.
        most_waiting: the most frames ever waiting in the ring.

    Raises ``ValueError`` for a ``capacity`` below 1.
    """

    def __init__(self, source: Iterable[Frame], capacity: int) -> None:
        if int(capacity) < 1:
            raise ValueError(f"CaptureRing: capacity must be >= 1, got {capacity!r}")
        self.source, self.capacity = source, int(capacity)
        self.camera = getattr(source, "camera", None)
        self.dropped: List[DroppedFrame] = []
        self.arrived = self.most_waiting = 0
        self._ring: Deque[Tuple[int, Frame]] = collections.deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._done = False
        self._error: Optional[BaseException] = None
        self._thread: Optional[threading.Thread] = None

    def __getattr__(self, name: str):
        """The source's other attributes (``name``, ``intrinsics``, ...)."""
        if name.startswith("_") or name == "source":
            raise AttributeError(name)
        return getattr(self.source, name)

    def __iter__(self) -> Iterator[Frame]:
        if self._thread is not None:
            raise RuntimeError("a CaptureRing is iterated once")
        self._thread = threading.Thread(target=self._capture, name="spgeo-capture",
                                        daemon=True)
        self._thread.start()
        try:
            while True:
                item = self._next()
                if item is None:
                    return
                yield item
        finally:
            self.close()

    def _next(self) -> Optional[Frame]:
        """The oldest waiting frame (waits for one); None at the end."""
        with self._cond:
            while not self._ring and not self._done:
                self._cond.wait()
            if self._ring:
                return self._ring.popleft()[1]
            if self._error is not None:
                raise self._error
            return None

    def _capture(self) -> None:
        """The thread: the source's frames into the ring, dropping the oldest."""
        it = iter(self.source)
        try:
            for frame in it:
                self._put(frame)
                if self._stop.is_set():
                    break
        except BaseException as exc:     # raised again in the consumer's thread
            self._error = exc
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()
            with self._cond:
                self._done = True
                self._cond.notify_all()

    def _put(self, frame: Frame) -> None:
        with self._cond:
            if len(self._ring) >= self.capacity:
                n, old = self._ring.popleft()
                self.dropped.append(DroppedFrame(str(old.name), float(old.timestamp), n))
            self._ring.append((self.arrived, frame))
            self.arrived += 1
            self.most_waiting = max(self.most_waiting, len(self._ring))
            self._cond.notify_all()

    def close(self, timeout: float = 5.0) -> None:
        """Stop the capture thread (it finishes the frame it reads and closes the
        source's iterator); idempotent."""
        self._stop.set()
        th = self._thread
        if th is not None and th.is_alive() and th is not threading.current_thread():
            th.join(timeout)     # putting never blocks: only the source's read can

    def report(self) -> dict:
        """JSON-ready: ``capacity``, frames ``arrived``, ``dropped`` (count),
        ``longest_drop_run`` (consecutive arrivals), ``most_waiting`` and
        ``dropped_frames`` (:meth:`DroppedFrame.to_dict` each)."""
        return {"capacity": self.capacity, "arrived": self.arrived,
                "dropped": len(self.dropped),
                "longest_drop_run": longest_run(d.arrival for d in self.dropped),
                "most_waiting": self.most_waiting,
                "dropped_frames": [d.to_dict() for d in self.dropped]}

    def __repr__(self) -> str:
        return (f"CaptureRing(capacity={self.capacity}, arrived={self.arrived}, "
                f"dropped={len(self.dropped)})")
