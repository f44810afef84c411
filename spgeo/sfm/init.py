"""Few-view SfM initialisation from feature-based two-view geometry (docs/design.md §5).

Each supporting view gets a relative pose from :func:`spgeo.twoview.estimate_relative_pose`;
the inliers of the view with the most inliers are triangulated into a sparse reference depth
that sets each primitive's initial log-scale, and the other views' translations are scaled to
that map.
"""
from __future__ import annotations

import logging
from typing import List, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..primitives import PrimitiveSet
from ..triangulation import triangulate

__all__ = ["twoview_initialisation", "triangulate_depths", "scales_from_points"]

log = logging.getLogger(__name__)


def triangulate_depths(T_ref_tgt: np.ndarray, camera: PinholeCamera, pts_ref: np.ndarray,
                       pts_tgt: np.ndarray) -> np.ndarray:
    """(N,) reference-frame depths (units of ``|t|``) of matched pixels ``pts_ref``,
    ``pts_tgt`` (N, 2) of cameras related by ``T_ref_tgt`` (target-to-reference), by
    :func:`spgeo.triangulation.triangulate` with the reference as the world; NaN
    behind either camera or at infinity."""
    X = triangulate(camera, [np.eye(4), T_ref_tgt], np.stack([pts_ref, pts_tgt], axis=1))
    return X[:, 2]


def scales_from_points(prims: PrimitiveSet, camera: PinholeCamera, pixels: np.ndarray,
                       depths: np.ndarray) -> Tuple[PrimitiveSet, int, int]:
    """``prims`` with log-scales set by a robust median over sparse reference depths.

    Args:
        prims: reference primitives (at their own, possibly smaller, working camera).
        camera: the camera of ``pixels`` (the reference image's).
        pixels: (N, 2) reference pixels (spgeo convention) of the points.
        depths: (N,) their depths (NaN: unused).
    Returns:
        ``(prims, points used, primitives with a point)``; primitives without a
        point take the median log-scale of the others; ``prims`` unchanged when no
        primitive has a point.
    """
    cam = prims.camera
    sx, sy = cam.width / camera.width, cam.height / camera.height
    sparse = np.full(cam.shape, np.nan)
    u = np.round((pixels[:, 0] + 0.5) * sx - 0.5).astype(int)
    v = np.round((pixels[:, 1] + 0.5) * sy - 0.5).astype(int)
    keep = np.isfinite(depths) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    sparse[v[keep], u[keep]] = depths[keep]
    s, n = prims.fit_log_scales(sparse)
    if np.any(np.isfinite(s)):
        s = np.where(np.isfinite(s), s, np.nanmedian(s))
        prims = prims.with_log_scales(s)
    return prims, int(keep.sum()), int(np.sum(n > 0))


def twoview_initialisation(ref_image: np.ndarray, views: Sequence[np.ndarray],
                           camera: PinholeCamera, prims: PrimitiveSet, report: dict
                           ) -> Tuple[List[np.ndarray], PrimitiveSet]:
    """Initial view poses and primitive log-scales from feature-based two-view geometry.

    Args:
        ref_image, views: reference and supporting images at ``camera``'s resolution.
        camera: camera of the images (feature matching and triangulation run there).
        prims: reference primitives (at their own, possibly smaller, working camera).
        report: dict updated with ``twoview_status`` (per view) and, when a view
            succeeded, ``twoview_points`` and ``primitives_with_points``.

    Returns:
        ``(poses, prims)``: 4x4 ``T_ref_view`` per view, the two-view estimate where
        there is one, else identity (when no view succeeded only ``low_parallax``
        estimates are kept), translations in units of the best view's baseline; and
        ``prims`` with log-scales set by a robust median over the triangulated inliers
        (unchanged when no primitive has a point).
    """
    from ..twoview import estimate_relative_pose

    cam = prims.camera
    sx, sy = cam.width / camera.width, cam.height / camera.height
    results = [estimate_relative_pose(ref_image, v, camera) for v in views]
    report["twoview_status"] = [r.status for r in results]
    poses = [np.eye(4) if r.T_ref_tgt is None else r.T_ref_tgt.copy() for r in results]
    ok = [j for j, r in enumerate(results) if r.ok]
    if not ok:
        log.info("two-view initialisation failed for every view; starting at identity")
        return [p if results[j].status == "low_parallax" else np.eye(4)
                for j, p in enumerate(poses)], prims
    # sparse reference depth from the view with the most inliers (its baseline = 1)
    best = max(ok, key=lambda j: results[j].num_inliers)
    r = results[best]
    z = triangulate_depths(r.T_ref_tgt, camera, r.points_ref, r.points_tgt)
    prims, n_points, n_prims = scales_from_points(prims, camera, r.points_ref, z)
    report["twoview_points"] = n_points
    report["primitives_with_points"] = n_prims
    # other views: translation magnitude from their own triangulation vs the map
    depth_map = prims.depth_map()
    for j in ok:
        if j == best:
            continue
        rj = results[j]
        zj = triangulate_depths(rj.T_ref_tgt, camera, rj.points_ref, rj.points_tgt)
        uj = np.clip(np.round((rj.points_ref[:, 0] + 0.5) * sx - 0.5).astype(int), 0, cam.width - 1)
        vj = np.clip(np.round((rj.points_ref[:, 1] + 0.5) * sy - 0.5).astype(int), 0, cam.height - 1)
        ratio = depth_map[vj, uj] / zj
        ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
        if ratio.size >= 5:
            poses[j][:3, 3] *= float(np.median(ratio))
    return poses, prims
