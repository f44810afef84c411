"""Probe of issue 38 (docs/results.md "On the road"): why photometric tracking
fails on the synthetic straight street.

Runs the VO (inline mapping) over the first N frames of
:func:`spgeo.synthetic.road.straight_street`, then tracks the next three frames
against the latest keyframe from their ground-truth poses (in map units) with
the keyframe's primitive log-scales as mapped, with the far (> 60 m) ones set to
the truth, and with all set to the truth (the shapes unchanged), and prints the
relative cost and the distance (metres) the tracker moves from the truth.

    python scripts/road_scale_probe.py [N]     (default 31)
"""
from __future__ import annotations

import sys

import cv2
import numpy as np

from spgeo import synthetic
from spgeo.camera import PinholeCamera
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.geometry import invert_pose
from spgeo.synthetic.road import straight_street
from spgeo.vo import MappingConfig, Odometry, OdometryConfig
from spgeo.vo.tracking import track_frame


def _scale_errors(road, kf, T_world_cam):
    """``({primitive id: (log-scale error about the keyframe's median, median true
    depth m)} for primitives of at least 50 pixels with truth, map units per metre)``."""
    pr = kf.primitives
    c = pr.camera
    G = road.scene.render_depth(PinholeCamera(c.fx, c.fy, c.cx, c.cy, c.width, c.height),
                                T_world_cam)
    D, L = pr.depth_map(), pr.label_image()
    ok = np.isfinite(D) & (D > 0) & np.isfinite(G) & (L >= 0)
    e = np.log(D) - np.log(G)
    med = float(np.median(e[ok & (G < 60)]))
    out = {}
    for pid in np.unique(L[ok]):
        m = ok & (L == pid)
        if m.sum() >= 50:
            out[int(pid)] = (float(np.median(e[m]) - med), float(np.median(G[m])))
    return out, float(np.exp(med))


def main(n: int = 31) -> None:
    road = straight_street()
    poses = road.drive()[:n + 3]
    cam = synthetic.street_camera()
    frames = synthetic.render_frames(road.scene, cam, poses, supersample=2)
    vo = Odometry(cam, OdometryConfig(mapping=MappingConfig(mode="inline")),
                  make_frontend("classical", FrontEndConfig(working_size=(cam.width, cam.height))))
    for f in frames[:n]:
        vo.track(f)
    latest = vo._map.latest            # a probe: reads the map's latest keyframe
    kf, i0 = latest.keyframe, latest.frame
    errors, units = _scale_errors(road, kf, poses[i0])
    ls = np.asarray(kf.primitives.log_scales, float)
    for name in ("as mapped", "far set to truth", "all set to truth"):
        l2 = ls.copy()
        for pid, (err, depth) in errors.items():
            if name == "all set to truth" or (name == "far set to truth" and depth > 60):
                l2[pid] -= err
        probe = kf.rebuilt(kf.primitives.with_log_scales(l2), kf.T_world_kf)
        row = []
        for j in (i0 + 1, i0 + 2, i0 + 3):
            T_rel = invert_pose(poses[i0]) @ poses[j]
            T_rel[:3, 3] *= units
            T0 = kf.T_world_kf @ T_rel
            h, w = kf.input_shape[:2]
            img = cv2.resize(np.asarray(frames[j].image, np.float32), (w, h),
                             interpolation=cv2.INTER_AREA)
            tr = track_frame(probe, img, T0, (0, 0), vo.config.tracker)
            moved = np.linalg.norm((invert_pose(T0) @ tr.T_world_frame)[:3, 3]) / units
            row.append(f"+{j - i0}: cost {tr.relative_cost:.3f}, {moved:.3f} m")
        print(f"keyframe at frame {i0}, scales {name}: " + "; ".join(row))
    vo.close()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 31)
