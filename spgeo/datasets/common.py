"""Shared machinery of the data-set readers.

* :func:`parse_frame_range` / :func:`select_frames`: the ``--frames A:B[:S]``
  selection by *frame number* (``A <= n < B`` and ``(n - A) % S == 0``).
* :class:`FrameSequence`: the lazy random-access sequence every reader is
  (``len``, ``seq[i]``, ``seq[a:b]`` -> list, iteration, ``.camera``, ``.name``).
* image / depth / pose file helpers that raise clear errors naming the file.
* :func:`warp_image` / :func:`photometric_error`: warp a target image into a
  reference view with the reference depth and a relative pose (used to check
  pose conventions of data sets).
"""
from __future__ import annotations

import json
import logging
import os
import re
from abc import abstractmethod
from collections.abc import Sequence as _SequenceABC
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from ..geometry import transform_points
from ..images import load_image, sample_bilinear, to_gray

__all__ = [
    "FrameSelection", "parse_frame_range", "select_frames", "FrameSequence", "read_rgb",
    "read_depth_png", "read_camera_json", "nearest_rigid", "warp_image", "photometric_error",
]

logger = logging.getLogger(__name__)

#: A frame selection: ``None`` (all), a ``slice`` / ``range`` over frame numbers,
#: an explicit list of frame numbers, or a string ``"A:B[:S]"``.
FrameSelection = Union[None, slice, range, Sequence[int], str]

PathLike = Union[str, os.PathLike]


# --------------------------------------------------------------------- frames
def parse_frame_range(spec: str) -> slice:
    """Parse ``"A:B[:S]"`` into ``slice(A, B, S)`` over frame numbers.

    Any part may be empty (``"100:"``, ``":50"``, ``"::2"``); a single number
    ``"A"`` selects frame ``A`` only (``slice(A, A + 1)``).  Numbers must be
    non-negative integers and the step >= 1.  Raises ``ValueError`` otherwise.
    """
    if not isinstance(spec, str):
        raise TypeError(f"parse_frame_range: expected a string, got {type(spec).__name__}")
    text = spec.strip()
    parts = text.split(":")
    if not text or len(parts) > 3:
        raise ValueError(f"invalid frame range {spec!r}: expected 'A:B[:STEP]'")

    def _int(s: str, what: str) -> Optional[int]:
        s = s.strip()
        if not s:
            return None
        if not re.fullmatch(r"[+]?\d+", s):
            raise ValueError(f"invalid frame range {spec!r}: {what} {s!r} is not a "
                             "non-negative integer")
        return int(s)

    if len(parts) == 1:
        a = _int(parts[0], "frame")
        return slice(a, a + 1, None)
    start = _int(parts[0], "start")
    stop = _int(parts[1], "stop")
    step = _int(parts[2], "step") if len(parts) == 3 else None
    if step is not None and step < 1:
        raise ValueError(f"invalid frame range {spec!r}: step must be >= 1")
    return slice(start, stop, step)


def read_matrix_file(path: PathLike, shape) -> np.ndarray:
    """Read a whitespace-separated matrix file, raising ``ValueError`` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"file not found: {path}")
    try:
        values = np.array([float(x) for x in path.read_text(encoding="utf-8").split()])
    except ValueError as exc:
        raise ValueError(f"malformed matrix file {path}: {exc}") from None
    if values.size != int(np.prod(shape)):
        raise ValueError(f"malformed matrix file {path}: expected {int(np.prod(shape))} numbers "
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
                raise ValueError(f"{folder}: frame {n} has two {what} "
                                 f"({found[n].name}, {p.name})")
            found[n] = p
    return found


def select_frames(numbers: Sequence[int], selection: FrameSelection) -> List[int]:
    """Positions (into ``numbers``) of the frames chosen by ``selection``.

    ``numbers`` are the frame numbers of the available frames (increasing).
    A slice / range / ``"A:B:S"`` keeps frame numbers ``n`` with ``A <= n < B``
    and ``(n - A) % S == 0`` (``A`` defaults to the first frame number, ``B`` to
    no limit, ``S`` to 1).  A list keeps exactly those frame numbers, in the
    given order.  Raises ``ValueError`` for unknown numbers, negative bounds or
    an empty result.
    """
    numbers = [int(n) for n in numbers]
    if selection is None:
        return list(range(len(numbers)))
    if isinstance(selection, str):
        selection = parse_frame_range(selection)
    if isinstance(selection, range):
        selection = slice(selection.start, selection.stop, selection.step)
    if isinstance(selection, slice):
        start, stop, step = selection.start, selection.stop, selection.step
        for what, val in (("start", start), ("stop", stop)):
            if val is not None and int(val) < 0:
                raise ValueError(f"frame selection {what} must be >= 0 (frame numbers), got {val}")
        step = 1 if step is None else int(step)
        if step < 1:
            raise ValueError(f"frame selection step must be >= 1, got {step}")
        if not numbers:
            raise ValueError("frame selection: the data set has no frames")
        base = min(numbers) if start is None else int(start)
        keep = [i for i, n in enumerate(numbers)
                if n >= base and (stop is None or n < int(stop)) and (n - base) % step == 0]
        desc = f"{'' if start is None else start}:{'' if stop is None else stop}:{step}"
    else:
        wanted = [int(n) for n in selection]
        pos = {n: i for i, n in enumerate(numbers)}
        missing = [n for n in wanted if n not in pos]
        if missing:
            raise ValueError(f"frame selection: unknown frame numbers {missing[:10]}"
                             f"{' ...' if len(missing) > 10 else ''}")
        keep = [pos[n] for n in wanted]
        desc = f"{len(wanted)} explicit frame numbers"
    if not keep:
        rng = f"{min(numbers)}..{max(numbers)}" if numbers else "none"
        raise ValueError(f"frame selection {desc} selects no frames (available frame numbers: "
                         f"{rng}, {len(numbers)} frames)")
    return keep


# ------------------------------------------------------------------ sequence
class FrameSequence(_SequenceABC):
    """Lazy random-access sequence of :class:`~spgeo.frame.Frame`.

    ``seq[i]`` loads frame ``i`` of the *selection* (0-based position; negative
    indices count from the end), ``seq[a:b]`` returns a list of frames.  Nothing
    is cached except the undistortion maps.  ``frame_numbers`` gives the data
    set's frame number of each position, ``timestamps`` their times.

    Subclasses set ``self._raw_camera`` (the camera of the files, possibly with
    distortion), ``self._undistort``, ``self._name`` and the per-frame records
    (``self._records``), and implement :meth:`_load`.
    """

    _raw_camera: PinholeCamera
    _undistort: bool
    _name: str
    _records: List[Any]

    def __init__(self) -> None:
        self._maps: Optional[Tuple[np.ndarray, np.ndarray]] = None

    # -- public API
    @property
    def name(self) -> str:
        """Sequence name (the folder name)."""
        return self._name

    @property
    def camera(self) -> PinholeCamera:
        """Camera of the returned images (undistorted when ``undistort`` is on)."""
        if self._undistort:
            return self._raw_camera.undistorted()
        return self._raw_camera

    @property
    def raw_camera(self) -> PinholeCamera:
        """Camera of the image files as stored (with distortion, if any)."""
        return self._raw_camera

    @property
    def frame_numbers(self) -> List[int]:
        """Data-set frame number of every position of the selection."""
        return [int(r.number) for r in self._records]

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) float64 timestamps in seconds (frame numbers where the data set has none)."""
        return np.array([float(r.timestamp) for r in self._records], dtype=np.float64)

    def ground_truth(self) -> List[Optional[np.ndarray]]:
        """Camera-to-world ground-truth poses of the selection, ``None`` where unknown,
        without reading images (readers with ground truth override this)."""
        return [None] * len(self)

    def __len__(self) -> int:
        return len(self._records)

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return [self._get(i) for i in range(*index.indices(len(self)))]
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"{type(self).__name__} indices must be integers or slices, "
                            f"got {type(index).__name__}")
        i = int(index)
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{type(self).__name__} index {index} out of range for {n} frames")
        return self._get(i)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self._get(i)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(name={self.name!r}, frames={len(self)}, "
                f"camera={self.camera!r})")

    # -- helpers for subclasses
    def _get(self, i: int) -> Frame:
        return self._load(i, self._records[i])

    @abstractmethod
    def _load(self, index: int, record: Any) -> Frame:
        """Load the frame at position ``index`` described by ``record``."""

    def _undistortion_maps(self) -> Optional[Tuple[np.ndarray, np.ndarray]]:
        if not self._undistort or self._raw_camera.distortion is None:
            return None
        if self._maps is None:
            self._maps = self._raw_camera.undistortion_maps()
        return self._maps

    def _finish_image(self, image: np.ndarray) -> np.ndarray:
        maps = self._undistortion_maps()
        if maps is None:
            return image
        return np.clip(self._raw_camera.undistort_image(image, maps=maps), 0.0, 1.0)

    def _finish_depth(self, depth: np.ndarray) -> np.ndarray:
        """Undistort a float depth map (NaN invalid) with nearest-neighbour sampling."""
        import cv2

        maps = self._undistortion_maps()
        if maps is None:
            return depth
        return cv2.remap(depth, maps[0], maps[1], cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


# ---------------------------------------------------------------- file I/O
def read_rgb(path: PathLike, camera: Optional[PinholeCamera] = None) -> np.ndarray:
    """Read a colour image as float32 RGB (H, W, 3) in [0, 1].

    Grey files are replicated to three channels.  Raises ``FileNotFoundError``
    for a missing file, ``ValueError`` for an undecodable one or (with
    ``camera``) a size that does not match the camera; messages name the file.
    """
    image = load_image(path)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    if camera is not None and image.shape[:2] != camera.shape:
        raise ValueError(f"image {os.fspath(path)} has shape {image.shape}, expected "
                         f"({camera.height}, {camera.width}, 3) for {camera!r}")
    return np.ascontiguousarray(image, dtype=np.float32)


def read_depth_png(path: PathLike, scale: float, camera: Optional[PinholeCamera] = None,
                   invalid_values: Sequence[int] = (0,), dtype=np.float32) -> np.ndarray:
    """Read a uint16 depth PNG as metres (``raw / scale``, in ``dtype``), NaN where invalid.

    ``invalid_values`` are raw values meaning "no measurement" (0 by default).
    Raises ``FileNotFoundError`` / ``ValueError`` naming the file.
    """
    import cv2

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"depth file not found: {path}")
    raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise ValueError(f"cannot decode depth file: {path}")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise ValueError(f"depth file {path} must be a single-channel 16-bit (uint16) image, "
                         f"got shape {raw.shape} dtype {raw.dtype}")
    if camera is not None and raw.shape != camera.shape:
        raise ValueError(f"depth file {path} has shape {raw.shape}, expected "
                         f"({camera.height}, {camera.width}) for {camera!r}")
    depth = raw.astype(dtype) / np.asarray(scale, dtype=dtype)
    invalid = np.isin(raw, np.asarray(invalid_values, dtype=raw.dtype))
    depth[invalid] = np.nan
    return depth


def read_camera_json(path: PathLike) -> PinholeCamera:
    """Read a ``camera.json`` written with :meth:`PinholeCamera.to_dict`."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        return PinholeCamera.from_dict(data)
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"invalid camera file {path}: {exc}") from exc


def nearest_rigid(T: np.ndarray, name: str = "pose", tol: float = 1e-2) -> np.ndarray:
    """Project an almost-rigid 4x4 matrix onto SE(3) (SVD of the rotation block).

    Data-set poses are often stored with a few 1e-4 of rotation error (7-Scenes);
    :class:`~spgeo.frame.Frame` requires 1e-5.  Raises ``ValueError`` when the
    matrix is non-finite or further than ``tol`` from a rigid transform.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: expected a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if (np.abs(R @ R.T - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol
            or np.abs(T[3] - [0, 0, 0, 1]).max() > tol):
        raise ValueError(f"{name}: not a rigid transform (rotation not orthonormal or last row "
                         "not [0 0 0 1])")
    U, _, Vt = np.linalg.svd(R)
    out = np.eye(4)
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out[:3, 3] = T[:3, 3]
    return out



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
        raise ValueError(f"invalid pose file {path}: {exc}") from None

def check_selection_files(paths: Sequence[Path], what: str) -> None:
    """Raise ``FileNotFoundError`` naming the first listed file that does not exist."""
    for p in paths:
        if not p.is_file():
            raise FileNotFoundError(f"{what} file listed but missing: {p}")


# ------------------------------------------------------------------- warping
def warp_image(image_tgt: np.ndarray, depth_ref: np.ndarray, camera: PinholeCamera,
               T_tgt_ref: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Warp ``image_tgt`` into the reference view.

    Every reference pixel with valid depth is unprojected, mapped into the
    target camera with ``T_tgt_ref = inv(T_world_tgt) @ T_world_ref``,
    projected and sampled bilinearly.  Both images use ``camera`` (undistorted).

    Returns:
        ``(warped, valid)``: the target image as seen from the reference view
        (float32, same shape as ``image_tgt``; 0 where invalid) and the (H, W)
        mask of pixels with valid depth that land inside the target image in
        front of the camera.
    """
    camera.check_image(image_tgt, "image_tgt")
    points = camera.unproject_depth_map(depth_ref)  # NaN where invalid
    uv, z = camera.project(transform_points(np.asarray(T_tgt_ref, dtype=np.float64), points))
    values, valid = sample_bilinear(np.asarray(image_tgt, dtype=np.float32),
                                    uv[..., 0], uv[..., 1])
    with np.errstate(invalid="ignore"):
        valid &= z > 0
    mask = valid[..., None] if values.ndim == 3 else valid
    return np.where(mask, values, 0.0).astype(np.float32), valid


def photometric_error(image_ref: np.ndarray, image_tgt: np.ndarray, depth_ref: np.ndarray,
                      camera: PinholeCamera, T_tgt_ref: np.ndarray) -> Tuple[float, float]:
    """Mean absolute grey-level error between ``image_ref`` and the warped target.

    Returns ``(error, valid_fraction)``; the error is NaN when no pixel is valid.
    """
    warped, valid = warp_image(to_gray(image_tgt), depth_ref, camera, T_tgt_ref)
    frac = float(valid.mean())
    if not valid.any():
        return float("nan"), frac
    return float(np.abs(warped - to_gray(image_ref))[valid].mean()), frac


def config_from_kwargs(config_cls, config, kwargs: Dict[str, Any], reader: str):
    """Build a reader config from ``config`` and/or keyword overrides."""
    import dataclasses

    if config is not None and not isinstance(config, config_cls):
        raise TypeError(f"{reader}: config must be a {config_cls.__name__}, "
                        f"got {type(config).__name__}")
    base = config if config is not None else config_cls()
    if not kwargs:
        return base
    names = {f.name for f in dataclasses.fields(config_cls)}
    unknown = sorted(set(kwargs) - names)
    if unknown:
        raise TypeError(f"{reader}: unknown option(s) {unknown}; valid options: {sorted(names)}")
    return dataclasses.replace(base, **kwargs)
