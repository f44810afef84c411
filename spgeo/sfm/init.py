"""Few-view SfM initialisation from feature-based two-view geometry (docs/design.md §5).

Each supporting view gets a relative pose from :func:`spgeo.twoview.estimate_relative_pose`;
the inliers of the view with the most inliers are triangulated into a sparse reference depth
that sets each primitive's initial log-scale, and the other views' translations are scaled to
that map.
"""
from __future__ import annotations

import logging
from typing import List, Sequence, Tuple

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose
from ..primitives import PrimitiveSet

__all__ = ["twoview_initialisation", "triangulate_depths"]

log = logging.getLogger(__name__)


def triangulate_depths(T_ref_tgt: np.ndarray, camera: PinholeCamera, pts_ref: np.ndarray,
                       pts_tgt: np.ndarray) -> np.ndarray:
    """Reference-frame depths (units of ``|t|``) of matched pixels; NaN if behind
    either camera."""
    T_tr = invert_pose(T_ref_tgt)
    Kinv = camera.K_inv
    x1 = (np.c_[pts_ref, np.ones(len(pts_ref))] @ Kinv.T)[:, :2].T
    x2 = (np.c_[pts_tgt, np.ones(len(pts_tgt))] @ Kinv.T)[:, :2].T
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = T_tr[:3]
    Xh = cv2.triangulatePoints(P1, P2, x1.astype(np.float64), x2.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):   # points at infinity: NaN
        X = (Xh[:3] / Xh[3]).T
        z_tgt = X @ T_tr[2, :3] + T_tr[2, 3]
        return np.where((X[:, 2] > 0) & (z_tgt > 0), X[:, 2], np.nan)


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
    sparse = np.full(cam.shape, np.nan)
    u = np.round((r.points_ref[:, 0] + 0.5) * sx - 0.5).astype(int)
    v = np.round((r.points_ref[:, 1] + 0.5) * sy - 0.5).astype(int)
    keep = np.isfinite(z) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    sparse[v[keep], u[keep]] = z[keep]
    s, n = prims.fit_log_scales(sparse)
    if np.any(np.isfinite(s)):
        s = np.where(np.isfinite(s), s, np.nanmedian(s))
        prims = prims.with_log_scales(s)
    report["twoview_points"] = int(keep.sum())
    report["primitives_with_points"] = int(np.sum(n > 0))
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
