"""Hole filling and sparse-depth helpers of :mod:`spgeo.completion`.

Depth maps are (H, W) metres; sparse maps use 0 (or NaN on input) for
missing.  Pixel coordinates ``uv`` are (K, 2), u = column, v = row, pixel
centres at integers.
"""
from __future__ import annotations

import logging
from typing import Optional, Tuple

import cv2
import numpy as np
from scipy import ndimage

from ..camera import PinholeCamera
from .scales import working_pixels

__all__ = [
    "CONFIDENCE_PRIMITIVE", "CONFIDENCE_LINEAR", "CONFIDENCE_NEAREST",
    "nearest_fill", "linear_fill", "upsample", "resample_sparse", "fill_holes",
    "scattered_fill", "residual_correction",
]

log = logging.getLogger(__name__)

#: Confidence / coverage codes of :attr:`spgeo.completion.CompletionResult.confidence`.
CONFIDENCE_PRIMITIVE = 2   #: depth of a primitive with sparse support
CONFIDENCE_LINEAR = 1      #: filled by linear interpolation
CONFIDENCE_NEAREST = 0     #: filled with the nearest value (outside the hull)


def nearest_fill(values: np.ndarray, known: Optional[np.ndarray] = None) -> np.ndarray:
    """Copy of ``values`` with every pixel where ``known`` is False replaced by
    the value of the nearest known pixel (Euclidean; one distance transform).
    ``known`` defaults to finite and > 0."""
    values = np.asarray(values, dtype=np.float64)
    if known is None:
        known = np.isfinite(values) & (values > 0)
    if not np.any(known):
        raise ValueError("nearest_fill: no known pixel")
    if np.all(known):
        return values.copy()
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return values[iy, ix]


def linear_fill(uv: np.ndarray, values: np.ndarray, shape: Tuple[int, int],
                query: Optional[np.ndarray] = None) -> np.ndarray:
    """Linear interpolation (Delaunay, ``scipy.interpolate.LinearNDInterpolator``)
    of scattered ``values`` at pixels ``uv`` (K, 2) (u = column, v = row).

    Returns an (H, W) map holding the interpolant at the pixels of ``query``
    ((H, W) bool; default all) and NaN elsewhere, including query pixels
    outside the convex hull.  Fewer than 3 or collinear points give all NaN.
    """
    from scipy.interpolate import LinearNDInterpolator

    h, w = shape
    out = np.full((h, w), np.nan)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if uv.shape[0] < 3:
        return out
    # only pixels in the points' bounding box can lie in their convex hull
    u0, v0 = (max(0, int(np.ceil(uv[:, i].min()))) for i in (0, 1))
    u1, v1 = min(w, int(np.floor(uv[:, 0].max())) + 1), min(h, int(np.floor(uv[:, 1].max())) + 1)
    box = np.zeros((max(v1 - v0, 0), max(u1 - u0, 0)), bool)
    box[...] = True if query is None else np.asarray(query, bool)[v0:v1, u0:u1]
    bv, bu = np.nonzero(box)
    if bv.size == 0:
        return out
    try:
        interp = LinearNDInterpolator(uv, values)
    except Exception as exc:  # qhull errors: all points collinear / coincident
        log.debug("linear_fill: triangulation failed (%s)", exc)
        return out
    out[bv + v0, bu + u0] = interp(np.stack([bu + u0, bv + v0], 1).astype(np.float64))
    return out


def upsample(depth_w: np.ndarray, conf_w: np.ndarray, camera: PinholeCamera
             ) -> Tuple[np.ndarray, np.ndarray]:
    """Bring a complete working-resolution depth map (bilinear) and its
    confidence codes (nearest) to ``camera``'s size."""
    if depth_w.shape == camera.shape:
        return depth_w, conf_w
    depth = cv2.resize(depth_w.astype(np.float64), camera.size, interpolation=cv2.INTER_LINEAR)
    conf = cv2.resize(conf_w, camera.size, interpolation=cv2.INTER_NEAREST)
    return depth, conf


def resample_sparse(uv: np.ndarray, d: np.ndarray, camera: PinholeCamera,
                    target: PinholeCamera) -> np.ndarray:
    """Sparse points of ``camera`` as a sparse map of ``target`` (rounded pixel;
    points sharing a pixel keep the mean)."""
    if target.size == camera.size:
        out = np.zeros(camera.shape)
        out[uv[:, 1].astype(np.int64), uv[:, 0].astype(np.int64)] = d
        return out
    flat = working_pixels(uv, camera, target)
    npix = target.width * target.height
    tot = np.bincount(flat, weights=d, minlength=npix)
    cnt = np.bincount(flat, minlength=npix)
    return np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0).reshape(target.shape)


def scattered_fill(uv: np.ndarray, values: np.ndarray, shape: Tuple[int, int]) -> np.ndarray:
    """(H, W) map of scattered ``values`` at integer pixels ``uv`` (K >= 1, u =
    column, v = row): the values themselves at their pixels, linear
    interpolation (:func:`linear_fill`) inside their convex hull, the nearest
    value outside it."""
    uv = np.asarray(uv).reshape(-1, 2).astype(np.int64)
    out = linear_fill(uv, values, shape)
    out[uv[:, 1], uv[:, 0]] = values
    return nearest_fill(out, np.isfinite(out))


def fill_holes(depth: np.ndarray, covered: np.ndarray, sparse: np.ndarray
               ) -> Tuple[np.ndarray, np.ndarray]:
    """Fill ``~covered`` pixels: linear interpolation of hole-border depths and
    sparse points inside holes, then nearest.  Returns ``(depth, confidence)``."""
    h, w = depth.shape
    conf = np.full((h, w), CONFIDENCE_NEAREST, np.uint8)
    conf[covered] = CONFIDENCE_PRIMITIVE
    holes = ~covered
    if not holes.any():
        return depth, conf
    border = covered & cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    in_hole = holes & (sparse > 0)
    known = border | in_hole
    vals = np.where(covered, depth, sparse)
    kv, ku = np.nonzero(known)
    lin = linear_fill(np.stack([ku, kv], 1), vals[kv, ku], (h, w), holes)
    out = depth.copy()
    lin_ok = holes & np.isfinite(lin)
    out[lin_ok] = lin[lin_ok]
    out[in_hole] = sparse[in_hole]
    conf[lin_ok | in_hole] = CONFIDENCE_LINEAR
    rest = holes & ~(lin_ok | in_hole)
    if rest.any():
        filled = nearest_fill(np.where(rest, np.nan, out), ~rest)
        out[rest] = filled[rest]
    return out, conf


def residual_correction(depth: np.ndarray, uv: np.ndarray, values: np.ndarray, clip: float,
                        weight: Optional[np.ndarray] = None) -> np.ndarray:
    """``depth`` corrected towards its sparse points by a smooth multiplicative field.

    At each sparse pixel the log-residual ``log(value) - log(depth)`` is clipped
    to ``[-clip, clip]``; the field interpolates these linearly (Delaunay) and
    takes the nearest value outside their convex hull; the result is
    ``depth * exp(weight * field)``.  Where ``weight`` is 1 (default everywhere)
    the result at the sparse pixels therefore equals the
    point where the residual is within ``clip`` and moves by ``clip`` towards it
    otherwise (a point the robust fits rejected cannot drag its surroundings by
    more than the factor ``exp(clip)``).

    Args:
        depth: (H, W) metres, finite and > 0.
        uv: (K, 2) integer pixel positions (u = column, v = row) inside the map.
        values: (K,) metres > 0.
        clip: largest correction in log units (>= 0; 0 returns ``depth``).
        weight: (H, W) factor in [0, 1] on the field (None: 1).
    Returns:
        (H, W) float64 metres, finite and > 0.
    """
    depth = np.asarray(depth, dtype=np.float64)
    uv = np.asarray(uv).reshape(-1, 2)
    if clip <= 0 or uv.shape[0] == 0:
        return depth
    u = uv[:, 0].astype(np.int64)
    v = uv[:, 1].astype(np.int64)
    r = np.clip(np.log(np.asarray(values, dtype=np.float64).reshape(-1)) - np.log(depth[v, u]),
                -clip, clip)
    field = scattered_fill(np.stack([u, v], 1), r, depth.shape)
    if weight is not None:
        field = field * weight
    return depth * np.exp(field)
