"""Warp a target image into a reference view with the reference depth and a
relative pose (used to check the pose conventions of data sets)."""
from __future__ import annotations

from typing import Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import transform_points
from ..images import sample_bilinear, to_gray

__all__ = ["warp_image", "photometric_error"]


def warp_image(image_tgt: np.ndarray, depth_ref: np.ndarray, camera: PinholeCamera,
               T_tgt_ref: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Warp ``image_tgt`` into the reference view.

    Every reference pixel with valid depth is unprojected, mapped into the
    target camera with ``T_tgt_ref = inv(T_world_tgt) @ T_world_ref``,
    projected and sampled bilinearly.  Both images use ``camera`` (undistorted).

    Returns:
        ``(warped, valid)``: the target image as seen from the reference view
        (float32, same shape as ``image_tgt``; 0 where invalid) and the (H, W)
        mask of pixels with valid depth that land inside the target image in
        front of the camera.
    """
    camera.check_image(image_tgt, "image_tgt")
    points = camera.unproject_depth_map(depth_ref)  # NaN where invalid
    uv, z = camera.project(transform_points(np.asarray(T_tgt_ref, dtype=np.float64), points))
    values, valid = sample_bilinear(np.asarray(image_tgt, dtype=np.float32),
                                    uv[..., 0], uv[..., 1])
    with np.errstate(invalid="ignore"):
        valid &= z > 0
    mask = valid[..., None] if values.ndim == 3 else valid
    return np.where(mask, values, 0.0).astype(np.float32), valid


def photometric_error(image_ref: np.ndarray, image_tgt: np.ndarray, depth_ref: np.ndarray,
                      camera: PinholeCamera, T_tgt_ref: np.ndarray) -> Tuple[float, float]:
    """Mean absolute grey-level error between ``image_ref`` and the warped target.

    Returns ``(error, valid_fraction)``; the error is NaN when no pixel is valid.
    """
    warped, valid = warp_image(to_gray(image_tgt), depth_ref, camera, T_tgt_ref)
    frac = float(valid.mean())
    if not valid.any():
        return float("nan"), frac
    return float(np.abs(warped - to_gray(image_ref))[valid].mean()), frac
