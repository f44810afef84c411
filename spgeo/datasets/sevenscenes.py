"""Microsoft 7-Scenes reader (one ``seq-XX`` folder).

Layout::

    frame-NNNNNN.color.png|jpg   colour, 640x480
    frame-NNNNNN.depth.png       uint16 millimetres; 0 and 65535 = no measurement
    frame-NNNNNN.pose.txt        4x4 camera-to-world
    camera-intrinsics.txt        optional 3x3 K (default fx = fy = 585, cx 320, cy 240)

* Frame number = ``NNNNNN``.  7-Scenes has no timestamps: ``Frame.timestamp``
  is the frame number (as a float), *not* seconds.
* The depth maps are **not registered** to the colour images (the Kinect depth
  camera is a different sensor with other intrinsics and a small baseline).
  They are returned as an approximate depth in the colour view and
  ``Frame.meta['depth_registered']`` is False: use them for coarse checks, not
  as accurate per-pixel ground truth.
* Stored poses carry rotation errors of up to a few 1e-4; they are projected
  onto SE(3) (nearest rotation).  A missing or non-finite pose file gives
  ``T_world_cam=None`` with a warning.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from .common import (FileRecord, FrameSelection, FrameSequence, check_camera, numbered_frames,
                     select_frames)
from .files import (PathLike, index_frame_files, read_depth_png, read_matrix_file,
                    read_pose_file, read_rgb)

__all__ = ["SevenScenesConfig", "SevenScenesSequence", "SEVEN_SCENES_CAMERA",
           "read_matrix_file"]

logger = logging.getLogger(__name__)

#: Default 7-Scenes colour intrinsics (640x480).
SEVEN_SCENES_CAMERA = PinholeCamera(585.0, 585.0, 320.0, 240.0, 640, 480)

_COLOR_RE = re.compile(r"^frame-(\d+)\.color\.(png|jpg|jpeg)$", re.IGNORECASE)
_POSE_RE = re.compile(r"^frame-(\d+)\.pose\.txt$", re.IGNORECASE)


def _frame_stem(color_path: Path) -> str:
    """``frame-NNNNNN`` of a colour image ``frame-NNNNNN.color.png|jpg`` (its depth
    and pose files are ``<stem>.depth.png`` and ``<stem>.pose.txt``)."""
    return color_path.name[:color_path.name.lower().index(".color.")]


@config_class
@dataclass
class SevenScenesConfig:
    """Options of :class:`SevenScenesSequence`.

    Attributes:
        intrinsics: camera of the colour images; default None reads
            ``camera-intrinsics.txt`` if present, else fx = fy = 585, cx 320, cy 240.
        undistort: undistort when ``intrinsics`` carries distortion (default True;
            7-Scenes images themselves have none).
        load_depth: read the (unregistered, approximate) depth maps (default True).
        load_pose: read the pose files (default True).
        frames: selection by frame number ``NNNNNN`` (``"A:B[:S]"``, slice,
            range or list; default None = all).
        depth_scale: raw depth units per metre (default 1000: millimetres).
    """

    intrinsics: Optional[PinholeCamera] = None
    undistort: bool = True
    load_depth: bool = True
    load_pose: bool = True
    frames: FrameSelection = None
    depth_scale: float = 1000.0


class SevenScenesSequence(FrameSequence):
    """Lazy reader of a 7-Scenes sequence folder (see the module docstring)."""

    def __init__(self, path: PathLike, config: Optional[SevenScenesConfig] = None,
                 **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, SevenScenesConfig, config, kwargs, "7-Scenes sequence folder")
        root = self.root

        def missing() -> str:
            subs = sorted(q.name for q in root.iterdir() if q.is_dir() and q.name.startswith("seq"))
            hint = f" (pass one of its sequence folders: {subs})" if subs else ""
            return f"no frame-NNNNNN.color.png|jpg images in {root}{hint}"

        found, poses, selected = self._frames(root, cfg.frames, missing)

        if cfg.intrinsics is not None:
            self._raw_camera = check_camera(cfg.intrinsics, "SevenScenesConfig.intrinsics")
        elif (root / "camera-intrinsics.txt").is_file():
            K = read_matrix_file(root / "camera-intrinsics.txt", (3, 3))
            self._raw_camera = PinholeCamera.from_K(K, 640, 480)
        else:
            self._raw_camera = SEVEN_SCENES_CAMERA

        self._records = []
        for n in selected:
            # a missing colour image is named after its pose file (it is skipped)
            stem = _frame_stem(found[n]) if n in found else poses[n].name[:-len(".pose.txt")]
            color = found.get(n, root / f"{stem}.color.png")
            self._records.append(FileRecord(n, float(n), color, root / f"{stem}.depth.png",
                                            pose_path=root / f"{stem}.pose.txt"))

    @staticmethod
    def _frames(root: Path, selection: FrameSelection, missing
                ) -> Tuple[Dict[int, Path], Dict[int, Path], List[int]]:
        """``(colour images, pose files, by frame number; selected frame numbers)``:
        the frames with a colour image or a pose file (issue 53: a frame whose colour
        image is missing is selected, warned about, and fails to read: a skipped
        frame with its reason, never silently absent)."""
        found, _ = numbered_frames(root, _COLOR_RE, "colour images", None, missing)
        poses = index_frame_files(root, _POSE_RE, "pose files")
        numbers = sorted(set(found) | set(poses))
        selected = [numbers[k] for k in select_frames(numbers, selection)]
        gone = [n for n in selected if n not in found]
        if gone:
            logger.warning("%s: %d selected frames have a pose file but no colour image "
                           "(frame numbers %s%s): they are skipped", root, len(gone),
                           gone[:5], " ..." if len(gone) > 5 else "")
        return found, poses, selected

    def _pose(self, rec: FileRecord) -> Optional[np.ndarray]:
        return read_pose_file(rec.pose_path, "7-Scenes", lambda p: read_matrix_file(p, (4, 4)))

    def _load(self, index: int, rec: FileRecord) -> Frame:
        image = self._finish_image(read_rgb(rec.color_path, self._raw_camera))
        depth = None
        if self.config.load_depth:
            depth = self._finish_depth(read_depth_png(rec.depth_path, self.config.depth_scale,
                                                      self._raw_camera, invalid_values=(0, 65535)))
        pose = self._pose(rec) if self.config.load_pose else None
        meta = {"dataset": "7scenes", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "depth_path": str(rec.depth_path) if depth is not None else None,
                "pose_path": str(rec.pose_path), "depth_registered": False,
                "timestamp_is_frame_number": True}
        return Frame(image=image, camera=self.camera, timestamp=rec.timestamp, depth=depth,
                     T_world_cam=pose, name=_frame_stem(rec.color_path), meta=meta)
