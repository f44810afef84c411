"""The VO's processing size and the resizing of input frames to it.

:class:`spgeo.vo.Odometry` works at one processing size: its camera is the
input camera resized (:meth:`~spgeo.camera.PinholeCamera.resized`) to
``OdometryConfig.resolution`` when set, else to :func:`processing_size` of
the input size with ``OdometryConfig.target_pixels`` (about that many pixels,
the input's aspect ratio kept; 4:3 gives 320x240; smaller inputs are kept).  Frames given at the input
size are resized by :func:`resize_for_vo` inside ``Odometry.track`` (which checks
each frame with :func:`checked_frame`), so a library loop over full-size frames
and ``spgeo vo`` process the same pixels.
"""
from __future__ import annotations

import contextlib
import math
from typing import Iterator, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame, frame_label
from ..validation import MAX_IMAGE_SIDE, InputError, check_same_camera, swapped_size_hint

__all__ = ["DEFAULT_TARGET_PIXELS", "SIZE_MULTIPLE", "processing_size", "resize_for_vo",
           "checked_frame", "opencv_threads"]

#: Default processing area in pixels (``OdometryConfig.target_pixels``): that of 320x240.
DEFAULT_TARGET_PIXELS = 320 * 240
#: Processing widths and heights of :func:`processing_size` are multiples of this
#: (the keyframe pyramid halves the image twice and stays on whole pixels).
SIZE_MULTIPLE = 8


def processing_size(input_size: Tuple[int, int], target_pixels: int = DEFAULT_TARGET_PIXELS,
                    multiple: int = SIZE_MULTIPLE) -> Tuple[int, int]:
    """The default processing ``(width, height)`` for an input of ``input_size``
    ``(width, height)`` pixels: the input size itself when it has at most
    ``target_pixels`` pixels (small inputs are not upsampled), else about
    ``target_pixels`` pixels with the input's aspect ratio, i.e.
    ``sqrt(target_pixels * W / H)`` by ``sqrt(target_pixels * H / W)``, each
    rounded to the nearest multiple of ``multiple`` (at least ``multiple``).
    A 4:3 input of at least 320x240 with the default target gives exactly
    320x240.  Raises :class:`~spgeo.validation.InputError` for non-positive
    sizes or target."""
    w, h = (int(v) for v in input_size)
    if w <= 0 or h <= 0 or int(target_pixels) <= 0 or int(multiple) <= 0:
        raise InputError(f"processing_size: input size {input_size!r}, target_pixels "
                         f"{target_pixels!r} and multiple {multiple!r} must be positive")
    if w * h <= int(target_pixels):
        return w, h
    m = int(multiple)
    out = [max(m, int(round(np.sqrt(target_pixels * a / b) / m)) * m) for a, b in ((w, h), (h, w))]
    return min(out[0], MAX_IMAGE_SIDE), min(out[1], MAX_IMAGE_SIDE)


def resize_for_vo(frame: Frame, camera: PinholeCamera, use_depth: bool, index: int) -> Frame:
    """``frame`` at ``camera``'s size, as the VO reads it: float32 image resized
    with ``cv2.INTER_AREA``; depth (resized with ``cv2.INTER_NEAREST``) only
    when ``use_depth``; no ground truth or meta (not
    :func:`spgeo.frame.resize_frame`: no undistortion, the camera is given).

    Raises :class:`~spgeo.validation.InputError` (a ``ValueError``) naming
    frame ``index`` when ``use_depth`` and the frame has no depth.
    """
    import cv2

    size = camera.size
    image = np.asarray(frame.image)
    if image.dtype != np.float32:
        from ..images import to_float_image

        image = to_float_image(image)
    if (image.shape[1], image.shape[0]) != tuple(size):
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    depth = None
    if use_depth:
        if frame.depth is None:
            raise InputError(f"{frame_label(frame.name, index)} has no depth but the front-end "
                             "uses depth (open the data set with depth, or use a monocular "
                             "front-end)")
        depth = np.asarray(frame.depth, dtype=np.float32)
        if (depth.shape[1], depth.shape[0]) != tuple(size):
            depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    return Frame(image, camera, float(frame.timestamp), depth, None, frame.name)


def checked_frame(frame: Frame, index: int, camera: PinholeCamera, input_camera: PinholeCamera,
                  use_depth: bool, previous_timestamp: Optional[float]) -> Frame:
    """``frame`` (frame number ``index`` of a VO run) at the processing
    ``camera``'s size: given at ``input_camera``'s size it is resized by
    :func:`resize_for_vo`, given at the processing size it is kept.  The
    image's dtype, channels and range were checked when the frame was made
    (:func:`spgeo.frame.check_frame_image`); messages name an unnamed frame by
    ``index`` (:func:`spgeo.frame.frame_label`).

    Raises:
        TypeError: ``frame`` is not a :class:`~spgeo.frame.Frame`.
        InputError: (a ``ValueError``) the image's (H, W) is neither camera's
            (the message says when width and height look swapped), the frame's
            camera is not the camera of its size (``input_camera``, or
            ``camera`` at the processing size:
            :func:`~spgeo.validation.check_same_camera`), the image holds
            NaN / inf, or the timestamp is not finite or not strictly after
            ``previous_timestamp`` (None for the first frame).
    """
    if not isinstance(frame, Frame):
        raise TypeError(f"Odometry.track expects a spgeo.frame.Frame, got "
                        f"{type(frame).__name__}")
    what = f"Odometry.track: {frame_label(frame.name, index)}"
    image = np.asarray(frame.image)
    hw = tuple(image.shape[:2])
    if image.ndim not in (2, 3) or hw not in (camera.shape, input_camera.shape):
        raise InputError(f"{what} image of shape {image.shape} does not match the input "
                         f"camera's (H, W) {input_camera.shape}"
                         f"{swapped_size_hint(image.shape, input_camera.shape)}")
    if hw == input_camera.shape:
        check_same_camera(frame.camera, input_camera, f"{what} camera",
                          "the camera the Odometry was built with")
    else:
        check_same_camera(frame.camera, camera, f"{what} camera (processing size)",
                          "the Odometry's processing camera (Odometry.camera)")
    if hw != camera.shape:
        frame = resize_for_vo(frame, camera, use_depth, index)
        image = frame.image
    if not np.all(np.isfinite(image)):
        raise InputError(f"{what} image contains NaN or inf")
    try:
        stamp = float(frame.timestamp)
    except (TypeError, ValueError):
        stamp = math.nan
    if not math.isfinite(stamp):
        raise InputError(f"{what} timestamp {frame.timestamp!r} is not a finite number")
    if previous_timestamp is not None and not stamp > previous_timestamp:
        raise InputError(f"{what} timestamp {stamp!r} is not after the previous frame's "
                         f"{previous_timestamp!r}: timestamps must be strictly increasing")
    return frame


@contextlib.contextmanager
def opencv_threads(n: int) -> Iterator[None]:
    """OpenCV limited to ``n`` threads inside the block, its setting restored
    after.  :meth:`spgeo.vo.Odometry.track` runs with one:
    at the processing size OpenCV's thread pool costs more than it gives, and
    the second core maps (docs/results.md, *Real time on two cores*)."""
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)
