"""TUM RGB-D benchmark reader (raw layout).

Folder layout (Sturm et al., IROS 2012)::

    rgb.txt            "timestamp filename" per line, '#' comments (optional: see below)
    depth.txt          same, optional
    groundtruth.txt    "timestamp tx ty tz qx qy qz qw" (camera-to-world), optional
    rgb/*.png  depth/*.png (uint16, metres x 5000, 0 = no measurement)
    camera.json        optional, PinholeCamera.to_dict() (spgeo's synthetic sequences)

* Frame number = 0-based index of the line in ``rgb.txt``; timestamp = its stamp.
* Without ``rgb.txt`` (``depth.txt``) the images of ``rgb/`` (``depth/``) are
  listed instead, each timed by its file name (TUM's ``<seconds>.<fraction>.png``,
  :func:`spgeo.datasets.files.stamp_from_name`), in time order, with an info
  line saying so: the same frames, stamps and association as the list files
  give.  A file name that is not a timestamp is an
  :class:`~spgeo.validation.InputError` naming the file.
* Depth is associated to each colour image like TUM's ``associate.py``: pairs
  closer than ``max_depth_difference`` seconds, matched greedily one-to-one by
  increasing time difference.  Frames without a match get ``depth=None``.
* Ground truth is interpolated at the colour stamp between the two bracketing
  ground-truth stamps (linear translation, quaternion slerp); no pose when the
  stamp is outside the ground-truth range or the bracketing gap exceeds
  ``max_pose_gap``.  A stamp equal to a ground-truth stamp returns that pose.
* Calibration, first match wins: ``calibration`` given explicitly (a
  :class:`PinholeCamera` or ``"fr1"|"fr2"|"fr3"|"ros"``), ``camera.json`` in the
  folder, ``freiburgN`` / ``frN`` in the folder name, else the ROS default
  (525, 525, 319.5, 239.5) with a warning.
* With ``undistort=True`` (default) images are undistorted once per frame with
  maps computed once (depth with nearest-neighbour sampling); ``.camera`` is
  then ``raw_camera.undistorted()``.  (TUM's own page recommends the ROS
  default intrinsics without undistortion because the depth maps were
  registered by the Kinect driver.)
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, List, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame
from ..geometry import pose_from_tum
from .common import FileRecord, FrameSelection, FrameSequence, select_frames
from .files import (IMAGE_EXTENSIONS, PathLike, check_increasing, check_selection_files,
                    parse_stamp, read_camera_json, read_depth_png, read_rgb, stamped_files)

__all__ = ["TUMConfig", "TUMSequence", "tum_camera", "detect_tum_calibration", "read_tum_list",
           "list_tum_folder", "read_tum_groundtruth", "associate", "interpolate_poses", "TUM_CALIBRATIONS"]

logger = logging.getLogger(__name__)

_W, _H = 640, 480

#: Published TUM RGB-D colour-camera calibrations (640x480): fx, fy, cx, cy, distortion.
TUM_CALIBRATIONS = {
    "fr1": (517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": (520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": (535.4, 539.2, 320.1, 247.6, None),
    "ros": (525.0, 525.0, 319.5, 239.5, None),
}


def tum_camera(name: str) -> PinholeCamera:
    """Camera of a TUM calibration ``"fr1" | "fr2" | "fr3" | "ros"`` (also
    ``"freiburg1"``...)."""
    key = str(name).lower().replace("freiburg", "fr")
    if key not in TUM_CALIBRATIONS:
        raise ValueError(f"unknown TUM calibration {name!r}; expected one of "
                         f"{sorted(TUM_CALIBRATIONS)}")
    fx, fy, cx, cy, dist = TUM_CALIBRATIONS[key]
    return PinholeCamera(fx, fy, cx, cy, _W, _H, dist)


def detect_tum_calibration(folder: PathLike) -> Optional[str]:
    """``"fr1"``/``"fr2"``/``"fr3"`` from a folder name containing ``freiburgN`` or
    ``frN`` (e.g. ``rgbd_dataset_freiburg1_desk``, ``tum_fr1_desk_9``), else None."""
    name = Path(folder).name.lower()
    m = re.search(r"(?:freiburg|(?<![a-z0-9])fr)([123])(?![0-9])", name)
    return f"fr{m.group(1)}" if m else None


@config_class
@dataclass
class TUMConfig:
    """Options of :class:`TUMSequence`.

    Attributes:
        calibration: ``None`` (auto: camera.json, then folder name, then ROS
            default with a warning), ``"fr1"|"fr2"|"fr3"|"ros"`` or a
            :class:`PinholeCamera` of the stored (distorted) images.
        undistort: undistort images and depth (default True); ``.camera`` then
            has no distortion.
        load_depth: read depth maps (default True).
        load_pose: attach interpolated ground-truth poses (default True).
        frames: selection by frame number (index in ``rgb.txt``): ``"A:B[:S]"``,
            slice, range or list (default None = all).
        max_depth_difference: association tolerance in seconds (default 0.02,
            as TUM's ``associate.py``).
        max_pose_gap: largest gap in seconds between the two ground-truth
            stamps bracketing a frame for which a pose is interpolated (default 0.05).
        depth_scale: raw depth units per metre (default 5000).
        check_files: check at construction that every selected listed file
            exists (default True; fail fast with ``FileNotFoundError``).
    """

    calibration: Union[None, str, PinholeCamera] = None
    undistort: bool = True
    load_depth: bool = True
    load_pose: bool = True
    frames: FrameSelection = None
    max_depth_difference: float = 0.02
    max_pose_gap: float = 0.05
    depth_scale: float = 5000.0
    check_files: bool = True


# -------------------------------------------------------------------- parsing
def _data_lines(path: Path):
    """Yield ``(line_number, tokens)`` of the non-comment, non-empty lines."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"TUM list file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read TUM list file {path}: {exc}") from exc
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        yield lineno, s.replace(",", " ").split()


def _read_stamped(path: Path, layout: str, parse: Callable[[List[str], int], Any]
                  ) -> Tuple[np.ndarray, list]:
    """``(stamps (N,), [parse(fields after the stamp, line number)])`` of a TUM
    text file whose lines are ``layout`` (its words name the fields); raises
    ``ValueError`` naming the file and line for a wrong field count, a bad
    stamp or stamps not strictly increasing."""
    n_fields = len(layout.split())
    stamps, rows, linenos = [], [], []
    for lineno, tok in _data_lines(path):
        if len(tok) != n_fields:
            raise ValueError(f"{path}:{lineno}: malformed line, expected '{layout}', "
                             f"got {len(tok)} fields")
        stamps.append(parse_stamp(tok[0], path, lineno))
        rows.append(parse(tok[1:], lineno))
        linenos.append(lineno)
    check_increasing(stamps, linenos, path)
    return np.asarray(stamps, dtype=np.float64), rows


def read_tum_list(path: PathLike) -> Tuple[np.ndarray, List[str]]:
    """Parse a TUM ``timestamp filename`` list (``rgb.txt`` / ``depth.txt``).

    Returns ``(stamps (N,), filenames)``.  Raises ``ValueError`` naming the file
    and line for malformed lines or non-increasing stamps.
    """
    return _read_stamped(Path(path), "timestamp filename", lambda rest, lineno: rest[0])


def list_tum_folder(root: PathLike, folder: str) -> Tuple[np.ndarray, List[str]]:
    """What ``rgb.txt`` / ``depth.txt`` would list, from the folder itself: the
    images of ``root/folder`` (extensions of
    :data:`~spgeo.datasets.files.IMAGE_EXTENSIONS`; other files are ignored),
    each timed by its name (``1305031102.175304.png``), in time order.

    Returns ``(stamps (N,) seconds, file names relative to root)`` as
    :func:`read_tum_list`.  Raises ``FileNotFoundError`` when the folder is
    missing or holds no image, :class:`~spgeo.validation.InputError` naming a
    file whose name is not a timestamp or two files of one stamp
    (:func:`~spgeo.datasets.files.stamped_files`).
    """
    path = Path(root) / folder
    files = ([p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
             if path.is_dir() else [])
    if not files:
        raise FileNotFoundError(f"TUM sequence {root}: no {folder}.txt and no images in "
                                f"{path}")
    paths, stamps = stamped_files(files, f"TUM {folder}")
    return stamps, [f"{folder}/{p.name}" for p in paths]


# Kept apart from spgeo.io.tum.read_tum (one 4x4 pose per line, inline '#' comments, any
# order): interpolation needs the raw quaternion rows and strictly increasing stamps.
def read_tum_groundtruth(path: PathLike) -> Tuple[np.ndarray, np.ndarray]:
    """Parse ``groundtruth.txt``: returns ``(stamps (N,), tum (N, 7) tx ty tz qx qy qz qw)``."""
    path = Path(path)

    def pose_row(fields: List[str], lineno: int) -> List[float]:
        try:
            vals = [float(x) for x in fields]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: malformed pose values {fields}") from None
        q = np.asarray(vals[3:])
        if not np.all(np.isfinite(vals)) or np.linalg.norm(q) < 1e-6:
            raise ValueError(f"{path}:{lineno}: pose is not finite or has a zero quaternion")
        return vals

    stamps, rows = _read_stamped(path, "timestamp tx ty tz qx qy qz qw", pose_row)
    return stamps, np.asarray(rows, dtype=np.float64).reshape(-1, 7)


def associate(stamps_a: np.ndarray, stamps_b: np.ndarray, max_difference: float = 0.02,
              offset: float = 0.0) -> np.ndarray:
    """For each stamp of ``a``, the index of its matched stamp in ``b`` or -1.

    Same rule as TUM's ``associate.py``: candidate pairs with
    ``|a - (b + offset)| < max_difference`` are matched greedily one-to-one in
    order of increasing difference.
    """
    a = np.asarray(stamps_a, dtype=np.float64)
    b = np.sort(np.asarray(stamps_b, dtype=np.float64)) + offset
    order_b = np.argsort(np.asarray(stamps_b, dtype=np.float64), kind="stable")
    cands = []
    for i, t in enumerate(a):
        lo = np.searchsorted(b, t - max_difference, side="left")
        hi = np.searchsorted(b, t + max_difference, side="right")
        for j in range(lo, hi):
            d = abs(t - b[j])
            if d < max_difference:
                cands.append((d, i, j))
    cands.sort()
    out = np.full(len(a), -1, dtype=np.int64)
    used_b = np.zeros(len(b), dtype=bool)
    for _, i, j in cands:
        if out[i] < 0 and not used_b[j]:
            out[i] = order_b[j]
            used_b[j] = True
    return out


def _slerp(q0: np.ndarray, q1: np.ndarray, alpha: float) -> np.ndarray:
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + alpha * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    s = np.sin(theta)
    return (np.sin((1 - alpha) * theta) * q0 + np.sin(alpha * theta) * q1) / s


def interpolate_poses(gt_stamps: np.ndarray, gt_tum: np.ndarray, query: np.ndarray,
                      max_gap: float = 0.05) -> List[Optional[np.ndarray]]:
    """Camera-to-world 4x4 poses at ``query`` stamps, interpolated from TUM rows.

    Linear interpolation of translation and slerp of the quaternion between
    the two bracketing ground-truth stamps; ``None`` outside the ground-truth
    range or where the bracketing gap exceeds ``max_gap`` seconds.
    """
    gt_stamps = np.asarray(gt_stamps, dtype=np.float64)
    out: List[Optional[np.ndarray]] = []
    n = len(gt_stamps)
    for t in np.asarray(query, dtype=np.float64).ravel():
        if n == 0 or t < gt_stamps[0] or t > gt_stamps[-1]:
            out.append(None)
            continue
        j = int(np.searchsorted(gt_stamps, t, side="left"))
        if j < n and gt_stamps[j] == t:
            out.append(pose_from_tum(gt_tum[j]))
            continue
        i0, i1 = j - 1, j
        t0, t1 = gt_stamps[i0], gt_stamps[i1]
        if t1 - t0 > max_gap:
            out.append(None)
            continue
        alpha = (t - t0) / (t1 - t0)
        trans = (1 - alpha) * gt_tum[i0, :3] + alpha * gt_tum[i1, :3]
        quat = _slerp(gt_tum[i0, 3:], gt_tum[i1, 3:], alpha)
        out.append(pose_from_tum(np.concatenate([trans, quat])))
    return out


# --------------------------------------------------------------------- reader
@dataclass
class _TUMRecord(FileRecord):
    """A TUM frame's record: also the stamp of its associated depth image."""

    depth_timestamp: Optional[float] = None


class TUMSequence(FrameSequence):
    """Lazy reader of a TUM RGB-D sequence folder (see the module docstring).

    Args:
        path: the sequence folder (containing ``rgb.txt``, or ``rgb/`` of images
            named by their timestamps).
        config: a :class:`TUMConfig`; keyword arguments override its fields.
    """

    def __init__(self, path: PathLike, config: Optional[TUMConfig] = None, **kwargs) -> None:
        super().__init__()
        cfg = self._open(path, TUMConfig, config, kwargs, "TUM sequence folder")
        root = self.root
        self._raw_camera, self.calibration_source = self._resolve_camera(cfg.calibration)
        self._intrinsics_detail = self.calibration_source

        stamps, names = self._listed("rgb")
        if len(stamps) == 0:
            raise ValueError(f"{root / 'rgb.txt'} lists no images")
        keep = select_frames(range(len(stamps)), cfg.frames)

        depth_idx = np.full(len(stamps), -1, dtype=np.int64)
        d_stamps: np.ndarray = np.zeros(0)
        d_names: List[str] = []
        if cfg.load_depth:
            if (root / "depth.txt").is_file() or (root / "depth").is_dir():
                d_stamps, d_names = self._listed("depth")
                depth_idx = associate(stamps, d_stamps, cfg.max_depth_difference)
                unmatched = int(np.sum(depth_idx[keep] < 0))
                if unmatched:
                    logger.info("%s: %d of %d selected frames have no depth within %.3f s",
                                self._name, unmatched, len(keep), cfg.max_depth_difference)
            else:
                logger.warning("%s: no depth.txt nor depth/, frames will have no depth", root)

        poses: List[Optional[np.ndarray]] = [None] * len(stamps)
        if cfg.load_pose:
            gt_path = root / "groundtruth.txt"
            if gt_path.is_file():
                gt_stamps, gt_tum = read_tum_groundtruth(gt_path)
                sel = np.asarray(keep)
                for k, T in zip(sel, interpolate_poses(gt_stamps, gt_tum, stamps[sel],
                                                       cfg.max_pose_gap)):
                    poses[k] = T
            else:
                logger.info("%s: no groundtruth.txt, frames will have no pose", root)

        self._records = []
        for k in keep:
            j = int(depth_idx[k])
            self._records.append(_TUMRecord(
                number=k, timestamp=float(stamps[k]), color_path=root / names[k],
                depth_path=root / d_names[j] if j >= 0 else None,
                depth_timestamp=float(d_stamps[j]) if j >= 0 else None, pose=poses[k]))
        if cfg.check_files:
            check_selection_files([r.color_path for r in self._records], "rgb")
            check_selection_files([r.depth_path for r in self._records if r.depth_path],
                                  "depth")
        logger.debug("opened TUM sequence %s: %d frames, camera %r (%s)", root, len(self),
                     self._raw_camera, self.calibration_source)

    def _listed(self, kind: str) -> Tuple[np.ndarray, List[str]]:
        """``(stamps, names)`` of ``<kind>.txt`` (``"rgb"`` / ``"depth"``), or without
        it of the images of ``<kind>/`` timed by their names (:func:`list_tum_folder`,
        an info line)."""
        listing = self.root / f"{kind}.txt"
        if listing.is_file():
            return read_tum_list(listing)
        stamps, names = list_tum_folder(self.root, kind)
        logger.info("%s: no %s.txt: the %d images of %s/ are timed by their file names",
                    self._name, kind, len(names), kind)
        return stamps, names

    def _resolve_camera(self, calibration) -> Tuple[PinholeCamera, str]:
        if isinstance(calibration, PinholeCamera):
            return calibration, "argument"
        if isinstance(calibration, str):
            return tum_camera(calibration), calibration.lower()
        if calibration is not None:
            raise TypeError("TUMConfig.calibration must be None, a name or a PinholeCamera, "
                            f"got {type(calibration).__name__}")
        cam_json = self.root / "camera.json"
        if cam_json.is_file():
            return read_camera_json(cam_json), str(cam_json)
        detected = detect_tum_calibration(self.root.resolve())
        if detected is not None:
            return tum_camera(detected), f"{detected} (from folder name)"
        logger.warning("%s: cannot tell fr1/fr2/fr3 from the folder name and no camera.json; "
                       "using the TUM ROS default intrinsics (525, 525, 319.5, 239.5). Pass "
                       "calibration='fr1'|'fr2'|'fr3' to choose.", self.root)
        return tum_camera("ros"), "ros default"

    def _load(self, index: int, rec: _TUMRecord) -> Frame:
        image = self._finish_image(read_rgb(rec.color_path, self._raw_camera))
        depth = None
        if rec.depth_path is not None:
            depth = self._finish_depth(read_depth_png(rec.depth_path, self.config.depth_scale,
                                                      self._raw_camera))
        meta = {"dataset": "tum", "sequence": self._name, "index": index,
                "frame_number": rec.number, "rgb_path": str(rec.color_path),
                "depth_path": None if rec.depth_path is None else str(rec.depth_path),
                "depth_timestamp": rec.depth_timestamp, "depth_registered": True,
                "undistorted": self._undistort and self._raw_camera.distortion is not None}
        return Frame(image=image, camera=self.camera, timestamp=rec.timestamp, depth=depth,
                     T_world_cam=self._pose(rec),
                     name=rec.color_path.stem, meta=meta)
