"""Files of the data sets: colour images, uint16 depth PNGs, camera JSON,
whitespace matrices, 4x4 pose files, timestamps (in text files, or as file names:
:func:`stamp_from_name`), numbered frame files.

Every reader raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError`
(a ``ValueError``) with a message naming the file (and line, for text files);
folders, unreadable, empty and truncated files are refused
(:func:`spgeo.validation.check_input_file`, :func:`spgeo.images.read_raw_image`).
"""
from __future__ import annotations

import json
import logging
import os
import re
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..geometry import nearest_rigid as _nearest_rigid
from ..images import load_image, read_raw_image
from ..validation import ImageSizeMismatch, InputError, check_input_file

__all__ = ["PathLike", "read_rgb", "read_depth_png", "read_camera_json", "read_matrix_file",
           "nearest_rigid", "read_pose_file", "check_selection_files", "index_frame_files",
           "parse_stamp", "check_increasing", "yaml_number_list", "stamp_from_name",
           "stamped_files", "NANOSECOND_NAME_DIGITS", "IMAGE_EXTENSIONS"]

logger = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]

#: file extensions (lower case) of the image files a reader lists from a folder
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")


def read_matrix_file(path: PathLike, shape) -> np.ndarray:
    """Read a whitespace-separated matrix file, raising ``FileNotFoundError`` /
    :class:`~spgeo.validation.InputError` naming the file."""
    path = Path(check_input_file(path, "matrix"))
    try:
        values = np.array([float(x) for x in path.read_text(encoding="utf-8").split()])
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"malformed matrix file {path}: {exc}") from None
    if values.size != int(np.prod(shape)):
        raise InputError(f"malformed matrix file {path}: expected {int(np.prod(shape))} numbers "
                         f"({shape[0]}x{shape[1]}), got {values.size}")
    return values.reshape(shape)


def index_frame_files(folder: Path, pattern: "re.Pattern", what: str) -> Dict[int, Path]:
    """Files of ``folder`` whose name matches ``pattern`` (group 1 = frame
    number) -> ``{frame number: path}``.  Two files for one number raise
    ``ValueError`` naming both."""
    found: Dict[int, Path] = {}
    for p in folder.iterdir():
        m = pattern.match(p.name)
        if m:
            n = int(m.group(1))
            if n in found:
                raise InputError(f"{folder}: frame {n} has two {what} "
                                 f"({found[n].name}, {p.name})")
            found[n] = p
    return found


def parse_stamp(tok: str, path: Path, lineno: int) -> float:
    """A finite timestamp from ``tok``; ``ValueError`` naming ``path:lineno`` otherwise."""
    try:
        t = float(tok)
    except ValueError:
        raise InputError(f"{path}:{lineno}: malformed timestamp {tok!r}") from None
    if not np.isfinite(t):
        raise InputError(f"{path}:{lineno}: timestamp {tok!r} is not finite")
    return t


#: an integer file name of at least this many digits is a time in nanoseconds (EuRoC's and
#: ROS's ``1403636579763555584.png``: Unix time in ns has 19 digits since 2001, 18 since
#: 1973); a shorter integer (``000123.png``) is a frame number, not a time
NANOSECOND_NAME_DIGITS = 18
_SECONDS_NAME = re.compile(r"\d+\.\d+")
_NANOSECONDS_NAME = re.compile(r"\d{%d,}" % NANOSECOND_NAME_DIGITS)


def stamp_from_name(stem: str) -> Optional[float]:
    """The time in seconds that a file name (its stem, without the extension) is, or None.

    ``<digits>.<digits>`` is seconds (TUM's ``1305031102.175304``); an integer of
    :data:`NANOSECOND_NAME_DIGITS` or more digits is nanoseconds (EuRoC's
    ``1403636579763555584``, read as EuRoC's ``data.csv`` stamps: ``int * 1e-9``);
    anything else (a shorter integer such as a frame number, a sign, an exponent,
    letters) is not a time.
    """
    if _SECONDS_NAME.fullmatch(stem):
        return float(stem)
    if _NANOSECONDS_NAME.fullmatch(stem):
        return int(stem) * 1e-9
    return None


def stamped_files(paths: Sequence[Path], what: str) -> Tuple[List[Path], np.ndarray]:
    """``paths`` in time order and their times (seconds, (N,) float64) read from their
    names (:func:`stamp_from_name`).

    Raises :class:`~spgeo.validation.InputError` naming the first file whose name is
    not a time, or two files of one time (``1.5.png`` and ``1.50.png``); ``what``
    names the files in the message (e.g. ``"TUM rgb"``).
    """
    stamps = []
    for p in paths:
        t = stamp_from_name(Path(p).stem)
        if t is None:
            raise InputError(f"{what} file {p}: its name is not a timestamp (expected "
                             "<seconds>.<fraction> as 1305031102.175304.png, or integer "
                             f"nanoseconds of >= {NANOSECOND_NAME_DIGITS} digits)")
        stamps.append(t)
    order = np.argsort(np.asarray(stamps, dtype=np.float64), kind="stable")
    ordered = [Path(paths[i]) for i in order]
    times = np.asarray(stamps, dtype=np.float64)[order]
    for k in range(1, len(times)):
        if not times[k] > times[k - 1]:
            raise InputError(f"{what} files {ordered[k - 1]} and {ordered[k]} have the same "
                             f"timestamp {times[k]:.9f}")
    return ordered, times


def check_increasing(stamps: Sequence[float], linenos: Sequence[int], path: Path) -> None:
    """``ValueError`` naming ``path`` and the line of the first stamp not greater
    than its predecessor."""
    for k in range(1, len(stamps)):
        if not stamps[k] > stamps[k - 1]:
            raise InputError(f"{path}:{linenos[k]}: timestamps are not strictly increasing "
                             f"({stamps[k]:.6f} after {stamps[k - 1]:.6f})")


def read_rgb(path: PathLike, camera: Optional[PinholeCamera] = None) -> np.ndarray:
    """Read a colour image as float32 RGB (H, W, 3) in [0, 1].

    Grey files are replicated to three channels.  Raises ``FileNotFoundError``
    for a missing file, :class:`~spgeo.validation.InputError` for a folder, an
    unreadable, empty, truncated or undecodable file or (with ``camera``) a
    size that does not match the camera; messages name the file.
    """
    image = load_image(path)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    if camera is not None and image.shape[:2] != camera.shape:
        raise ImageSizeMismatch(f"image {os.fspath(path)} has shape {image.shape}, expected "
                                f"({camera.height}, {camera.width}, 3) for {camera!r}")
    return np.ascontiguousarray(image, dtype=np.float32)


def read_depth_png(path: PathLike, scale: float, camera: Optional[PinholeCamera] = None,
                   invalid_values: Sequence[int] = (0,), dtype=np.float32) -> np.ndarray:
    """Read a uint16 depth PNG as metres (``raw / scale``, in ``dtype``), NaN where invalid.

    ``invalid_values`` are raw values meaning "no measurement" (0 by default).
    Raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming
    the file (as :func:`read_rgb`; also for an 8-bit or colour image).
    """
    path = os.fspath(path)
    raw = read_raw_image(path, "depth")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise InputError(f"depth file {path} must be a single-channel 16-bit (uint16) image, "
                         f"got shape {raw.shape} dtype {raw.dtype}")
    if camera is not None and raw.shape != camera.shape:
        raise InputError(f"depth file {path} has shape {raw.shape}, expected "
                         f"({camera.height}, {camera.width}) for {camera!r}")
    depth = raw.astype(dtype) / np.asarray(scale, dtype=dtype)
    invalid = np.isin(raw, np.asarray(invalid_values, dtype=raw.dtype))
    depth[invalid] = np.nan
    return depth


def read_camera_json(path: PathLike) -> PinholeCamera:
    """Read a ``camera.json`` written with :meth:`PinholeCamera.to_dict`.

    Raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming
    the file: unreadable or malformed JSON, missing keys, or intrinsics that
    fail :func:`spgeo.validation.check_intrinsics`.
    """
    path = check_input_file(path, "camera")
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        return PinholeCamera.from_dict(data)
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError,
            ValueError) as exc:
        raise InputError(f"invalid camera file {path}: {exc}") from None


def nearest_rigid(T: np.ndarray, name: str = "pose", tol: float = 1e-2) -> np.ndarray:
    """Project an almost-rigid 4x4 matrix onto SE(3) (:func:`spgeo.geometry.nearest_rigid`,
    after checking it is almost rigid).

    Data-set poses are often stored with a few 1e-4 of rotation error (7-Scenes);
    :class:`~spgeo.frame.Frame` requires 1e-5.  Raises ``ValueError`` when the
    matrix is non-finite or further than ``tol`` from a rigid transform.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{name}: expected a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if (np.abs(R @ R.T - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol
            or np.abs(T[3] - [0, 0, 0, 1]).max() > tol):
        raise InputError(f"{name}: not a rigid transform (rotation not orthonormal or last row "
                         "not [0 0 0 1])")
    return _nearest_rigid(T)


def read_pose_file(path: PathLike, dataset: str, read_matrix) -> Optional[np.ndarray]:
    """A 4x4 camera-to-world pose file -> rigid 4x4, or None (with a log line)
    when the file is missing or holds non-finite values (invalid poses).

    ``read_matrix(path)`` parses the file (raising ``FileNotFoundError`` /
    ``ValueError`` naming it); a matrix too far from rigid raises ``ValueError``.
    """
    path = Path(path)
    if not path.is_file():
        logger.warning("%s: pose file missing: %s", dataset, path)
        return None
    T = read_matrix(path)
    if not np.all(np.isfinite(T)):
        logger.debug("%s: invalid (non-finite) pose in %s", dataset, path)
        return None
    try:
        return nearest_rigid(T, str(path))
    except ValueError as exc:
        raise InputError(f"invalid pose file {path}: {exc}") from None


def check_selection_files(paths: Sequence[Path], what: str) -> None:
    """Raise ``FileNotFoundError`` naming the first listed file that does not
    exist, :class:`~spgeo.validation.InputError` for one that is a folder."""
    for p in paths:
        if os.path.isdir(p):
            raise InputError(f"{what} path listed is a folder, not a file: {p}")
        if not p.is_file():
            raise FileNotFoundError(f"{what} file listed but missing: {p}")


def yaml_number_list(text: str, key: str, path: Path, size: int) -> np.ndarray:
    """The ``size`` numbers of the first line ``key: [a, b, ...]`` (the list possibly
    over several lines) of the YAML ``text`` read from ``path``;
    :class:`~spgeo.validation.InputError` naming the file and key when there is no
    such list of ``size`` finite numbers."""
    m = re.search(rf"^\s*{key}\s*:\s*\[([^\]]*)\]", text, re.MULTILINE)
    try:
        vals = np.array([float(v) for v in m.group(1).replace(",", " ").split()]) if m else None
    except ValueError:
        vals = None
    if vals is None or vals.size != size or not np.all(np.isfinite(vals)):
        raise InputError(f"{path}: '{key}' must be a list of {size} numbers")
    return vals
