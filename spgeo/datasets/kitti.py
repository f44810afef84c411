"""KITTI odometry reader (one ``sequences/XX`` folder).

Layout (Geiger et al., CVPR 2012)::

    sequences/XX/image_0/NNNNNN.png   grey left camera (image_1: grey right,
                                      image_2 / image_3: colour left / right;
                                      image_l / image_r: grey left / right, as
                                      image_0 / image_1)
    sequences/XX/calib.txt            "P0: 12 numbers" ... "P3: ...": 3x4 row-major
                                      projection matrices of the rectified cameras
                                      (lines without "Pk:" are P0, P1, ... in order)
    sequences/XX/times.txt            optional: one timestamp (seconds) per frame
    poses/XX.txt                      optional ground truth: one 3x4 row-major
                                      camera-to-world matrix of camera 0 per frame

* The path given is the sequence folder ``sequences/XX``; the ground truth is
  ``../../poses/XX.txt`` (or ``poses.txt`` inside the sequence folder).
* Image folder: ``image_dir`` (default: the first of ``image_0``, ``image_2``,
  ``image_l`` present); the camera is ``K`` of the matching ``Pk`` (``image_k``;
  ``image_l`` / ``image_r``: ``P0`` / ``P1``), no distortion (the images are
  rectified).
* Frame number = ``NNNNNN``; timestamp = line ``NNNNNN`` of ``times.txt``, else
  the frame number divided by :data:`KITTI_FPS`.
* Ground truth ``T_world_cam`` (camera-to-world, OpenCV axes: x right, y down,
  z forward, metres; the world is camera 0 at frame 0) of frame ``n`` is row
  ``n`` of the pose file, moved to camera ``k`` with ``Pk = K [I | t_k]``:
  ``T_world_camk = T_world_cam0 @ [I | -t_k]``.
* A missing ``calib.txt`` raises ``FileNotFoundError`` naming it.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..validation import InputError, check_input_file
from .common import FileRecord, FrameSelection, FrameSequence, numbered_frames
from .files import PathLike, nearest_rigid, parse_stamp, read_rgb

__all__ = ["KITTIConfig", "KITTISequence", "read_kitti_calib", "read_kitti_poses", "KITTI_FPS",
           "IMAGE_DIRS"]

logger = logging.getLogger(__name__)

#: Frame rate of the KITTI odometry recordings (Hz), used without ``times.txt``.
KITTI_FPS = 10.0

_IMAGE_RE = re.compile(r"^(\d+)\.png$", re.IGNORECASE)

#: image folder -> the index k of its projection matrix ``Pk`` in ``calib.txt``
IMAGE_DIRS = {"image_0": 0, "image_1": 1, "image_2": 2, "image_3": 3, "image_l": 0,
              "image_r": 1}
#: the folders looked for, in order, without ``KITTIConfig.image_dir``
DEFAULT_IMAGE_DIRS = ("image_0", "image_2", "image_l")


@config_class
@dataclass
class KITTIConfig:
    """Options of :class:`KITTISequence`.

    Attributes:
        image_dir: ``"image_0"`` ... ``"image_3"``, ``"image_l"`` or ``"image_r"``
            (:data:`IMAGE_DIRS`); default None: the first of ``image_0``,
            ``image_2``, ``image_l`` present.
        load_pose: attach the ground truth when the pose file exists (default True).
        frames: selection by frame number ``NNNNNN`` (``"A:B[:S]"``, slice, range,
            list; default None = all).
        load_depth: accepted for the runner's sake; KITTI odometry has no depth.
        undistort: undistort when a given camera (``--calibration``) carries
            distortion (default True; KITTI's own images are rectified).
    """

    image_dir: Optional[str] = None
    load_pose: bool = True
    frames: FrameSelection = None
    load_depth: bool = False
    undistort: bool = True


def read_kitti_calib(path: PathLike) -> Dict[str, np.ndarray]:
    """``calib.txt`` -> ``{"P0": (3, 4), ...}`` (every ``NAME: 12 numbers`` line; a
    line without ``NAME:`` is ``P<k>``, k counting such lines from 0).

    Raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming
    the file (and line) for a missing file or a malformed line.
    """
    path = Path(check_input_file(path, "KITTI calibration"))
    out: Dict[str, np.ndarray] = {}
    unnamed = 0
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        name, _, rest = line.rpartition(":")
        if not name:
            name, unnamed = f"P{unnamed}", unnamed + 1
        try:
            vals = np.array([float(x) for x in rest.split()])
        except ValueError:
            raise InputError(f"{path}:{lineno}: malformed calibration line") from None
        if vals.size == 12 and np.all(np.isfinite(vals)):
            out[name.strip()] = vals.reshape(3, 4)
        elif name.strip().startswith("P"):
            raise InputError(f"{path}:{lineno}: {name.strip()} needs 12 finite numbers, "
                             f"got {vals.size}")
    return out


def read_kitti_poses(path: PathLike) -> List[np.ndarray]:
    """A KITTI pose file (one 3x4 row-major matrix per line) -> rigid 4x4 matrices
    (:func:`~spgeo.datasets.files.nearest_rigid`).  Raises
    :class:`~spgeo.validation.InputError` naming the file and line otherwise."""
    path = Path(check_input_file(path, "KITTI pose"))
    poses = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            vals = np.array([float(x) for x in line.split()])
        except ValueError:
            raise InputError(f"{path}:{lineno}: malformed pose line") from None
        if vals.size != 12:
            raise InputError(f"{path}:{lineno}: expected 12 numbers (3x4), got {vals.size}")
        poses.append(nearest_rigid(np.vstack([vals.reshape(3, 4), [0, 0, 0, 1]]),
                                   f"{path}:{lineno}"))
    return poses


class KITTISequence(FrameSequence):
    """Lazy reader of a KITTI odometry sequence folder (see the module docstring)."""

    def __init__(self, path: PathLike, config: Optional[KITTIConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, KITTIConfig, config, kwargs, "KITTI sequence folder")
        root = self.root
        calib_path = root / "calib.txt"
        if not calib_path.is_file():
            raise FileNotFoundError(
                f"kitti: calibration file not found: {calib_path} (a KITTI odometry sequence "
                "folder sequences/XX holds calib.txt and image_0/ or image_2/)")
        image_dir = self._image_dir(root, cfg.image_dir)
        k = IMAGE_DIRS[image_dir]
        P = read_kitti_calib(calib_path).get(f"P{k}")
        if P is None:
            raise InputError(f"{calib_path} has no P{k} for {image_dir}")
        found, selected = numbered_frames(root / image_dir, _IMAGE_RE, "images", cfg.frames,
                                          lambda: f"no NNNNNN.png images in {root / image_dir}")
        h, w = read_rgb(found[selected[0]]).shape[:2]
        K = P[:, :3]
        self._raw_camera = PinholeCamera.from_K(K, w, h)
        self._intrinsics_detail = f"{calib_path} P{k}"
        T_cam0_cam = np.eye(4)
        T_cam0_cam[:3, 3] = -np.linalg.solve(K, P[:, 3])
        times = self._times(root / "times.txt")
        poses = self._poses(root) if cfg.load_pose else None
        self._records = []
        for n in selected:
            t = float(times[n]) if times is not None and n < len(times) else n / KITTI_FPS
            T = poses[n] @ T_cam0_cam if poses is not None and n < len(poses) else None
            self._records.append(FileRecord(n, t, found[n], pose=T))

    @staticmethod
    def _image_dir(root: Path, name: Optional[str]) -> str:
        """The image folder: ``name``, else the first of :data:`DEFAULT_IMAGE_DIRS`
        present; :class:`InputError` for a name not in :data:`IMAGE_DIRS`,
        ``FileNotFoundError`` naming the folders looked for otherwise."""
        if name is not None and name not in IMAGE_DIRS:
            raise InputError(f"kitti: image_dir must be one of {sorted(IMAGE_DIRS)}, "
                             f"got {name!r}")
        for cand in (name,) if name is not None else DEFAULT_IMAGE_DIRS:
            if (root / cand).is_dir():
                return cand
        looked = name if name is not None else ", ".join(DEFAULT_IMAGE_DIRS)
        raise FileNotFoundError(f"kitti: no image folder ({looked}) in {root}")

    @staticmethod
    def _times(path: Path) -> Optional[np.ndarray]:
        """``times.txt`` (one stamp per line, seconds) or None when absent."""
        if not path.is_file():
            return None
        stamps = [parse_stamp(s.strip(), path, k)
                  for k, s in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1)
                  if s.strip()]
        return np.asarray(stamps, dtype=np.float64)

    def _poses(self, root: Path) -> Optional[List[np.ndarray]]:
        """Camera-0 poses of ``../../poses/XX.txt`` (or ``poses.txt``), None without."""
        for cand in (root.resolve().parent.parent / "poses" / f"{self._name}.txt",
                     root / "poses.txt"):
            if cand.is_file():
                return read_kitti_poses(cand)
        logger.info("%s: no ground-truth poses", root)
        return None

    def _load(self, index: int, rec: FileRecord) -> Frame:
        image = read_rgb(rec.color_path, self._raw_camera)
        meta = {"dataset": "kitti", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path)}
        return Frame(image=self._finish_image(image), camera=self.camera,
                     timestamp=rec.timestamp, T_world_cam=self._pose(rec),
                     name=rec.color_path.stem, meta=meta)
