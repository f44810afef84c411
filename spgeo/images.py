"""Image utilities: conversion to float [0, 1], Gaussian pyramid, Scharr
gradients and vectorised bilinear sampling with a validity mask."""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import List, Optional, Tuple

import cv2
import numpy as np

from .camera import PinholeCamera
from .validation import InputError, read_image_bytes

__all__ = [
    "to_float_image", "to_gray", "read_raw_image", "load_image", "blur121", "gaussian_pyramid", "Pyramid",
    "scharr_gradients", "sample_bilinear", "featureless",
]

_GREY_WEIGHTS = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def to_float_image(image: np.ndarray) -> np.ndarray:
    """Convert uint8 / uint16 / float images to float32 in [0, 1].

    Float input must already lie in [0, 1] (a small tolerance is clipped).
    Raises :class:`~spgeo.validation.InputError` for another shape or dtype
    (bool, signed integers, ...), an empty image, NaN / inf, or float values
    outside [0, 1].
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise InputError(f"image must be (H, W) or (H, W, 1|3|4), got shape {image.shape}")
    if image.size == 0:
        raise InputError(f"image is empty (shape {image.shape})")
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.dtype == np.uint8:
        return image.astype(np.float32) / 255.0
    if image.dtype == np.uint16:
        return image.astype(np.float32) / 65535.0
    if np.issubdtype(image.dtype, np.floating):
        out = image.astype(np.float32)
        bad = int(np.count_nonzero(~np.isfinite(out)))
        if bad:
            raise InputError(f"image contains {bad} NaN or inf values")
        lo, hi = float(out.min()), float(out.max())
        if lo < -1e-3 or hi > 1 + 1e-3:
            raise InputError(f"float image values must lie in [0, 1], got [{lo:.4g}, {hi:.4g}]")
        return np.clip(out, 0.0, 1.0)
    raise InputError(f"unsupported image dtype {image.dtype}: expected uint8, uint16 or float "
                     "in [0, 1]")


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 grey image in [0, 1] from grey or RGB input (BT.601 weights)."""
    image = to_float_image(image)
    if image.ndim == 2:
        return image
    return image @ _GREY_WEIGHTS


def read_raw_image(path, what: str = "image") -> np.ndarray:
    """The file's pixels as stored (``cv2.IMREAD_UNCHANGED``: BGR order, any dtype).

    Raises ``FileNotFoundError`` for a missing file and
    :class:`~spgeo.validation.InputError` for a folder, an unreadable or empty
    file, a truncated PNG / JPEG (:func:`spgeo.validation.read_image_bytes`) or
    content OpenCV cannot decode; messages name the ``what`` file.
    """
    path = os.fspath(path)
    data = read_image_bytes(path, what)
    raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise InputError(f"cannot decode {what} file {path}: not an image in a format OpenCV "
                         "reads (PNG, JPEG, TIFF, ...), or corrupt")
    return raw


def load_image(path, grey: bool = False) -> np.ndarray:
    """Read an image file as float32 RGB (H, W, 3) or grey (H, W) in [0, 1].

    Raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming
    the file (:func:`read_raw_image`).
    """
    raw = read_raw_image(path)
    if raw.ndim == 3:
        raw = cv2.cvtColor(raw[..., :3], cv2.COLOR_BGR2RGB)
    img = to_float_image(raw)
    return to_gray(img) if grey else img


def blur121(image: np.ndarray) -> np.ndarray:
    """Separable [1 2 1]^2 / 16 blur with replicated borders (float32)."""
    k = np.array([0.25, 0.5, 0.25], dtype=np.float32)
    return cv2.sepFilter2D(np.asarray(image, dtype=np.float32), -1, k, k,
                           borderType=cv2.BORDER_REPLICATE)


@dataclass
class Pyramid:
    """Gaussian pyramid: ``images[0]`` is full resolution; ``cameras[l]`` matches ``images[l]``."""

    images: List[np.ndarray]
    cameras: List[PinholeCamera]

    def __len__(self) -> int:
        return len(self.images)

    def coarse_to_fine(self) -> List[Tuple[int, np.ndarray, PinholeCamera]]:
        """``[(level, image, camera), ...]`` from the coarsest level to level 0."""
        return [(lvl, self.images[lvl], self.cameras[lvl]) for lvl in reversed(range(len(self)))]


def gaussian_pyramid(image: np.ndarray, camera: PinholeCamera, levels: int,
                     min_size: int = 8) -> Pyramid:
    """Blur with [1 2 1]^2/16 and keep every second pixel, ``levels`` levels in total.

    Level ``l`` pixel ``i`` is level-0 pixel ``2^l i``, so the camera of level
    ``l`` is ``camera.decimated(2)`` applied ``l`` times.  Stops early when a
    side would drop below ``min_size`` pixels.
    """
    if levels < 1:
        raise ValueError(f"gaussian_pyramid: levels must be >= 1, got {levels}")
    image = np.asarray(camera.check_image(image), dtype=np.float32)
    images, cameras = [image], [camera]
    for _ in range(levels - 1):
        cam = cameras[-1].decimated(2)
        if min(cam.width, cam.height) < min_size:
            break
        images.append(blur121(images[-1])[::2, ::2].copy())
        cameras.append(cam)
    return Pyramid(images, cameras)


def scharr_gradients(image: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Scharr derivatives (d/du, d/dv) in intensity per pixel (kernel normalised by 1/32)."""
    image = np.asarray(image, dtype=np.float32)
    gu = cv2.Scharr(image, cv2.CV_32F, 1, 0, scale=1.0 / 32.0, borderType=cv2.BORDER_REPLICATE)
    gv = cv2.Scharr(image, cv2.CV_32F, 0, 1, scale=1.0 / 32.0, borderType=cv2.BORDER_REPLICATE)
    return gu, gv


def sample_bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray,
                    return_gradient: bool = False,
                    gradients: Optional[Tuple[np.ndarray, np.ndarray]] = None):
    """Bilinear sampling at float pixel coordinates, vectorised.

    Args:
        image: (H, W) or (H, W, C) array.
        u, v: arrays of equal shape, column / row coordinates in pixels.
        return_gradient: also return the image gradient at the samples.  By
            default it is the analytic derivative of the bilinear interpolant;
            pass ``gradients=(gu, gv)`` (e.g. Scharr) to sample those instead.

    Returns:
        ``(values, valid)`` or ``(values, valid, (du, dv))``.  ``valid`` is
        False where the sample falls outside ``[0, W-1] x [0, H-1]`` or is NaN;
        values (and gradients) there are 0.
    """
    image = np.asarray(image)
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    if u.shape != v.shape:
        raise ValueError(f"sample_bilinear: u {u.shape} and v {v.shape} differ in shape")
    h, w = image.shape[:2]
    with np.errstate(invalid="ignore"):
        valid = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc = np.where(valid, u, 0.0)
    vc = np.where(valid, v, 0.0)
    u0 = np.minimum(np.floor(uc).astype(np.int64), max(w - 2, 0))
    v0 = np.minimum(np.floor(vc).astype(np.int64), max(h - 2, 0))
    u1 = np.minimum(u0 + 1, w - 1)
    v1 = np.minimum(v0 + 1, h - 1)
    au = uc - u0
    av = vc - v0
    if image.ndim == 3:
        au_, av_ = au[..., None], av[..., None]
        vmask = valid[..., None]
    else:
        au_, av_, vmask = au, av, valid
    i00 = image[v0, u0]
    i01 = image[v0, u1]
    i10 = image[v1, u0]
    i11 = image[v1, u1]
    top = i00 + (i01 - i00) * au_
    bot = i10 + (i11 - i10) * au_
    values = np.where(vmask, top + (bot - top) * av_, 0.0)
    if not return_gradient:
        return values, valid
    if gradients is not None:
        gu, _ = sample_bilinear(gradients[0], u, v)
        gv, _ = sample_bilinear(gradients[1], u, v)
    else:
        gu = np.where(vmask, (i01 - i00) * (1 - av_) + (i11 - i10) * av_, 0.0)
        gv = np.where(vmask, bot - top, 0.0)
    return values, valid, (gu, gv)


def featureless(image: np.ndarray) -> bool:
    """Whether ``image`` is (nearly) constant: its standard deviation under 1e-3 of
    its largest magnitude (at least 1), e.g. a covered lens (the VO never
    re-initialises a map from one)."""
    grey = np.asarray(image, dtype=np.float64)
    return float(np.std(grey)) < 1e-3 * max(float(np.max(np.abs(grey))), 1.0)
