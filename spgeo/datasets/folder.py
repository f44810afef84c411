"""Plain folder of images plus intrinsics.

Layout::

    *.png | *.jpg | *.jpeg      the images, in natural name order (img2 before img10),
                                or in time order when every name is a timestamp
    camera.json                 PinholeCamera.to_dict() (may carry distortion), or
    intrinsics.txt              "fx fy cx cy" on one line, or a 3x3 K (9 numbers);
                                the size is taken from the first image
    times.txt                   optional: one timestamp (seconds) per image, in order
    depth/<stem>.png            optional: uint16 depth, raw / depth_scale metres
                                (default 1000: millimetres; TUM's is 5000), 0 = no
                                measurement
    depth/<stem>.npy            optional: float depth in metres (<= 0 / non-finite invalid)

* Frame number = 0-based position in the sorted image list; timestamp = frame
  number unless ``times.txt`` exists or the names are timestamps.
* Timestamp names: when *every* image's name is a time
  (:func:`spgeo.datasets.files.stamp_from_name`: ``<seconds>.<fraction>`` as
  TUM's ``1305031102.175304.png``, or an integer of 18 or more digits, in
  nanoseconds, as EuRoC's ``1403636579763555584.png``), the frames are in time
  order and their timestamps are those times in seconds (an info line says
  so), so that ``trajectory.txt`` matches a TUM / EuRoC ground truth; two
  names of one time are an :class:`~spgeo.validation.InputError`.  Shorter
  integers (``000123.png``) are frame numbers, not times.  ``times.txt``, when
  present, still gives the timestamps.
* ``camera`` passed in the config overrides the files; ``camera.json`` wins
  over ``intrinsics.txt``; with neither, the intrinsics are guessed
  (:func:`spgeo.datasets.calibration.guess_camera`, a warning) and
  ``intrinsics["source"]`` is ``"guessed"``.
* Frames without a depth file have ``depth=None``; no ground-truth poses.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..validation import InputError
from .calibration import CameraSpec
from .common import FileRecord, FrameSelection, FrameSequence, select_frames
from .files import (IMAGE_EXTENSIONS, PathLike, parse_stamp, read_camera_json, read_depth_png,
                    read_rgb, stamp_from_name, stamped_files)

__all__ = ["FolderConfig", "FolderSequence", "read_intrinsics_txt"]

logger = logging.getLogger(__name__)


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def read_intrinsics_txt(path: PathLike, width: int, height: int) -> PinholeCamera:
    """Camera from ``intrinsics.txt``: ``fx fy cx cy`` (4 numbers) or a 3x3 K (9 numbers)."""
    path = Path(path)
    try:
        vals = [float(x) for line in path.read_text(encoding="utf-8").splitlines()
                if line.strip() and not line.strip().startswith("#")
                for x in line.replace(",", " ").split()]
    except ValueError:
        raise ValueError(f"malformed intrinsics file {path}: non-numeric value") from None
    try:
        if len(vals) == 4:
            return PinholeCamera(vals[0], vals[1], vals[2], vals[3], width, height)
        if len(vals) == 9:
            return PinholeCamera.from_K(np.reshape(vals, (3, 3)), width, height)
    except ValueError as exc:
        raise ValueError(f"invalid intrinsics in {path}: {exc}") from None
    raise ValueError(f"malformed intrinsics file {path}: expected 'fx fy cx cy' or a 3x3 K, "
                     f"got {len(vals)} numbers")


@config_class
@dataclass
class FolderConfig:
    """Options of :class:`FolderSequence`.

    Attributes:
        camera: intrinsics of the stored images: a :class:`PinholeCamera` or a
            :class:`~spgeo.datasets.calibration.CameraSpec` (``--intrinsics`` /
            ``--fov``, built at the images' size); default None reads
            ``camera.json`` or ``intrinsics.txt`` from the folder, else guesses
            (:func:`~spgeo.datasets.calibration.guess_camera`: EXIF, else a
            default field of view; a warning, ``intrinsics["source"] == "guessed"``).
        undistort: undistort when the camera has distortion (default True).
        load_depth: read ``depth/<stem>.png|.npy`` when present (default True).
        frames: selection by frame number (position in the sorted list;
            ``"A:B[:S]"``, slice, range, list; default None = all).
        depth_dir: depth sub-folder name (default ``"depth"``).
        depth_scale: raw PNG depth units per metre (default 1000: 16-bit PNGs in
            millimetres; 5000 for TUM's; ``spgeo vo --depth-scale``); finite and > 0.
        extensions: image file extensions, case-insensitive (default png, jpg, jpeg).
    """

    camera: Union[None, PinholeCamera, CameraSpec] = None
    undistort: bool = True
    load_depth: bool = True
    frames: FrameSelection = None
    depth_dir: str = "depth"
    depth_scale: float = 1000.0
    extensions: Tuple[str, ...] = IMAGE_EXTENSIONS


class FolderSequence(FrameSequence):
    """Lazy reader of a plain image folder (see the module docstring)."""

    def __init__(self, path: PathLike, config: Optional[FolderConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, FolderConfig, config, kwargs, "image folder")
        root = self.root
        images, times = self._images(cfg.extensions)
        self._raw_camera = self._resolve_camera(cfg.camera, images[0])
        times_path = root / "times.txt"
        if times_path.is_file():
            times = self._read_times(times_path, len(images))
        keep = select_frames(range(len(images)), cfg.frames)
        self._records = [FileRecord(k, float(times[k]), images[k]) for k in keep]

    def _images(self, extensions) -> Tuple[List[Path], np.ndarray]:
        """The image files and their timestamps (module docstring): in time order,
        timed by their names when every name is a time, else in natural name order,
        timed by their positions."""
        root = self.root
        exts = tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)
        images = sorted((p for p in root.iterdir() if p.is_file() and p.suffix.lower() in exts),
                        key=lambda p: _natural_key(p.name))
        if not images:
            raise FileNotFoundError(f"no images ({', '.join(exts)}) in {root}")
        stems = [p.stem for p in images]
        if len(set(stems)) != len(stems):
            dup = sorted({s for s in stems if stems.count(s) > 1})
            raise ValueError(f"{root}: several images share a stem: {dup[:5]}")
        if all(stamp_from_name(s) is not None for s in stems):
            images, times = stamped_files(images, "image")
            logger.info("%s: the %d image names are timestamps: frames in time order, "
                        "timed by their names (%.6f to %.6f s)", root, len(images), times[0],
                        times[-1])
            return images, times
        return images, np.arange(len(images), dtype=np.float64)

    def _resolve_camera(self, camera, first_image: Path) -> PinholeCamera:
        """Given camera, else ``camera.json``, else ``intrinsics.txt`` (source
        ``"file"``), else a guess (:meth:`FrameSequence._given_or_guessed`)."""
        if camera is None and (self.root / "camera.json").is_file():
            self._intrinsics_detail = str(self.root / "camera.json")
            return read_camera_json(self.root / "camera.json")
        if isinstance(camera, PinholeCamera):
            return self._given_or_guessed(camera, camera.width, camera.height)
        h, w = read_rgb(first_image).shape[:2]
        if camera is None and (self.root / "intrinsics.txt").is_file():
            self._intrinsics_detail = str(self.root / "intrinsics.txt")
            return read_intrinsics_txt(self.root / "intrinsics.txt", w, h)
        return self._given_or_guessed(camera, w, h, first_image)

    @staticmethod
    def _read_times(path: Path, n: int) -> np.ndarray:
        stamps = []
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            t = parse_stamp(s, path, lineno)
            if stamps and not t > stamps[-1]:
                raise ValueError(f"{path}:{lineno}: timestamps are not strictly increasing")
            stamps.append(t)
        if len(stamps) != n:
            raise ValueError(f"{path} has {len(stamps)} timestamps for {n} images")
        return np.asarray(stamps, dtype=np.float64)

    def _read_depth(self, stem: str) -> Tuple[Optional[np.ndarray], Optional[Path]]:
        ddir = self.root / self.config.depth_dir
        png, npy = ddir / f"{stem}.png", ddir / f"{stem}.npy"
        if png.is_file():
            return read_depth_png(png, self.config.depth_scale, self._raw_camera), png
        if npy.is_file():
            try:
                depth = np.load(npy, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise InputError(f"cannot read depth file {npy}: {exc}") from None
            if depth.shape != self._raw_camera.shape or not np.issubdtype(depth.dtype, np.floating):
                raise InputError(f"depth file {npy} must be a float (H, W) = "
                                 f"{self._raw_camera.shape} array, got {depth.dtype} {depth.shape}")
            depth = depth.astype(np.float32)
            with np.errstate(invalid="ignore"):
                depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
            return depth, npy
        return None, None

    def _load(self, index: int, rec: FileRecord) -> Frame:
        image = self._finish_image(read_rgb(rec.color_path, self._raw_camera))
        depth, depth_path = (None, None)
        if self.config.load_depth:
            depth, depth_path = self._read_depth(rec.color_path.stem)
            if depth is not None:
                depth = self._finish_depth(depth)
        meta = {"dataset": "folder", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "depth_path": None if depth_path is None else str(depth_path),
                "depth_registered": True}
        return Frame(image=image, camera=self.camera, timestamp=rec.timestamp, depth=depth,
                     name=rec.color_path.stem, meta=meta)
