"""Calibration files of other tools read as a spgeo camera
(``spgeo vo --calibration FILE[:ID]``, :func:`read_calibration`).

Formats, told apart by their content (not their names):

* COLMAP ``cameras.txt``: ``#`` comment lines, then one line per camera
  ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`` with a model of
  :data:`COLMAP_MODELS`: ``SIMPLE_PINHOLE`` (f cx cy), ``PINHOLE`` (fx fy cx
  cy), ``SIMPLE_RADIAL`` (f cx cy k), ``RADIAL`` (f cx cy k1 k2), ``OPENCV``
  (fx fy cx cy k1 k2 p1 p2) or ``FULL_OPENCV`` (fx fy cx cy k1 k2 p1 p2 k3 k4
  k5 k6); their distortion is OpenCV's with the other coefficients zero.
  COLMAP puts the centre of the top-left pixel at (0.5, 0.5), spgeo at (0, 0):
  ``cx = cx_colmap - 0.5``, ``cy = cy_colmap - 0.5`` (the inverse of spgeo's
  COLMAP export, :func:`spgeo.twoview.backends.colmap_camera`).
* ORB-SLAM2 / ORB-SLAM3 settings (OpenCV YAML, ``%YAML:1.0``, read with
  ``cv2.FileStorage``): ``Camera.fx fy cx cy`` and ``Camera.k1 k2 p1 p2
  [k3]`` (ORB-SLAM3 1.0: ``Camera1.*``, and ``Camera2.*`` for a second
  camera; ``Camera.type`` ``"PinHole"`` or ``"Rectified"``); the image size
  from ``Camera.width`` / ``Camera.height`` where the file has them, else the
  images' own.
* Kalibr camchain YAML: ``camN:`` blocks with ``camera_model: pinhole``,
  ``intrinsics: [fu, fv, pu, pv]``, ``distortion_model: radtan`` (or
  ``none``), ``distortion_coeffs: [k1, k2, r1, r2]`` and ``resolution: [W,
  H]``; also one camera without a ``camN:`` block (EuRoC's ``sensor.yaml``,
  ``distortion_coefficients``).

ORB-SLAM and Kalibr share OpenCV's pixel convention (pixel centres at
integers, as spgeo): their values are taken as they are.  Pixels are those of
the stored images; a camera with distortion is undistorted by the readers
(:class:`~spgeo.datasets.common.CameraSource`).

A file with several cameras: identical ones count as one; otherwise ``FILE:ID``
picks one (the COLMAP camera id, Kalibr's ``camN``, ORB-SLAM's ``Camera1`` /
``Camera2``), and without it :class:`~spgeo.validation.InputError` lists the
IDs.  Every error names the file: ``FileNotFoundError``, or
:class:`~spgeo.validation.InputError` for a file of none of these formats, a
model it does not read (naming it and the ones it reads), a malformed value or
implausible intrinsics.
"""
from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple, Union

from ..camera import PinholeCamera
from ..validation import InputError, check_input_file
from .files import yaml_number_list

__all__ = ["Calibration", "read_calibration", "COLMAP_MODELS"]

#: COLMAP camera models read, with their number of parameters.
COLMAP_MODELS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5,
                 "OPENCV": 8, "FULL_OPENCV": 12}

_FORMATS = "COLMAP cameras.txt, ORB-SLAM settings YAML or Kalibr camchain YAML"
_KALIBR_DISTORTIONS = ("radtan", "radial-tangential", "none")
_ORBSLAM_TYPES = ("PinHole", "Rectified")


@dataclass(frozen=True)
class Calibration:
    """One camera of a calibration file.

    Attributes:
        fx, fy, cx, cy: intrinsics in pixels, spgeo's convention (pixel centres
            at integers: COLMAP's principal point less 0.5).
        distortion: OpenCV coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``, or None.
        size: ``(width, height)`` in pixels that the file gives, or None (an
            ORB-SLAM file without ``Camera.width`` / ``Camera.height``).
        path: the file.
        tool: ``"COLMAP"``, ``"ORB-SLAM"`` or ``"Kalibr"``.
        model: the file's name of the model (``"OPENCV"``, ``"PinHole"``, ``"pinhole-radtan"``).
        camera_id: the camera's ID in the file (None for a file of one unnamed camera).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Optional[Tuple[float, ...]]
    size: Optional[Tuple[int, int]]
    path: Path
    tool: str
    model: str
    camera_id: Optional[str] = None

    def describe(self) -> str:
        """``--calibration FILE: TOOL MODEL camera [ID]`` (``report.json``'s
        ``intrinsics.detail``)."""
        ident = "" if self.camera_id is None else f" {self.camera_id}"
        return f"--calibration {self.path}: {self.tool} {self.model} camera{ident}"

    def camera(self, width: Optional[int] = None, height: Optional[int] = None) -> PinholeCamera:
        """The :class:`PinholeCamera` (with the file's distortion) of images of
        ``width`` x ``height`` pixels (default: the file's size).
        :class:`~spgeo.validation.InputError` naming the file when its size is
        another (both sizes named), when neither gives a size, or for
        intrinsics :class:`PinholeCamera` refuses."""
        size = self.size if width is None else (int(width), int(height))
        if size is None:
            raise InputError(f"calibration {self.path} gives no image size (Camera.width, "
                             "Camera.height)")
        if self.size is not None and size != self.size:
            raise InputError(f"calibration {self.path} is for {self.size[0]}x{self.size[1]} "
                             f"images, the images are {size[0]}x{size[1]}: give the "
                             "calibration of the images as stored")
        try:
            return PinholeCamera(self.fx, self.fy, self.cx, self.cy, size[0], size[1],
                                 self.distortion)
        except InputError as exc:
            raise InputError(f"calibration {self.path}: {exc}") from None


def read_calibration(spec: Union[str, os.PathLike]) -> Calibration:
    """The camera of the calibration file ``spec`` (``FILE`` or ``FILE:ID``;
    formats, conventions and errors: the module docstring).  Intrinsics are
    checked here when the file gives the image size."""
    path, wanted = _split_id(spec)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"calibration {path} is not a text file ({_FORMATS})") from None
    if re.search(r"^\s*Camera1?\.fx\s*:", text, re.MULTILINE):
        cams = _orbslam(path)
    elif re.search(r"^\s*intrinsics\s*:", text, re.MULTILINE):
        cams = _kalibr(text, path)
    else:
        cams = _colmap(text, path)
    chosen = _choose(cams, wanted, path)
    if chosen.size is not None:
        chosen.camera()
    return chosen


def _split_id(spec: Union[str, os.PathLike]) -> Tuple[Path, Optional[str]]:
    """``(file, ID or None)`` of ``FILE`` or ``FILE:ID`` (a path that exists as
    given is a file name, colons included)."""
    text = os.fspath(spec)
    head, sep, tail = text.rpartition(":")
    if not os.path.exists(text) and sep and head and tail and os.path.isfile(head):
        return Path(check_input_file(head, "calibration")), tail.strip()
    return Path(check_input_file(text, "calibration")), None


def _choose(cams: Sequence[Calibration], wanted: Optional[str], path: Path) -> Calibration:
    """The camera ``wanted``, else the only one (identical cameras count as one)."""
    ids = ", ".join(str(c.camera_id) for c in cams)
    if not cams:
        raise InputError(f"calibration {path} holds no camera ({_FORMATS})")
    if wanted is not None:
        for cam in cams:
            if cam.camera_id == wanted:
                return cam
        raise InputError(f"calibration {path} has no camera {wanted!r}; its cameras: {ids}")
    first = cams[0]
    if all(dataclasses.replace(c, camera_id=first.camera_id) == first for c in cams[1:]):
        return first
    raise InputError(f"calibration {path} holds {len(cams)} different cameras ({ids}): "
                     f"pick one with --calibration {path}:ID")


# ------------------------------------------------------------------ COLMAP
def _colmap(text: str, path: Path) -> List[Calibration]:
    """The cameras of a COLMAP ``cameras.txt``."""
    cams = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        where = f"calibration {path}:{lineno}"
        try:
            cam_id, model, width, height = tokens[0], tokens[1], int(tokens[2]), int(tokens[3])
            params = [float(t) for t in tokens[4:]]
        except (IndexError, ValueError):
            raise InputError(f"{where}: not a calibration file spgeo reads ({_FORMATS}); a "
                             "COLMAP camera line is 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'"
                             ) from None
        if model not in COLMAP_MODELS:
            raise InputError(f"{where}: COLMAP camera model {model} is not read; supported: "
                             f"{', '.join(COLMAP_MODELS)}")
        if len(params) != COLMAP_MODELS[model]:
            raise InputError(f"{where}: a COLMAP {model} camera has {COLMAP_MODELS[model]} "
                             f"parameters, got {len(params)}")
        fx, fy, cx, cy, dist = _colmap_intrinsics(model, params)
        cams.append(Calibration(fx, fy, cx - 0.5, cy - 0.5, dist, (width, height), path,
                                "COLMAP", model, cam_id))
    return cams


def _colmap_intrinsics(model: str, p: Sequence[float]):
    """``(fx, fy, cx, cy, OpenCV distortion or None)`` of COLMAP's parameters (COLMAP's pixels)."""
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        radial = tuple(p[3:]) + (0.0,) * (4 - len(p[3:]))
        return p[0], p[0], p[1], p[2], radial if any(radial) else None
    return p[0], p[1], p[2], p[3], tuple(p[4:]) or None


# ------------------------------------------------------------------ ORB-SLAM
def _orbslam(path: Path) -> List[Calibration]:
    """The cameras of an ORB-SLAM2 / ORB-SLAM3 settings file (``cv2.FileStorage``)."""
    import cv2

    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        root = storage.root()
    except (cv2.error, SystemError) as exc:
        raise InputError(f"calibration {path}: not an OpenCV YAML file "
                         f"({' '.join(str(exc).split())[:200]})") from None
    node = root.getNode("Camera.type")
    kind = "PinHole" if node.empty() else node.string()
    if kind not in _ORBSLAM_TYPES:
        raise InputError(f"calibration {path}: ORB-SLAM Camera.type {kind!r} is not read; "
                         f"supported: {', '.join(_ORBSLAM_TYPES)}")
    width, height = (_orb_number(root, f"Camera.{k}", path, False) for k in ("width", "height"))
    size = None if width is None or height is None else (int(width), int(height))
    prefixes = [p for p in ("Camera1", "Camera2") if not root.getNode(f"{p}.fx").empty()]
    cams = []
    for prefix in prefixes or ["Camera"]:
        fx, fy, cx, cy = (_orb_number(root, f"{prefix}.{k}", path, True)
                          for k in ("fx", "fy", "cx", "cy"))
        dist = [_orb_number(root, f"{prefix}.{k}", path, False) for k in ("k1", "k2", "p1", "p2")]
        k3 = _orb_number(root, f"{prefix}.k3", path, False)
        dist = tuple(d or 0.0 for d in dist) + (() if k3 is None else (k3,))
        cams.append(Calibration(fx, fy, cx, cy, dist if any(dist) else None, size, path,
                                "ORB-SLAM", kind, prefix if prefixes else None))
    storage.release()
    return cams


def _orb_number(root, key: str, path: Path, required: bool) -> Optional[float]:
    """The number at ``key`` (None when absent and not ``required``)."""
    node = root.getNode(key)
    if node.empty() and not required:
        return None
    if node.empty() or not (node.isReal() or node.isInt()):
        raise InputError(f"calibration {path}: {key} must be a number")
    return float(node.real())


# ------------------------------------------------------------------ Kalibr
def _kalibr(text: str, path: Path) -> List[Calibration]:
    """The cameras of a Kalibr camchain (``camN:`` blocks) or of a one-camera
    YAML of the same keys (EuRoC's ``sensor.yaml``)."""
    text = "\n".join(line.split("#", 1)[0] for line in text.splitlines())
    parts = re.split(r"^(cam\d+)\s*:\s*$", text, flags=re.MULTILINE)
    blocks = list(zip(parts[1::2], parts[2::2])) if len(parts) > 1 else [(None, text)]
    return [_kalibr_camera(body, path, name) for name, body in blocks]


def _kalibr_camera(body: str, path: Path, name: Optional[str]) -> Calibration:
    where = f"calibration {path}" + ("" if name is None else f" {name}")

    def scalar(key: str, default: str) -> str:
        m = re.search(rf"^\s*{key}\s*:\s*(\S+)", body, re.MULTILINE)
        return default if m is None else m.group(1).strip("'\"")

    model, distortion = scalar("camera_model", "pinhole"), scalar("distortion_model", "none")
    if model != "pinhole":
        raise InputError(f"{where}: Kalibr camera_model {model} is not read; supported: pinhole")
    if distortion not in _KALIBR_DISTORTIONS:
        raise InputError(f"{where}: Kalibr distortion_model {distortion} is not read; "
                         f"supported: {', '.join(_KALIBR_DISTORTIONS)}")
    fx, fy, cx, cy = (float(v) for v in yaml_number_list(body, "intrinsics", path, 4))
    width, height = (int(v) for v in yaml_number_list(body, "resolution", path, 2))
    dist = None
    if distortion != "none":
        key = ("distortion_coeffs" if re.search(r"^\s*distortion_coeffs\s*:", body, re.MULTILINE)
               else "distortion_coefficients")
        dist = tuple(float(v) for v in yaml_number_list(body, key, path, 4))
    return Calibration(fx, fy, cx, cy, dist, (width, height), path, "Kalibr",
                       f"{model}-{distortion}", name)
