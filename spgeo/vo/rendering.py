"""Z-buffered rendering of primitives into another camera, and keyframe scale
re-initialisation from rendered depth (docs/design.md §5, VO: "New KF depth").

A new keyframe's primitives have unknown log-scales; the previous keyframes'
geometry, rendered into the new keyframe, gives each primitive the median of
(rendered log-depth - unscaled log-depth) over its pixels; primitives nothing
renders into get the median of the others.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import transform_points
from ..primitives import PrimitiveSet

__all__ = ["render_depth", "render_primitives", "init_scales_from_render", "ScaleInit"]


def render_depth(points_cam: np.ndarray, camera: PinholeCamera, splat: int = 1,
                 tolerance: float = 0.0) -> np.ndarray:
    """Z-buffer camera-frame points (metres) into a (H, W) depth map (NaN: empty).

    Each point writes its depth to the pixel it projects to (rounded), and to
    the ``splat x splat`` block around it when ``splat > 1`` (closes the gaps of
    a cloud rendered at a higher resolution or from a closer view).  With
    ``tolerance = 0`` the nearest depth wins; with ``tolerance > 0`` a pixel
    gets the geometric mean of the depths within ``tolerance`` (log-depth
    difference) of its nearest one: several estimates of the same surface are
    averaged instead of the smallest winning, and surfaces further behind stay
    occluded.  Points behind the camera are ignored.
    """
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(pts)):
        pts = pts[np.all(np.isfinite(pts), axis=1)]
    uv, z = camera.project(pts)
    ok = np.isfinite(uv[:, 0]) & (z > 0)
    uv, z = uv[ok], z[ok]
    npix = camera.width * camera.height
    r = int(splat) // 2
    pix, zs = [], []
    for dv in range(-r, int(splat) - r):
        for du in range(-r, int(splat) - r):
            u = np.rint(uv[:, 0]).astype(np.int64) + du
            v = np.rint(uv[:, 1]).astype(np.int64) + dv
            inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
            pix.append(v[inside] * camera.width + u[inside])
            zs.append(z[inside])
    pix = np.concatenate(pix) if pix else np.zeros(0, np.int64)
    zs = np.concatenate(zs) if zs else np.zeros(0)
    zbuf = np.full(npix, np.inf)
    np.minimum.at(zbuf, pix, zs)
    if tolerance > 0 and zs.size:
        logz = np.log(zs)
        near = logz <= np.log(zbuf[pix]) + float(tolerance)
        total = np.bincount(pix[near], weights=logz[near], minlength=npix)
        count = np.bincount(pix[near], minlength=npix)
        zbuf = np.where(count > 0, np.exp(total / np.maximum(count, 1)), np.inf)
    out = np.where(np.isfinite(zbuf), zbuf, np.nan)
    return out.reshape(camera.shape)


def render_primitives(sources: Sequence[Tuple[PrimitiveSet, np.ndarray]], camera: PinholeCamera,
                      T_world_cam: np.ndarray, splat: int = 1, tolerance: float = 0.0
                      ) -> np.ndarray:
    """Render several primitive sets, each with its ``T_world_src`` pose
    (camera-to-world), into a camera at ``T_world_cam``; z-buffered depth
    (metres; ``splat`` and ``tolerance`` as in :func:`render_depth`)."""
    from ..geometry import invert_pose

    T_cam_world = invert_pose(T_world_cam)
    clouds = [transform_points(T_cam_world @ np.asarray(T_ws, float), prims.point_cloud().points)
              for prims, T_ws in sources]
    pts = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    return render_depth(pts, camera, splat, tolerance)


@dataclass
class ScaleInit:
    """Result of :func:`init_scales_from_render`: the primitives with new
    log-scales, how many pixels supported each, and which fell back to the
    median of the others."""

    primitives: PrimitiveSet
    n_support: np.ndarray
    fallback: np.ndarray


def init_scales_from_render(primitives: PrimitiveSet, rendered_depth: np.ndarray,
                            min_support: int = 5) -> ScaleInit:
    """Log-scale of each primitive = median of (log rendered depth - log D) over
    its pixels with a rendered depth.  A primitive with fewer than ``min_support``
    such pixels keeps its own log-scale shifted by the median shift of the
    fitted ones: with equal incoming scales (a monocular front-end) that is the
    median of the others' scales; with a depth-using front-end it keeps the
    relative depth the front-end measured (after a rotation into unmapped
    space, the median alone would flatten the new part of the view onto the
    old).  Raises ``ValueError`` if no primitive has support (nothing of the
    map is visible: re-initialise)."""
    s, n = primitives.fit_log_scales(rendered_depth, min_points=min_support)
    ok = np.isfinite(s)
    if not ok.any():
        raise ValueError("no primitive overlaps the rendered depth: the map is not visible "
                         "from this camera")
    fallback = ~ok
    own = np.asarray(primitives.log_scales, dtype=np.float64)
    s = np.where(ok, s, own + np.median(s[ok] - own[ok]))
    return ScaleInit(primitives.with_log_scales(s), n, fallback)
