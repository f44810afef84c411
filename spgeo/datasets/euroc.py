"""EuRoC MAV reader (ASL layout, one camera of one sequence).

Layout (Burri et al., IJRR 2016)::

    mav0/cam0/data.csv            "#timestamp [ns],filename" per line
    mav0/cam0/data/<ns>.png       grey images
    mav0/cam0/sensor.yaml         intrinsics [fu, fv, cu, cv] (pixels), resolution
                                  [W, H], distortion_coefficients [k1, k2, p1, p2]
                                  (radial-tangential), T_BS (4x4 camera-to-body)
    mav0/state_groundtruth_estimate0/data.csv
                                  optional: "#timestamp [ns], p_RS_R_x, _y, _z [m],
                                  q_RS_w, q_RS_x, q_RS_y, q_RS_z, ..." (body in world)

* The path given is the sequence folder (holding ``mav0``) or ``mav0`` itself.
* Frame number = 0-based line of ``data.csv``; timestamp = its nanoseconds / 1e9.
* The radial-tangential coefficients are OpenCV's ``(k1, k2, p1, p2)``; with
  ``undistort=True`` (default) the images are undistorted and ``.camera`` has no
  distortion, as for TUM.
* Ground truth ``T_world_cam = T_world_body @ T_BS`` (camera-to-world, OpenCV
  axes, metres), the body pose of the ground-truth row nearest in time
  (:func:`spgeo.datasets.tum.associate`, within ``max_pose_difference`` seconds;
  no pose beyond it).
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..geometry import pose_from_tum
from ..validation import InputError, check_input_file
from .common import FileRecord, FrameSelection, FrameSequence, select_frames
from .files import (PathLike, check_increasing, check_selection_files, nearest_rigid, read_rgb,
                    yaml_number_list)
from .tum import associate

__all__ = ["EuRoCConfig", "EuRoCSequence", "read_euroc_sensor", "read_euroc_csv"]

logger = logging.getLogger(__name__)


@config_class
@dataclass
class EuRoCConfig:
    """Options of :class:`EuRoCSequence`.

    Attributes:
        sensor: ``"cam0"`` (default, left) or ``"cam1"``.
        undistort: undistort the images (default True).
        load_pose: attach the ground truth when present (default True).
        frames: selection by frame number (line of ``data.csv``; ``"A:B[:S]"``,
            slice, range, list; default None = all).
        max_pose_difference: largest time difference in seconds between a
            frame and its ground-truth row (default 0.01).
        load_depth: accepted for the runner's sake; EuRoC has no depth.
        check_files: check at construction that every selected image exists
            (default True).
    """

    sensor: str = "cam0"
    undistort: bool = True
    load_pose: bool = True
    frames: FrameSelection = None
    max_pose_difference: float = 0.01
    load_depth: bool = False
    check_files: bool = True


def read_euroc_csv(path: PathLike, n_min: int) -> Tuple[np.ndarray, List[List[str]]]:
    """An EuRoC CSV (``#`` header, comma-separated, nanosecond stamp first) ->
    ``(stamps in seconds (N,), the other fields per row)``; each row must have at
    least ``n_min`` fields and the stamps must increase.  Raises
    ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming the file and line."""
    path = Path(check_input_file(path, "EuRoC CSV"))
    stamps, rows, linenos = [], [], []
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f.strip() for f in s.split(",")]
        if len(fields) < n_min or not fields[0].isdigit():
            raise InputError(f"{path}:{lineno}: malformed line, expected a nanosecond "
                             f"timestamp and {n_min - 1} more fields")
        stamps.append(int(fields[0]) * 1e-9)
        rows.append(fields[1:])
        linenos.append(lineno)
    check_increasing(stamps, linenos, path)
    return np.asarray(stamps, dtype=np.float64), rows


def read_euroc_sensor(path: PathLike) -> Tuple[PinholeCamera, np.ndarray]:
    """``sensor.yaml`` of a camera -> ``(camera with its radial-tangential
    distortion, T_BS: 4x4 camera-to-body)``.  Only the pinhole model with
    radial-tangential (or no) distortion is read; anything else raises
    :class:`~spgeo.validation.InputError` naming the file."""
    path = Path(check_input_file(path, "EuRoC sensor"))
    text = "\n".join(line.split("#", 1)[0] for line in
                     path.read_text(encoding="utf-8").splitlines())
    model = re.search(r"^\s*distortion_model\s*:\s*(\S+)", text, re.MULTILINE)
    if model and model.group(1) not in ("radial-tangential", "radtan", "none"):
        raise InputError(f"{path}: distortion_model {model.group(1)!r} is not supported "
                         "(radial-tangential only)")
    fu, fv, cu, cv = yaml_number_list(text, "intrinsics", path, 4)
    w, h = (int(v) for v in yaml_number_list(text, "resolution", path, 2))
    dist = None
    if model is None or model.group(1) != "none":
        dist = tuple(yaml_number_list(text, "distortion_coefficients", path, 4))
    tbs = re.search(r"^\s*T_BS\s*:(.*?)\bdata\s*:\s*\[([^\]]*)\]", text, re.MULTILINE | re.DOTALL)
    if tbs is None:
        raise InputError(f"{path}: no T_BS data")
    T_BS = yaml_number_list("data: [" + tbs.group(2) + "]", "data", path, 16).reshape(4, 4)
    try:
        camera = PinholeCamera(fu, fv, cu, cv, w, h, dist)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    return camera, nearest_rigid(T_BS, f"{path} T_BS")


class EuRoCSequence(FrameSequence):
    """Lazy reader of a EuRoC MAV sequence (see the module docstring)."""

    def __init__(self, path: PathLike, config: Optional[EuRoCConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, EuRoCConfig, config, kwargs, "EuRoC sequence folder")
        mav = self.root if self.root.name == "mav0" else self.root / "mav0"
        if self.root.name == "mav0":
            self._name = self.root.resolve().parent.name
        cam_dir = mav / cfg.sensor
        if not cam_dir.is_dir():
            raise FileNotFoundError(f"euroc: camera folder not found: {cam_dir}")
        self._raw_camera, T_BS = read_euroc_sensor(cam_dir / "sensor.yaml")
        self._intrinsics_detail = str(cam_dir / "sensor.yaml")
        stamps, rows = read_euroc_csv(cam_dir / "data.csv", 2)
        if len(stamps) == 0:
            raise InputError(f"{cam_dir / 'data.csv'} lists no images")
        keep = select_frames(range(len(stamps)), cfg.frames)
        poses = self._poses(mav, stamps[keep], T_BS) if cfg.load_pose else [None] * len(keep)
        self._records = [FileRecord(k, float(stamps[k]), cam_dir / "data" / rows[k][0], pose=T)
                         for k, T in zip(keep, poses)]
        if cfg.check_files:
            check_selection_files([r.color_path for r in self._records], "image")

    def _poses(self, mav: Path, stamps: np.ndarray,
               T_BS: np.ndarray) -> List[Optional[np.ndarray]]:
        """Camera-to-world poses at ``stamps`` (nearest ground-truth row), None without."""
        gt_path = mav / "state_groundtruth_estimate0" / "data.csv"
        if not gt_path.is_file():
            logger.info("%s: no ground truth (%s)", self.root, gt_path)
            return [None] * len(stamps)
        gt_stamps, rows = read_euroc_csv(gt_path, 8)
        try:
            body = np.array([[float(v) for v in r[:7]] for r in rows], dtype=np.float64)
        except ValueError:
            raise InputError(f"{gt_path}: non-numeric position or quaternion") from None
        match = associate(stamps, gt_stamps, self.config.max_pose_difference)
        out: List[Optional[np.ndarray]] = []
        for j in match:
            if j < 0:
                out.append(None)
                continue
            p, q_wxyz = body[j, :3], body[j, 3:7]
            T_world_body = pose_from_tum(np.concatenate([p, q_wxyz[1:], q_wxyz[:1]]))
            out.append(T_world_body @ T_BS)
        return out

    def _load(self, index: int, rec: FileRecord) -> Frame:
        image = self._finish_image(read_rgb(rec.color_path, self._raw_camera))
        meta = {"dataset": "euroc", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "undistorted": self._undistort and self._raw_camera.distortion is not None}
        return Frame(image=image, camera=self.camera, timestamp=rec.timestamp,
                     T_world_cam=self._pose(rec), name=rec.color_path.stem, meta=meta)
