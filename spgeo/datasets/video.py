"""Video files and live cameras through OpenCV's ``cv2.VideoCapture``.

* :class:`VideoSequence` (``"video"``): any file ``VideoCapture`` reads.  Opening
  scans the file once (``grab`` of every frame, no colour conversion) for the
  frame count and the timestamps; frames are then decoded in order (a request
  behind the current position reopens the file, one ahead skips forward).
  Frame number = 0-based position in the stream; timestamp = the container's
  ``CAP_PROP_POS_MSEC`` / 1000 (seconds), or ``number / fps`` where the
  container gives no increasing times (``number`` without a frame rate).  A
  frame that fails to decode raises :class:`~spgeo.validation.FrameReadError`
  naming the file and frame, as an unreadable image of a folder does.
* :class:`CameraStream` (``"camera"``): a live camera by device index; an
  iterable (no length), read once, of frames stamped with the seconds since
  the first frame (``time.monotonic``, kept strictly increasing).  It ends when the camera stops giving frames, at
  the end of the ``frames`` selection, or on Ctrl-C in the consumer.

Neither has a calibration file: the camera is the one given (``camera=`` a
:class:`~spgeo.camera.PinholeCamera` or a
:class:`~spgeo.datasets.calibration.CameraSpec`), else a guess
(:func:`~spgeo.datasets.calibration.guess_camera`, a warning).  Frames are
float32 RGB in [0, 1], without depth or ground truth.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..validation import InputError, check_input_file
from .calibration import CameraSpec
from .common import (CameraSource, FileRecord, FrameSelection, FrameSequence, config_from_kwargs,
                     parse_frame_range, select_frames)
from .files import PathLike

__all__ = ["VideoConfig", "VideoSequence", "CameraStream", "open_capture"]

logger = logging.getLogger(__name__)


@config_class
@dataclass
class VideoConfig:
    """Options of :class:`VideoSequence` and :class:`CameraStream`.

    Attributes:
        camera: intrinsics of the frames (:class:`PinholeCamera`, or a
            :class:`~spgeo.datasets.calibration.CameraSpec` built at the frame
            size); default None guesses them (a warning).
        frames: selection by frame number (``"A:B[:S]"``, slice, range, list;
            default None = all); for a camera only ``"A:B[:S]"`` / slice / range,
            and a stop ends the stream.
        undistort: undistort when ``camera`` carries distortion (default True).
        load_depth: accepted for the runner's sake; videos have no depth.
    """

    camera: Union[None, PinholeCamera, CameraSpec] = None
    frames: FrameSelection = None
    undistort: bool = True
    load_depth: bool = False


# FFmpeg reads its log level once, when OpenCV first loads it: set here, at import,
# so that a file FFmpeg cannot parse is reported by the reader's error alone.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")          # AV_LOG_QUIET


@contextlib.contextmanager
def _quiet_opencv():
    """OpenCV's log lines off, and the process's stderr (file descriptor 2, where
    FFmpeg writes when it was loaded before this module) sent to the null device,
    while a capture opens; a file or device that cannot be opened is reported
    once, by the reader's error."""
    import cv2

    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    saved = None
    try:
        sys.stderr.flush()
        saved = os.dup(2)
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
    except (OSError, ValueError, AttributeError):    # no usable fd 2 (embedded interpreters)
        saved = None
    try:
        yield
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
        cv2.utils.logging.setLogLevel(level)


def open_capture(source: Union[str, int]):
    """``cv2.VideoCapture(source)`` (a file path or a device index) opened quietly;
    None when OpenCV cannot open it."""
    import cv2

    with _quiet_opencv():
        cap = cv2.VideoCapture(source)
    if not cap.isOpened():
        cap.release()
        return None
    return cap


def _to_rgb(bgr: np.ndarray) -> np.ndarray:
    """A decoded OpenCV frame (BGR or grey, uint8/uint16) -> float32 RGB in [0, 1]."""
    from ..images import to_float_image

    if bgr.ndim == 2:
        bgr = np.repeat(bgr[..., None], 3, axis=2)
    return np.ascontiguousarray(to_float_image(bgr[..., 2::-1]), dtype=np.float32)


class VideoSequence(FrameSequence):
    """Lazy reader of a video file (see the module docstring).

    Args:
        path: the video file.
        config: a :class:`VideoConfig`; keyword arguments override its fields.

    Raises ``FileNotFoundError`` for a missing file and
    :class:`~spgeo.validation.InputError` naming the file when OpenCV cannot
    open it or it has no decodable frame.
    """

    def __init__(self, path: PathLike, config: Optional[VideoConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = config_from_kwargs(VideoConfig, config, kwargs, type(self).__name__)
        self.config = cfg
        self.root = Path(check_input_file(Path(path).expanduser(), "video"))
        self._name = self.root.stem
        self._undistort = bool(cfg.undistort)
        self._cap, self._next = None, 0
        stamps, size = self._scan()
        self._raw_camera = self._given_or_guessed(cfg.camera, size[0], size[1])
        keep = select_frames(range(len(stamps)), cfg.frames)
        self._records = [FileRecord(k, float(stamps[k]), self.root) for k in keep]

    def _scan(self) -> Tuple[np.ndarray, Tuple[int, int]]:
        """Grab every frame once: ``(timestamps in seconds, (width, height))``."""
        import cv2

        cap = open_capture(str(self.root))
        if cap is None:
            raise InputError(f"cannot open video {self.root}: not a video file OpenCV can read")
        try:
            ok, first = cap.read()
            if not ok or first is None:
                raise InputError(f"video {self.root} has no decodable frame")
            msec = [cap.get(cv2.CAP_PROP_POS_MSEC)]
            while cap.grab():
                msec.append(cap.get(cv2.CAP_PROP_POS_MSEC))
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        finally:
            cap.release()
        n = np.arange(len(msec), dtype=np.float64)
        stamps = np.asarray(msec, dtype=np.float64) / 1000.0
        if not (np.all(np.isfinite(stamps)) and np.all(np.diff(stamps) > 0)):
            stamps = n / fps if np.isfinite(fps) and fps > 0 else n
            logger.info("%s: no increasing container timestamps; using %s", self.root,
                        "frame number / fps" if fps > 0 else "frame numbers")
        logger.debug("opened video %s: %d frames, %dx%d", self.root, len(n),
                     first.shape[1], first.shape[0])
        return stamps, (int(first.shape[1]), int(first.shape[0]))

    def _seek(self, number: int) -> None:
        """Position the capture so that the next ``grab`` gives frame ``number``."""
        if self._cap is None or number < self._next:
            self.close()
            self._cap, self._next = open_capture(str(self.root)), 0
            if self._cap is None:
                raise InputError(f"cannot reopen video {self.root}")
        while self._next < number:
            if not self._cap.grab():
                raise InputError(f"video {self.root} ends before frame {number}")
            self._next += 1

    def _load(self, index: int, rec: FileRecord) -> Frame:
        self._seek(rec.number)
        ok = self._cap.grab()
        self._next += 1
        ok, bgr = self._cap.retrieve() if ok else (False, None)
        if not ok or bgr is None:
            raise InputError(f"frame {rec.number} of video {self.root} cannot be decoded")
        image = _to_rgb(bgr)
        if image.shape[:2] != self._raw_camera.shape:
            raise InputError(f"frame {rec.number} of video {self.root} is "
                             f"{image.shape[1]}x{image.shape[0]}, the video "
                             f"{self._raw_camera.width}x{self._raw_camera.height}")
        meta = {"dataset": "video", "sequence": self._name, "index": index,
                "frame_number": rec.number, "video_path": str(self.root)}
        return Frame(image=self._finish_image(image), camera=self.camera,
                     timestamp=rec.timestamp, name=f"{rec.number:06d}", meta=meta)

    def close(self) -> None:
        """Release the open capture (reading again reopens it)."""
        if self._cap is not None:
            self._cap.release()
        self._cap, self._next = None, 0

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


class CameraStream(CameraSource):
    """Frames of a live camera (see the module docstring): an iterable without
    length, with ``camera``, ``raw_camera``, ``name`` and ``intrinsics`` like the
    data-set readers.

    Args:
        index: the device index (an int, or a string of digits: ``"0"``).
        config: a :class:`VideoConfig`; keyword arguments override its fields.

    Raises :class:`~spgeo.validation.InputError` naming the index when it is not
    a device index or the camera gives no frame.
    """

    def __init__(self, index: Union[int, str], config: Optional[VideoConfig] = None,
                 **kwargs) -> None:
        cfg = config_from_kwargs(VideoConfig, config, kwargs, type(self).__name__)
        text = str(index).strip()
        if not text.isdigit():
            raise InputError(f"camera index must be a non-negative integer, got {index!r}")
        self.config, self.index = cfg, int(text)
        sel = cfg.frames
        sel = parse_frame_range(sel) if isinstance(sel, str) else sel
        if sel is not None and not isinstance(sel, (slice, range)):
            raise InputError("a camera's frame selection must be 'A:B[:STEP]'")
        self._selection = sel
        self._name, self._undistort = f"camera{self.index}", bool(cfg.undistort)
        self._cap = open_capture(self.index)
        ok, first = (False, None) if self._cap is None else self._cap.read()
        if not ok or first is None:
            self.close()
            raise InputError(f"camera {self.index} gives no frame (no such device, or it is "
                             "busy or not a camera)")
        self._first = first
        self._raw_camera = self._given_or_guessed(cfg.camera, first.shape[1], first.shape[0])

    def _wanted(self, number: int) -> Tuple[bool, bool]:
        """``(frame number selected, stream over)`` for the selection."""
        sel = self._selection
        if sel is None:
            return True, False
        start = sel.start or 0
        step = sel.step or 1
        if sel.stop is not None and number >= sel.stop:
            return False, True
        return number >= start and (number - start) % step == 0, False

    def __iter__(self) -> Iterator[Frame]:
        t0, last, number, bgr = None, None, 0, self._first
        try:
            while bgr is not None:
                keep, over = self._wanted(number)
                if over:
                    return
                now = time.monotonic()
                t0 = now if t0 is None else t0
                if keep:
                    stamp = now - t0 if last is None else max(now - t0, last + 1e-6)
                    last = stamp
                    yield Frame(image=self._finish_image(_to_rgb(bgr)), camera=self.camera,
                                timestamp=stamp, name=f"{number:06d}",
                                meta={"dataset": "camera", "camera_index": self.index,
                                      "frame_number": number})
                number += 1
                ok, bgr = self._cap.read() if self._cap is not None else (False, None)
                bgr = bgr if ok else None
        finally:
            self.close()

    def close(self) -> None:
        """Release the device."""
        if getattr(self, "_cap", None) is not None:
            self._cap.release()
        self._cap = None

    def __repr__(self) -> str:
        return f"CameraStream(index={self.index}, camera={self.camera!r})"
