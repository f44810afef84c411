"""The depth front-end from the first frame (issue 53): four synthetic rooms (seed, pose step),
50 frames at 160x120, inline mapping; Sim(3) and SE(3) ATE (the depth run is metric: SE(3) is
the measure that sees its scale) of the posed frames and the status counts.

    python scripts/depth_start_probe.py
"""
import logging

import numpy as np

from spgeo import synthetic
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.similarity import umeyama
from spgeo.vo import MappingConfig, Odometry, OdometryConfig


def rmse(est, gt, with_scale):
    S = umeyama(est, gt, with_scale=with_scale)
    return float(np.sqrt(np.mean(np.sum(((S[:3, :3] @ est.T).T + S[:3, 3] - gt) ** 2, 1))))


def main():
    logging.basicConfig(level=logging.ERROR)
    cam = synthetic.default_camera(160, 120)
    for seed, step in ((0, 3), (1, 3), (2, 5), (3, 2)):
        poses = synthetic.make_trajectory(step * 50, seed)[::step]
        scene = synthetic.SyntheticScene.generate(seed)
        vo = Odometry(cam, OdometryConfig(mapping=MappingConfig(mode="inline")),
                      make_frontend("depth", FrontEndConfig(working_size=(160, 120))))
        for i, T in enumerate(poses):
            r = scene.render(cam, T)
            vo.track(Frame(r.rgb, cam, float(i), depth=r.depth))
        res = vo.result()
        vo.close()
        ok = np.array([s.has_pose for s in res.statuses])
        e, g = res.poses[ok, :3, 3], poses[ok, :3, 3]
        print(f"seed {seed} step {step}: sim3 {rmse(e, g, True):.4f} se3 {rmse(e, g, False):.4f} "
              f"statuses {res.status_counts()}", flush=True)


if __name__ == "__main__":
    main()
