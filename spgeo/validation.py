"""Input validation at the library's boundaries (readers, public functions, the CLI).

Every check raises :class:`InputError` (a ``ValueError``) whose message names the
file or value and says what was expected; a missing file raises
``FileNotFoundError``, a wrong Python type ``TypeError``.  The checks take plain
values / arrays plus ``what`` (how the message names the input: a path, an
argument name), so every boundary can call them without building objects first.

:class:`InputError` and :func:`check_intrinsics` live in :mod:`spgeo.checks`, below
:mod:`spgeo.camera` (which uses them); they are re-exported here, the place to import them from.
"""
from __future__ import annotations

import logging
import os
from typing import Optional, Sequence, Tuple

import numpy as np

from .camera import PinholeCamera
from .checks import (FOCAL_RATIO_RANGE, FOV_RANGE_DEG, PRINCIPAL_POINT_MARGIN, InputError,
                     check_intrinsics, swapped_size_hint)

__all__ = ["InputError", "MAX_IMAGE_SIDE", "FOV_RANGE_DEG", "FOCAL_RATIO_RANGE",
           "PRINCIPAL_POINT_MARGIN", "MAX_MEDIAN_DEPTH_M", "MIN_NORMAL_LENGTH",
           "NORMAL_LENGTH_WARN",
           "CAMERA_MATCH_TOLERANCE", "check_intrinsics", "swapped_size_hint", "check_camera",
           "check_same_camera", "check_real_array", "check_sparse_depth",
           "check_normals", "check_mask_stack", "check_input_file", "read_image_bytes",
           "FrameReadError", "FrameFileMissing", "ImageSizeMismatch"]

log = logging.getLogger(__name__)

#: two cameras are the same when fx, fy, cx, cy differ by at most this (pixels) and the
#: distortion coefficients by at most this (dimensionless): above floating-point noise
CAMERA_MATCH_TOLERANCE = 1e-3
#: the largest image / processing width or height (pixels) the commands accept
MAX_IMAGE_SIDE = 8192
#: a sparse depth whose median valid value exceeds this (metres) is taken for millimetres
MAX_MEDIAN_DEPTH_M = 100.0
#: normals shorter than this are unknown (NaN); longer ones are normalised
MIN_NORMAL_LENGTH = 1e-3
#: normal lengths outside this range are normalised with a logged warning
NORMAL_LENGTH_WARN: Tuple[float, float] = (0.5, 2.0)


# ------------------------------------------------------------------ cameras
def check_camera(camera, what: str = "camera"):
    """Return ``camera`` if it is a :class:`~spgeo.camera.PinholeCamera`, else
    raise ``TypeError`` naming the type it got."""
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"{what} must be a spgeo.PinholeCamera, got {type(camera).__name__} "
                        f"({camera!r:.60})")
    return camera


def check_same_camera(camera: PinholeCamera, expected: PinholeCamera, what: str = "camera",
                      expected_what: str = "the expected camera") -> None:
    """Raise :class:`InputError` unless ``camera`` is ``expected``: the same width
    and height, fx, fy, cx, cy within :data:`CAMERA_MATCH_TOLERANCE` pixels and
    the same distortion (both none, or coefficients within the tolerance).  The
    message names ``what`` and ``expected_what``, shows both cameras and the
    first field that differs."""
    if camera == expected:
        return
    tol = CAMERA_MATCH_TOLERANCE
    diff = None
    for name in ("width", "height", "fx", "fy", "cx", "cy"):
        a, b = getattr(camera, name), getattr(expected, name)
        if not abs(a - b) <= (0 if name in ("width", "height") else tol):
            diff = f"{name} {a!r} vs {b!r}"
            break
    if diff is None:
        da, db = camera.distortion, expected.distortion
        if (da is None) != (db is None) or (da is not None and (
                len(da) != len(db) or not np.allclose(da, db, rtol=0.0, atol=tol))):
            diff = f"distortion {da} vs {db}"
    if diff is not None:
        raise InputError(f"{what} {camera!r} differs from {expected_what} {expected!r} "
                         f"({diff})")


# ------------------------------------------------------------------ arrays
def check_real_array(array, what: str) -> np.ndarray:
    """``np.asarray(array)``; :class:`InputError` unless its dtype is real numeric
    (bool, complex, object and string arrays are refused before any cast)."""
    a = np.asarray(array)
    if a.dtype == bool or not np.issubdtype(a.dtype, np.number) \
            or np.issubdtype(a.dtype, np.complexfloating):
        raise InputError(f"{what}: expected a real numeric array, got dtype {a.dtype}")
    return a


def check_sparse_depth(depth, what: str = "sparse depth",
                       expected_shape: Optional[Sequence[int]] = None) -> np.ndarray:
    """Validate an (H, W) metric sparse depth map; return it as float64 with missing = 0.

    0 and NaN mean "no measurement".  Raises :class:`InputError` for: a dtype that
    is not real floating point (bool, object, complex; integer arrays hold raw
    sensor units such as millimetres), not 2-D or not ``expected_shape`` (H, W),
    inf, negative values, no valid (> 0) point, or a median valid value above
    ``MAX_MEDIAN_DEPTH_M`` (millimetres given for metres).
    """
    d = check_real_array(depth, what)
    if np.issubdtype(d.dtype, np.integer):
        raise InputError(f"{what}: integer dtype {d.dtype} looks like raw sensor units "
                         "(millimetres); give metres as a float array (e.g. raw / 1000)")
    if d.ndim != 2 or d.size == 0:
        raise InputError(f"{what}: expected a non-empty (H, W) array, got shape {d.shape}")
    if expected_shape is not None and d.shape != tuple(expected_shape):
        raise InputError(f"{what}: shape {d.shape} differs from the image's "
                         f"{tuple(expected_shape)}")
    d = d.astype(np.float64)
    n_inf = int(np.isinf(d).sum())
    if n_inf:
        raise InputError(f"{what}: {n_inf} values are inf (use 0 or NaN for missing)")
    d = np.nan_to_num(d, nan=0.0)
    n_neg = int((d < 0).sum())
    if n_neg:
        raise InputError(f"{what}: {n_neg} values are negative (min {d.min():g}); depths are "
                         "metres > 0, with 0 or NaN for missing")
    valid = d[d > 0]
    if valid.size == 0:
        raise InputError(f"{what}: no valid point (all zero / NaN): nothing to complete from")
    med = float(np.median(valid))
    if med > MAX_MEDIAN_DEPTH_M:
        raise InputError(f"{what}: median depth {med:g} looks like millimetres; the values "
                         f"must be metres (median above {MAX_MEDIAN_DEPTH_M:g} m)")
    return d


def check_normals(normals, what: str = "normals",
                  expected_shape: Optional[Sequence[int]] = None) -> np.ndarray:
    """Camera-frame normals (..., 3) -> float64 unit normals, NaN rows where unknown.

    A normal is unknown when a component is NaN / inf or its length is below
    ``MIN_NORMAL_LENGTH`` (a zero vector has no direction: it becomes NaN, not a
    fronto-parallel guess).  Other normals are divided by their length; when some
    lengths lie outside ``NORMAL_LENGTH_WARN`` a warning with their count is
    logged.  Raises :class:`InputError` for a non-real dtype, a last axis that
    is not 3, or a shape other than ``expected_shape``.
    """
    n = check_real_array(normals, what)
    if n.ndim < 1 or n.shape[-1] != 3:
        raise InputError(f"{what}: expected shape (..., 3), got {n.shape}")
    if expected_shape is not None and n.shape != tuple(expected_shape):
        raise InputError(f"{what}: shape {n.shape} differs from the expected "
                         f"{tuple(expected_shape)} (the camera's (H, W, 3))")
    n = n.astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.sqrt(np.einsum("...i,...i->...", n, n))
        known = np.isfinite(length) & (length >= MIN_NORMAL_LENGTH)
    lo, hi = NORMAL_LENGTH_WARN
    off = known & ((length < lo) | (length > hi))
    if np.any(off):
        log.warning("%s: %d normals of length outside [%g, %g] were normalised", what,
                    int(off.sum()), lo, hi)
    return np.where(known[..., None], n / np.where(known, length, 1.0)[..., None], np.nan)


def check_mask_stack(masks, shape: Tuple[int, int], what: str = "masks") -> np.ndarray:
    """(N, H, W) or (H, W) masks of image ``shape`` -> (N, H, W) bool.

    Accepts bool arrays and real arrays holding only 0 and 1; raises
    :class:`InputError` for another shape, dtype or values.
    """
    m = np.asarray(masks)
    if m.ndim == 2:
        m = m[None]
    if m.ndim != 3 or m.shape[1:] != tuple(shape):
        raise InputError(f"{what} must be (N, {shape[0]}, {shape[1]}), got {np.shape(masks)}")
    if m.dtype == bool:
        return m
    check_real_array(m, what)
    if not np.all((m == 0) | (m == 1)):
        raise InputError(f"{what}: dtype {m.dtype} with values other than 0 and 1; "
                         "expected a boolean mask")
    return m.astype(bool)


# ------------------------------------------------------------------ files
class FrameReadError(InputError):
    """A frame of a sequence whose file(s) could not be read (missing, unreadable,
    truncated, undecodable; a wrong size is an ImageSizeMismatch): raised by
    :class:`spgeo.datasets.common.FrameSequence` in place of the reader's
    :class:`InputError` / ``OSError`` (kept as ``__cause__``), so that a batch
    runner can skip the frame (:mod:`spgeo.apps.vo_run`) and still let every
    other error through.

    Attributes:
        index: the frame's position in the sequence's selection (0-based).
        path: the frame's image file (the message names the file that failed,
            e.g. its depth file).
        timestamp: the frame's timestamp (seconds, or its frame number), known
            without reading the file; None where unknown.
        reason: the reader's message.
    """

    def __init__(self, index: int, path: Optional[str], reason: str,
                 timestamp: Optional[float] = None) -> None:
        super().__init__(f"frame {index} ({path}): {reason}")
        self.index = int(index)
        self.path = None if path is None else os.fspath(path)
        self.reason = str(reason)
        self.timestamp = None if timestamp is None else float(timestamp)


class FrameFileMissing(FrameReadError, FileNotFoundError):
    """A :class:`FrameReadError` whose file is missing: also a ``FileNotFoundError``,
    as a missing file is everywhere else."""


class ImageSizeMismatch(InputError):
    """An image whose size is not its sequence's camera's (the first image's):
    raised by :class:`spgeo.datasets.common.FrameSequence` as it is, not as a
    :class:`FrameReadError`, so a batch runner refuses the input instead of
    skipping the frames (issue 53)."""


def check_input_file(path, what: str = "input") -> str:
    """Return ``os.fspath(path)`` if it names a readable, non-empty regular file.

    Raises ``FileNotFoundError`` when nothing is there, :class:`InputError` for a
    folder, something that is not a regular file, a file this process may not
    read (permission denied) or an empty file; messages name ``what`` and the path.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{what} file not found: {path}")
    if os.path.isdir(path):
        raise InputError(f"{what} path {path} is a folder, not a file")
    if not os.path.isfile(path):
        raise InputError(f"{what} path {path} is not a regular file")
    if not os.access(path, os.R_OK):
        raise InputError(f"cannot read {what} file {path} (permission denied)")
    if os.path.getsize(path) == 0:
        raise InputError(f"{what} file {path} is empty (0 bytes)")
    return path


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_STANDALONE = frozenset([0x01] + list(range(0xD0, 0xD8)))


def _png_complete(data: bytes) -> bool:
    """True when the chunks of a PNG reach an IEND chunk inside ``data``."""
    pos = len(_PNG_SIGNATURE)
    while pos + 12 <= len(data):
        end = pos + 12 + int.from_bytes(data[pos:pos + 4], "big")
        if end > len(data):
            return False
        if data[pos + 4:pos + 8] == b"IEND":
            return True
        pos = end
    return False


def _jpeg_complete(data: bytes) -> bool:
    """True when a JPEG's header segments lead to a scan followed by an EOI marker."""
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return False
        marker = data[pos + 1]
        if marker == 0xFF:            # fill byte
            pos += 1
        elif marker == 0xDA:          # start of scan: entropy-coded data up to EOI
            return data.find(b"\xff\xd9", pos + 2) != -1
        elif marker in _JPEG_STANDALONE:
            pos += 2
        else:
            pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
    return False


def read_image_bytes(path, what: str = "image") -> bytes:
    """The bytes of an image file, after :func:`check_input_file`.

    PNG and JPEG files (recognised by their signature) must be complete: a PNG
    must reach its IEND chunk, a JPEG its end-of-image marker after the first
    scan; otherwise :class:`InputError` says the file is truncated or corrupt
    (decoders would otherwise return a partly grey image with a warning that
    names no file).  Bytes after the end marker are allowed.
    """
    path = check_input_file(path, what)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except PermissionError:
        raise InputError(f"cannot read {what} file {path} (permission denied)") from None
    except OSError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc.strerror or exc}") from None
    if data.startswith(_PNG_SIGNATURE):
        fmt, complete = "PNG", _png_complete(data)
    elif data.startswith(b"\xff\xd8\xff"):
        fmt, complete = "JPEG", _jpeg_complete(data)
    else:
        return data
    if not complete:
        raise InputError(f"{what} file {path} is a truncated or corrupt {fmt} "
                         f"({len(data)} bytes, no end marker)")
    return data
