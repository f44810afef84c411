"""The input checks below :mod:`spgeo.camera`: :class:`InputError` and the intrinsics check.

:class:`~spgeo.camera.PinholeCamera` validates its intrinsics on construction, so
these pieces must not depend on the camera; :mod:`spgeo.validation` (which checks
cameras too) re-exports them and is the place to import them from.
"""
from __future__ import annotations

import math
from typing import Tuple

__all__ = ["InputError", "FOV_RANGE_DEG", "FOCAL_RATIO_RANGE", "PRINCIPAL_POINT_MARGIN",
           "check_intrinsics", "swapped_size_hint"]

#: plausible field of view of a pinhole (rectilinear) camera, degrees: each axis at most
#: the upper bound (wider needs a fisheye model), the wider axis at least the lower one;
#: a horizontal field of view given as ``--fov`` must lie strictly inside it
#: (:func:`spgeo.datasets.calibration.check_fov`): the one range of both checks
FOV_RANGE_DEG: Tuple[float, float] = (10.0, 160.0)
#: plausible ``fx / fy`` (square pixels give 1)
FOCAL_RATIO_RANGE: Tuple[float, float] = (0.5, 2.0)
#: the principal point may lie outside the image by at most this fraction of its size
PRINCIPAL_POINT_MARGIN = 0.25


class InputError(ValueError):
    """Bad input: the message names the file or value and says what was expected."""


def _fov_deg(focal: float, size: int) -> float:
    return math.degrees(2.0 * math.atan(size / (2.0 * focal)))


def _flipped_axis_hint(name: str, value: float) -> str:
    """How to convert a negative focal length ``name`` = ``value`` (a camera axis
    pointing the other way) to spgeo's OpenCV convention, as the ICL-NUIM reader
    (:mod:`spgeo.datasets.icl`) converts that data set's negative fy."""
    axis, flip, c = ("y", "diag(1, -1, 1, 1)", "cy") if name == "fy" else \
        ("x", "diag(-1, 1, 1, 1)", "cx")
    icl = (" (ICL-NUIM's fy < 0: its y axis points up the image; "
           "spgeo.datasets.icl.icl_pose_to_opencv converts its poses)") if name == "fy" else ""
    return (f": a negative {name} means the data's camera {axis} axis is flipped{icl}; "
            f"spgeo's camera is OpenCV's (x right, y down): keep the image unchanged, use "
            f"{name} = {-value:g} ({c} unchanged) and convert camera-to-world poses T to "
            f"S @ T @ S with S = {flip}")


def swapped_size_hint(shape, expected_shape) -> str:
    """``"; ... look swapped ..."`` when the (H, W) of ``shape`` (an array's
    shape, (H, W[, C])) is ``expected_shape`` (a camera's (H, W)) reversed,
    else ``""``: the tail of an image-size error message."""
    hw, exp = tuple(shape[:2]), tuple(expected_shape)
    if len(hw) != 2 or hw == exp or hw != exp[::-1]:
        return ""
    return (f"; width and height look swapped: the image is {hw[1]}x{hw[0]} (width x height), "
            f"the camera {exp[1]}x{exp[0]} (PinholeCamera takes width before height; a numpy "
            "image is (height, width[, channels]))")


def check_intrinsics(fx, fy, cx, cy, width, height, what: str = "intrinsics") -> None:
    """Raise :class:`InputError` unless pinhole intrinsics (pixels) are plausible.

    Plausible means: ``fx``, ``fy`` finite and > 0; ``cx``, ``cy`` finite;
    ``width``, ``height`` positive integers; the field of view
    ``2 atan(size / (2 f))`` of each axis at most ``FOV_RANGE_DEG[1]`` and that of
    the wider axis at least ``FOV_RANGE_DEG[0]`` (strips and crops may be narrow
    along their short side); ``fx / fy`` within ``FOCAL_RATIO_RANGE``; the
    principal point inside the image or outside it by at most
    ``PRINCIPAL_POINT_MARGIN`` of the width / height.  All of these are
    invariant under :meth:`~spgeo.camera.PinholeCamera.resized` (the principal
    point scales with the image).  Intrinsics of order 1 (normalised by the image
    size) are named as such in the message.
    """
    vals = {}
    for name, value in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
        try:
            vals[name] = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{what}: {name} must be a number, got {value!r}") from None
        if not math.isfinite(vals[name]) or (name in ("fx", "fy") and vals[name] <= 0):
            kind = "finite and > 0" if name in ("fx", "fy") else "finite"
            hint = _flipped_axis_hint(name, vals[name]) \
                if name in ("fx", "fy") and -math.inf < vals[name] < 0 else ""
            raise InputError(f"{what}: {name} must be {kind}, got {value!r}{hint}")
    for name, value in (("width", width), ("height", height)):
        try:
            ok = int(value) == value and int(value) > 0
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise InputError(f"{what}: {name} must be a positive integer, got {value!r}")
    fx, fy, cx, cy = vals["fx"], vals["fy"], vals["cx"], vals["cy"]
    w, h = int(width), int(height)
    desc = f"{what} fx={fx:g}, fy={fy:g}, cx={cx:g}, cy={cy:g} for a {w}x{h} image"
    hint = ""
    if max(fx, fy, abs(cx), abs(cy)) <= 2.0 and max(w, h) >= 16:
        hint = (f"; looks normalised: multiply by the image size (fx, cx by the width {w}, "
                f"fy, cy by the height {h})")
    lo, hi = FOV_RANGE_DEG
    fov_u, fov_v = _fov_deg(fx, w), _fov_deg(fy, h)
    for axis, fov in (("horizontal", fov_u), ("vertical", fov_v)):
        if fov > hi:
            raise InputError(f"{desc}: {axis} field of view {fov:.1f} deg is wider than a "
                             f"pinhole camera's {hi:g} deg (focal length too small){hint}")
    if max(fov_u, fov_v) < lo:
        raise InputError(f"{desc}: field of view {max(fov_u, fov_v):.2f} deg is narrower than "
                         f"{lo:g} deg (focal length too large: intrinsics of a larger image?)")
    rlo, rhi = FOCAL_RATIO_RANGE
    if not rlo <= fx / fy <= rhi:
        raise InputError(f"{desc}: fx / fy = {fx / fy:.3g} is outside [{rlo:g}, {rhi:g}] "
                         f"(pixels that far from square are implausible){hint}")
    m = PRINCIPAL_POINT_MARGIN
    for name, c, size in (("cx", cx, w), ("cy", cy, h)):
        if not -m * size - 0.5 <= c <= (1 + m) * size - 0.5:
            raise InputError(f"{desc}: principal point {name}={c:g} is outside the image by "
                             f"more than {100 * m:g} % of its size (expected about "
                             f"{(size - 1) / 2:g}){hint}")
