"""Calibration when there is none: intrinsics given on the command line, a
horizontal field of view, or a guess.

* :class:`CameraSpec`: intrinsics the user gives (``fx, fy, cx, cy`` in pixels,
  a horizontal field of view in degrees, or a calibration file of another tool,
  :mod:`spgeo.datasets.calibration_files`) without the image size; its
  :meth:`CameraSpec.camera` builds the :class:`~spgeo.camera.PinholeCamera`
  once a reader knows the size.  Intrinsics or a field of view describe the
  stored images as an undistorted pinhole camera (a reader's distortion is
  dropped); a calibration file keeps its distortion (the reader undistorts)
  and must be of the images' size.
* :func:`camera_from_fov`: fx = fy from a horizontal field of view, principal
  point at the image centre.
* :func:`guess_camera`: the 35 mm-equivalent focal length of the image's EXIF
  when present (Pillow), else :data:`DEFAULT_HFOV_DEG`; always logs a warning
  ``intrinsics guessed: ...``.
* :func:`intrinsics_report`: the ``report.json`` entry ``{"source": "file" |
  "given" | "guessed", "fx", "fy", "cx", "cy", "width", "height", ...}``.

Pixel centres are at integer coordinates (the image centre is
``((W - 1) / 2, (H - 1) / 2)``); the camera axes are OpenCV's (x right, y down,
z forward).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Tuple, Union

from ..camera import PinholeCamera
from ..validation import FOV_RANGE_DEG, InputError
from .calibration_files import Calibration, read_calibration

__all__ = ["CameraSpec", "DEFAULT_HFOV_DEG", "FULL_FRAME_DIAGONAL_MM",
           "camera_from_fov", "camera_from_focal_35mm", "exif_focal_35mm", "guess_camera",
           "intrinsics_report", "INTRINSICS_SOURCES"]

logger = logging.getLogger(__name__)

#: Horizontal field of view (degrees) assumed when nothing tells the intrinsics.
#: Most videos without calibration come from a phone's main camera, whose lens
#: is sold as a 24-28 mm full-frame equivalent; on a 4:3 sensor that is a
#: horizontal field of view in the mid-to-high sixties of degrees, and webcams
#: sit in the same range.  65 degrees is at the narrow end of that range, so a
#: guess errs towards a longer focal length rather than a wider one.
DEFAULT_HFOV_DEG = 65.0

#: Diagonal of a 36 x 24 mm full frame (mm): the 35 mm-equivalent focal length
#: (EXIF ``FocalLengthIn35mmFilm``) is defined on the diagonal field of view.
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

#: Values of ``report.json``'s ``intrinsics.source``.
INTRINSICS_SOURCES = ("file", "given", "guessed")

_EXIF_FOCAL_35MM = 0xA405      # FocalLengthIn35mmFilm
_EXIF_IFD = 0x8769


def check_fov(fov_deg: float) -> float:
    """``fov_deg`` as a float; :class:`~spgeo.validation.InputError` naming the
    value unless it is finite and strictly inside
    :data:`~spgeo.validation.FOV_RANGE_DEG` (the range the intrinsics check accepts)."""
    try:
        fov = float(fov_deg)
    except (TypeError, ValueError):
        raise InputError(f"--fov {fov_deg} is not a number of degrees") from None
    lo, hi = FOV_RANGE_DEG
    if not (math.isfinite(fov) and lo < fov < hi):
        raise InputError(f"--fov {fov_deg} degrees is outside ({lo:g}, {hi:g}): give the "
                         "horizontal field of view of the camera")
    return fov


def camera_from_fov(width: int, height: int, fov_deg: float) -> PinholeCamera:
    """Pinhole camera of a ``width`` x ``height`` image whose horizontal field of
    view is ``fov_deg`` degrees: ``fx = fy = (W / 2) / tan(fov / 2)`` pixels
    (square pixels), principal point at the image centre, no distortion.

    Raises :class:`~spgeo.validation.InputError` for a field of view outside
    :data:`~spgeo.validation.FOV_RANGE_DEG` (naming the value) or intrinsics that
    :class:`PinholeCamera` refuses (e.g. a vertical field of view too wide).
    """
    fov = check_fov(fov_deg)
    f = 0.5 * int(width) / math.tan(math.radians(fov) / 2.0)
    try:
        return PinholeCamera(f, f, (int(width) - 1) / 2.0, (int(height) - 1) / 2.0,
                             int(width), int(height))
    except InputError as exc:
        raise InputError(f"--fov {fov_deg} degrees does not fit a {width}x{height} image: "
                         f"{exc}") from None


def camera_from_focal_35mm(width: int, height: int, focal_35mm: float) -> PinholeCamera:
    """Pinhole camera from a 35 mm-equivalent focal length (mm): the image
    diagonal sees the same angle as :data:`FULL_FRAME_DIAGONAL_MM` behind a lens of
    ``focal_35mm``, so ``f = focal_35mm * hypot(W, H) / FULL_FRAME_DIAGONAL_MM``
    pixels; principal point at the centre, no distortion."""
    f = float(focal_35mm) * math.hypot(int(width), int(height)) / FULL_FRAME_DIAGONAL_MM
    return PinholeCamera(f, f, (int(width) - 1) / 2.0, (int(height) - 1) / 2.0,
                         int(width), int(height))


def exif_focal_35mm(path: Union[str, Path, None]) -> Optional[float]:
    """EXIF ``FocalLengthIn35mmFilm`` (mm) of the image at ``path``, or None when
    there is no such tag, no readable file or no Pillow."""
    if path is None:
        return None
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with Image.open(path) as im:
            exif = im.getexif()
            value = exif.get(_EXIF_FOCAL_35MM) or exif.get_ifd(_EXIF_IFD).get(_EXIF_FOCAL_35MM)
    except (OSError, ValueError, SyntaxError, AttributeError):
        return None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def guess_camera(width: int, height: int, image_path: Union[str, Path, None] = None,
                 what: str = "the input") -> Tuple[PinholeCamera, str]:
    """A camera for a ``width`` x ``height`` image without calibration, and how it
    was guessed.

    The EXIF 35 mm-equivalent focal length of ``image_path`` when present
    (:func:`camera_from_focal_35mm`), else :data:`DEFAULT_HFOV_DEG`
    (:func:`camera_from_fov`).  Logs a warning ``intrinsics guessed: ...``
    naming ``what``, the method and the camera (give ``--intrinsics``,
    ``--fov`` or ``--calibration`` to replace it).  Returns ``(camera, method)``.
    """
    focal = exif_focal_35mm(image_path)
    camera = None
    if focal is not None:
        try:
            camera = camera_from_focal_35mm(width, height, focal)
            method = f"EXIF 35 mm-equivalent focal length {focal:g} mm"
        except InputError:
            camera = None
    if camera is None:
        camera = camera_from_fov(width, height, DEFAULT_HFOV_DEG)
        method = f"default horizontal field of view {DEFAULT_HFOV_DEG:g} degrees"
    logger.warning("intrinsics guessed: %s has no calibration; %s gives fx=%.1f fy=%.1f "
                   "cx=%.1f cy=%.1f (pass --intrinsics fx,fy,cx,cy, --fov DEGREES or "
                   "--calibration FILE)",
                   what, method, camera.fx, camera.fy, camera.cx, camera.cy)
    return camera, method


@dataclass(frozen=True)
class CameraSpec:
    """Intrinsics given by the user, independent of the image size.

    Attributes:
        intrinsics: ``(fx, fy, cx, cy)`` in pixels of the stored images, or None.
        fov_deg: horizontal field of view in degrees (strictly inside
            :data:`~spgeo.validation.FOV_RANGE_DEG`), or None.
        calibration: a camera read from a calibration file
            (:func:`~spgeo.datasets.calibration_files.read_calibration`: its
            distortion kept, its image size checked against the images'), or None.

    Exactly one must be set; construction raises
    :class:`~spgeo.validation.InputError` naming the bad value otherwise.
    """

    intrinsics: Optional[Tuple[float, float, float, float]] = None
    fov_deg: Optional[float] = None
    calibration: Optional[Calibration] = None

    def __post_init__(self) -> None:
        if sum(v is not None for v in (self.intrinsics, self.fov_deg, self.calibration)) != 1:
            raise InputError("give one of --intrinsics fx,fy,cx,cy, --fov DEGREES and "
                             "--calibration FILE, not both")
        if self.fov_deg is not None:
            object.__setattr__(self, "fov_deg", check_fov(self.fov_deg))
        elif self.intrinsics is not None:
            vals = tuple(self.intrinsics)
            if len(vals) != 4:
                raise InputError(f"--intrinsics must be fx,fy,cx,cy, got {self.intrinsics!r}")
            object.__setattr__(self, "intrinsics", tuple(float(v) for v in vals))

    @classmethod
    def from_options(cls, intrinsics: Optional[Sequence[float]] = None,
                     fov_deg: Optional[float] = None,
                     calibration: Union[None, str, Path] = None) -> Optional["CameraSpec"]:
        """A spec from optional ``--intrinsics`` / ``--fov`` / ``--calibration
        FILE[:ID]`` values (the file read by
        :func:`~spgeo.datasets.calibration_files.read_calibration`); None when
        all are None."""
        if intrinsics is None and fov_deg is None and calibration is None:
            return None
        return cls(None if intrinsics is None else tuple(intrinsics), fov_deg,
                   None if calibration is None else read_calibration(calibration))

    def camera(self, width: int, height: int) -> PinholeCamera:
        """The camera of a ``width`` x ``height`` image (no distortion, but a
        calibration file's; :class:`~spgeo.validation.InputError` naming the file
        and both sizes when the file is for another size)."""
        if self.calibration is not None:
            return self.calibration.camera(width, height)
        if self.fov_deg is not None:
            return camera_from_fov(width, height, self.fov_deg)
        fx, fy, cx, cy = self.intrinsics
        return PinholeCamera(fx, fy, cx, cy, int(width), int(height))

    def describe(self) -> str:
        """``--fov 60``, ``--intrinsics fx,fy,cx,cy`` as given, or ``--calibration
        FILE[:ID] (TOOL MODEL)``."""
        if self.calibration is not None:
            return self.calibration.describe()
        if self.fov_deg is not None:
            return f"--fov {self.fov_deg:g}"
        return "--intrinsics " + ",".join(f"{v:g}" for v in self.intrinsics)


def intrinsics_report(camera: PinholeCamera, source: str, detail: str = "") -> dict:
    """The ``report.json`` entry of a run's input camera: ``source`` (one of
    :data:`INTRINSICS_SOURCES`), ``fx fy cx cy`` (pixels), ``width height``,
    ``distortion`` (None or the OpenCV coefficients) and ``detail`` (how they
    were found: a file, the option given, the guess's method)."""
    if source not in INTRINSICS_SOURCES:
        raise ValueError(f"intrinsics source must be one of {INTRINSICS_SOURCES}, got {source!r}")
    out = {"source": source}
    out.update(camera.to_dict())
    out["detail"] = detail
    return out
