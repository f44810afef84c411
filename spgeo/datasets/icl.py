"""ICL-NUIM reader (living-room / office-room, TUM-style PNG release).

Layout::

    color/N.png  (or rgb/N.png)   colour, 640x480
    depth/N.png                   uint16, metres x 5000 (0 = no measurement)
    pose.txt                      "tx ty tz qx qy qz qw" per line: line k <-> frame k + 1
                                  (or "n tx ty tz qx qy qz qw": the first column is N)

* Frame number = ``N`` of the file name; ``Frame.timestamp`` is the frame
  number (as a float; ICL-NUIM has no timestamps).
* **Convention.**  ICL-NUIM's intrinsics are fx 481.20, fy **-480.00**, cx 319.5,
  cy 239.5: the data's camera y axis points *up* the image (a left-handed
  camera frame, from POV-Ray).  spgeo's camera is OpenCV's (y down, fy > 0).
  With ``S = diag(1, -1, 1, 1)`` a point of the data's camera frame is
  ``S x_ours``, so the reader keeps the images unchanged, uses fy = +480 and
  returns ``T_world_cam = S @ T_file @ S`` (a proper rigid transform, in a
  world frame whose y axis is the file's y negated).  Relative poses are then
  ``S T_rel S`` (checked by photometric warps in ``tests/test_datasets.py``).
* **Depth** in these PNGs is z-depth along the optical axis (not ray length).
* The images have no distortion; a given camera with distortion
  (``--calibration``) is undistorted, images and depth alike.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..geometry import pose_from_tum
from .common import FileRecord, FrameSelection, FrameSequence, check_camera, numbered_frames
from .files import PathLike, read_depth_png, read_rgb

__all__ = ["ICLConfig", "ICLSequence", "ICL_CAMERA", "icl_pose_to_opencv", "read_icl_poses"]

logger = logging.getLogger(__name__)

#: ICL-NUIM intrinsics in spgeo's convention (the data's fy = -480 flipped to +480).
ICL_CAMERA = PinholeCamera(481.20, 480.00, 319.5, 239.5, 640, 480)

_S = np.diag([1.0, -1.0, 1.0, 1.0])
_NUM_RE = re.compile(r"^(\d+)\.png$", re.IGNORECASE)


def icl_pose_to_opencv(T_file: np.ndarray) -> np.ndarray:
    """Convert an ICL-NUIM camera-to-world pose (fy < 0 camera) to spgeo's
    convention: ``S @ T @ S`` with ``S = diag(1, -1, 1, 1)``."""
    return _S @ np.asarray(T_file, dtype=np.float64) @ _S


def read_icl_poses(path: PathLike, first_frame: int = 1) -> Dict[int, np.ndarray]:
    """Parse an ICL-NUIM pose file into ``{frame number: T_file}`` (file convention).

    7 columns ``tx ty tz qx qy qz qw``: line k (0-based, comments and blank lines
    skipped) is frame ``first_frame + k``.  8 columns: the first is the frame number.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ICL-NUIM pose file not found: {path}")
    poses: Dict[int, np.ndarray] = {}
    k = 0
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tok = s.split()
        try:
            vals = [float(x) for x in tok]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: malformed pose line") from None
        if len(vals) == 7:
            n = first_frame + k
        elif len(vals) == 8:
            if vals[0] != int(vals[0]):
                raise ValueError(f"{path}:{lineno}: first column {tok[0]!r} is not a frame number")
            n, vals = int(vals[0]), vals[1:]
        else:
            raise ValueError(f"{path}:{lineno}: malformed pose line, expected 7 or 8 numbers, "
                             f"got {len(vals)}")
        try:
            poses[n] = pose_from_tum(vals)
        except ValueError as exc:
            raise ValueError(f"{path}:{lineno}: {exc}") from None
        k += 1
    return poses


@config_class
@dataclass
class ICLConfig:
    """Options of :class:`ICLSequence`.

    Attributes:
        intrinsics: camera in spgeo's convention (fy > 0); default None uses
            :data:`ICL_CAMERA` (481.20, 480.00, 319.5, 239.5).
        load_depth: read depth maps (default True).
        load_pose: read and convert ground-truth poses (default True).
        frames: selection by frame number ``N`` (``"A:B[:S]"``, slice, range,
            list; default None = all).
        pose_file: pose file name inside the folder (default ``"pose.txt"``).
        pose_first_frame: frame number of the first line of a 7-column pose
            file (default 1: line k <-> ``N = k + 1``).
        depth_scale: raw depth units per metre (default 5000).
    """

    intrinsics: Optional[PinholeCamera] = None
    load_depth: bool = True
    load_pose: bool = True
    frames: FrameSelection = None
    pose_file: str = "pose.txt"
    pose_first_frame: int = 1
    depth_scale: float = 5000.0


class ICLSequence(FrameSequence):
    """Lazy reader of an ICL-NUIM sequence folder (see the module docstring)."""

    def __init__(self, path: PathLike, config: Optional[ICLConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, ICLConfig, config, kwargs, "ICL-NUIM sequence folder")
        root = self.root
        self._raw_camera = check_camera(
            cfg.intrinsics if cfg.intrinsics is not None else ICL_CAMERA, "ICLConfig.intrinsics")

        color_dir = next((root / d for d in ("color", "rgb") if (root / d).is_dir()), None)
        if color_dir is None:
            raise FileNotFoundError(f"no color/ (or rgb/) folder in ICL-NUIM sequence {root}")
        found, selected = numbered_frames(color_dir, _NUM_RE, "images", cfg.frames,
                                          lambda: f"no N.png images in {color_dir}")

        poses: Dict[int, np.ndarray] = {}
        if cfg.load_pose:
            pose_path = root / cfg.pose_file
            if pose_path.is_file():
                poses = read_icl_poses(pose_path, cfg.pose_first_frame)
                missing = [n for n in selected if n not in poses]
                if missing:
                    logger.warning("%s: no pose for %d selected frames (e.g. %s)", pose_path,
                                   len(missing), missing[:5])
            else:
                logger.info("%s: no %s, frames will have no pose", root, cfg.pose_file)

        self._records = []
        for n in selected:
            T = poses.get(n)
            self._records.append(FileRecord(n, float(n), found[n], root / "depth" / found[n].name,
                                            None if T is None else icl_pose_to_opencv(T)))

    def _load(self, index: int, rec: FileRecord) -> Frame:
        image = self._finish_image(read_rgb(rec.color_path, self._raw_camera))
        depth = None
        if self.config.load_depth:
            depth = self._finish_depth(read_depth_png(rec.depth_path, self.config.depth_scale,
                                                      self._raw_camera))
        meta = {"dataset": "icl", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "depth_path": str(rec.depth_path) if depth is not None else None,
                "depth_registered": True, "timestamp_is_frame_number": True,
                "pose_convention": "S @ T_file @ S, S = diag(1, -1, 1, 1)"}
        return Frame(image=image, camera=self.camera, timestamp=rec.timestamp, depth=depth,
                     T_world_cam=self._pose(rec),
                     name=rec.color_path.stem, meta=meta)
