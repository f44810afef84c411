"""Shared machinery of the data-set readers.

* :func:`parse_frame_range` / :func:`select_frames`: the ``--frames A:B[:S]``
  selection by *frame number* (``A <= n < B`` and ``(n - A) % S == 0``).
* :class:`FrameSequence`: the lazy random-access sequence every reader is
  (``len``, ``seq[i]``, ``seq[a:b]`` -> list, iteration, ``.camera``, ``.name``),
  with the shared constructor steps (:meth:`FrameSequence._open`,
  :func:`numbered_frames`, :func:`check_camera`, :func:`config_from_kwargs`).
* :class:`FileRecord`: the one per-frame record of every reader (frame number,
  timestamp, image / depth / pose files, the pose read when opening).

The file readers (:mod:`spgeo.datasets.files`) and :func:`warp_image` /
:func:`photometric_error` (:mod:`spgeo.datasets.warp`) are re-exported here.
"""
from __future__ import annotations

import logging
import re
from abc import abstractmethod
from collections.abc import Sequence as _SequenceABC
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from .files import (PathLike, index_frame_files, nearest_rigid, read_camera_json,
                    read_depth_png, read_rgb)
from ..validation import FrameFileMissing, FrameReadError, ImageSizeMismatch, InputError
from .calibration import CameraSpec, guess_camera, intrinsics_report
from .warp import photometric_error, warp_image

log = logging.getLogger(__name__)

__all__ = [
    "FrameSelection", "parse_frame_range", "select_frames", "FrameSequence", "CameraSource", "FileRecord",
    "numbered_frames", "check_camera", "check_depth_scale", "config_from_kwargs", "PathLike", "read_rgb",
    "read_depth_png", "read_camera_json", "nearest_rigid", "warp_image", "photometric_error",
]

#: A frame selection: ``None`` (all), a ``slice`` / ``range`` over frame numbers,
#: an explicit list of frame numbers, or a string ``"A:B[:S]"``.
FrameSelection = Union[None, slice, range, Sequence[int], str]


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


def numbered_frames(folder: Path, pattern: "re.Pattern", what: str, selection: FrameSelection,
                    missing: Callable[[], str]) -> Tuple[Dict[int, Path], List[int]]:
    """Index the files of ``folder`` by frame number (:func:`index_frame_files`) and
    apply ``selection`` (:func:`select_frames`).

    Returns ``(files by frame number, selected frame numbers)``.  Raises
    ``FileNotFoundError(missing())`` when no file matches ``pattern``.
    """
    found = index_frame_files(folder, pattern, what)
    if not found:
        raise FileNotFoundError(missing())
    numbers = sorted(found)
    return found, [numbers[k] for k in select_frames(numbers, selection)]


def check_camera(camera: Any, field: str) -> PinholeCamera:
    """``camera`` itself; ``TypeError("<field> must be a PinholeCamera")`` if it is not one."""
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"{field} must be a PinholeCamera")
    return camera


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
        if stop is not None and int(stop) > max(numbers) + 1 and keep:
            log.warning("frame selection %s reaches past the last frame (%d): %d frames "
                        "selected", desc, max(numbers), len(keep))
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


# ------------------------------------------------------------------ records
@dataclass
class FileRecord:
    """One frame of a reader's selection (the one record type of every
    :class:`FrameSequence`; a reader subclasses it only for a field of its own).

    Attributes:
        number: the data-set frame number.
        timestamp: seconds, or the frame number where the data set has no times.
        color_path: the file the frame's image is read from (for a video, the
            video file; named in :class:`~spgeo.validation.FrameReadError`).
        depth_path: the frame's depth file where the reader knows it when opening,
            else None (no depth, or found when loading, as by the folder reader).
        pose: camera-to-world ground truth read when opening (one pose file of the
            sequence), None where unknown or read per frame from ``pose_path``.
        pose_path: the frame's own pose file (7-Scenes, ScanNet), read by the
            reader's :meth:`FrameSequence._pose`; None where there is none.
    """

    number: int
    timestamp: float
    color_path: Path
    depth_path: Optional[Path] = None
    pose: Optional[np.ndarray] = None
    pose_path: Optional[Path] = None


# ------------------------------------------------------------------ cameras
class CameraSource:
    """The camera side of a reader (:class:`FrameSequence`, the live
    :class:`~spgeo.datasets.video.CameraStream`): ``name``, ``camera``,
    ``raw_camera`` and where the intrinsics come from (:attr:`intrinsics`).

    Subclasses set ``self._raw_camera``, ``self._undistort``, ``self._name`` and,
    when the camera is not the data set's own calibration (source ``"file"``),
    call :meth:`set_camera` or :meth:`_given_or_guessed`.
    """

    _raw_camera: PinholeCamera
    _undistort: bool
    _name: str
    _maps: Optional[Tuple[np.ndarray, np.ndarray]] = None
    _intrinsics_source: str = "file"
    _intrinsics_detail: str = ""

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
    def intrinsics(self) -> Dict[str, Any]:
        """Where the camera comes from and its values
        (:func:`~spgeo.datasets.calibration.intrinsics_report`: ``source``
        ``"file"`` | ``"given"`` | ``"guessed"``, ``fx fy cx cy width height
        distortion`` of :attr:`raw_camera`, ``detail``); ``report.json``'s ``intrinsics``."""
        return intrinsics_report(self._raw_camera, self._intrinsics_source,
                                 self._intrinsics_detail)

    def set_camera(self, camera: Union[PinholeCamera, CameraSpec], detail: str = "") -> None:
        """Replace the reader's camera by one the user gives (source ``"given"``):
        a :class:`PinholeCamera` of the stored image size or a
        :class:`~spgeo.datasets.calibration.CameraSpec` (built at that size; no
        distortion but a calibration file's, which the images then lose when
        the reader undistorts).  Raises :class:`~spgeo.validation.InputError`
        for another size."""
        width, height = self._raw_camera.size
        if isinstance(camera, CameraSpec):
            detail = detail or camera.describe()
            camera = camera.camera(width, height)
        check_camera(camera, "camera")
        if camera.size != (width, height):
            raise InputError(f"{self._name}: the given camera is {camera.width}x{camera.height}, "
                             f"the images {width}x{height}")
        self._raw_camera, self._maps = camera, None
        self._intrinsics_source, self._intrinsics_detail = "given", detail or "camera given"

    def _given_or_guessed(self, camera: Union[None, PinholeCamera, CameraSpec], width: int,
                          height: int, image_path: Optional[Path] = None) -> PinholeCamera:
        """The camera of a reader that may have no calibration: ``camera`` when given
        (a :class:`PinholeCamera`, or a :class:`~spgeo.datasets.calibration.CameraSpec`
        built at ``width`` x ``height``; source ``"given"``), else
        :func:`~spgeo.datasets.calibration.guess_camera` (EXIF of ``image_path``,
        else the default field of view; source ``"guessed"``, a logged warning)."""
        if isinstance(camera, CameraSpec):
            self._intrinsics_source, self._intrinsics_detail = "given", camera.describe()
            return camera.camera(width, height)
        if camera is not None:
            self._intrinsics_source, self._intrinsics_detail = "given", "camera given"
            return check_camera(camera, f"{type(self).__name__} camera")
        guessed, method = guess_camera(width, height, image_path,
                                       str(getattr(self, "root", self._name)))
        self._intrinsics_source, self._intrinsics_detail = "guessed", method
        return guessed


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


# ------------------------------------------------------------------ sequence
class FrameSequence(CameraSource, _SequenceABC):
    """Lazy random-access sequence of :class:`~spgeo.frame.Frame`.

    ``seq[i]`` loads frame ``i`` of the *selection* (0-based position; negative
    indices count from the end), ``seq[a:b]`` returns a list of frames.  Nothing
    is cached except the undistortion maps.  ``frame_numbers`` gives the data
    set's frame number of each position, ``timestamps`` their times.

    Subclasses set ``self._raw_camera`` (the camera of the files, possibly with
    distortion), ``self._undistort``, ``self._name`` and the per-frame records
    (``self._records``, :class:`FileRecord`), and implement :meth:`_load`.
    Where the camera comes from is :attr:`intrinsics` (``"file"``: the data
    set's calibration file or published intrinsics, ``"given"``, ``"guessed"``).
    """

    _records: List[FileRecord]

    def __init__(self) -> None:
        self._maps: Optional[Tuple[np.ndarray, np.ndarray]] = None

    # -- public API
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
        without reading images."""
        return [self._pose(r) for r in self._records]

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
    def _open(self, path: PathLike, config_cls, config, kwargs: Dict[str, Any], what: str):
        """Shared start of a reader constructor; returns the config.

        The config is built by :func:`config_from_kwargs` and checked by
        :meth:`_check_config`; then ``self.config``, ``self.root`` (``path``;
        ``FileNotFoundError`` "``<what>`` not found: ``<path>``" unless it is a
        folder), the name (the folder name) and undistortion
        (``config.undistort``; on for configs without that field: their files
        carry no distortion, a given calibration file may) are set.
        """
        cfg = config_from_kwargs(config_cls, config, kwargs, type(self).__name__)
        self._check_config(cfg)
        self.config = cfg
        root = Path(path).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"{what} not found: {root}")
        self.root = root
        self._name = root.resolve().name
        self._undistort = bool(getattr(cfg, "undistort", True))
        return cfg

    def _check_config(self, config: Any) -> None:
        """Raise ``ValueError`` for invalid option values; here the one every reader
        of depth PNGs shares: ``depth_scale`` (raw units per metre), where the
        config has it, must be a finite number > 0
        (:class:`~spgeo.validation.InputError` naming the value)."""
        if getattr(config, "depth_scale", None) is not None:
            check_depth_scale(config.depth_scale)

    def _pose(self, record: FileRecord) -> Optional[np.ndarray]:
        """Camera-to-world pose of a record: a copy of ``record.pose``, None where
        the record has none (readers with per-frame pose files override this)."""
        return None if record.pose is None else record.pose.copy()

    def _get(self, i: int) -> Frame:
        """Frame ``i`` (:meth:`_load`); a file that cannot be read (the reader's
        :class:`~spgeo.validation.InputError` or ``OSError``) raises
        :class:`~spgeo.validation.FrameReadError` naming the position, the
        frame's image file and the reader's message (for a missing file
        :class:`~spgeo.validation.FrameFileMissing`, also a ``FileNotFoundError``);
        an image of another size than the sequence's camera raises
        :class:`~spgeo.validation.ImageSizeMismatch` (not a frame to skip: the
        input mixes sizes)."""
        record = self._records[i]
        try:
            return self._load(i, record)
        except ImageSizeMismatch as exc:
            raise ImageSizeMismatch(f"frame {i}: {exc}: the input mixes image sizes; give "
                                    "frames of one size (resize them, or split the folder)"
                                    ) from None
        except (InputError, OSError) as exc:
            cls = FrameFileMissing if isinstance(exc, FileNotFoundError) else FrameReadError
            raise cls(i, str(record.color_path), str(exc), record.timestamp) from exc

    @abstractmethod
    def _load(self, index: int, record: FileRecord) -> Frame:
        """Load the frame at position ``index`` described by ``record``."""

    def _finish_depth(self, depth: np.ndarray) -> np.ndarray:
        """Undistort a float depth map (NaN invalid) with nearest-neighbour sampling."""
        import cv2

        maps = self._undistortion_maps()
        if maps is None:
            return depth
        return cv2.remap(depth, maps[0], maps[1], cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


def check_depth_scale(scale: Any) -> float:
    """``scale`` (raw depth-PNG units per metre: 5000 for TUM, 1000 for 16-bit PNGs in
    millimetres) as a float; :class:`~spgeo.validation.InputError` naming the value
    unless it is a finite number > 0."""
    try:
        value = float(scale)
    except (TypeError, ValueError):
        value = float("nan")
    if isinstance(scale, bool) or not (np.isfinite(value) and value > 0):
        raise InputError(f"depth scale must be a finite number > 0 (raw depth units per "
                         f"metre, e.g. 5000 for TUM, 1000 for millimetres), got {scale!r}")
    return value


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
