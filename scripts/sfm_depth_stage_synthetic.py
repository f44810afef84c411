"""Few-view SfM reference depth on synthetic rooms (exact depth) with and without the
depth stage (``SfMConfig.depth_stage``, issue 54), in one run.

    python scripts/sfm_depth_stage_synthetic.py [--angles 5 20] [--seeds 0 1 2 3]

Prints per (angle, seed) the AbsRel / delta<1.25 of the reference depth after one
median scale (:func:`spgeo.evaluation.depth_eval.sfm_reference_depth`), the rotation error of
the views (degrees) and the seconds of each solve.
"""
import argparse
import time

import numpy as np

from spgeo.evaluation.depth_eval import sfm_reference_depth
from spgeo.evaluation.pose_metrics import rotation_error_deg
from spgeo.evaluation.sfm.baselines import view_set_frames
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.sfm import SfMConfig, few_view_sfm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--angles", type=float, nargs="+", default=[5.0, 20.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = ap.parse_args()
    print("| angle | seed | stage | AbsRel | d<1.25 | rot err deg | s |")
    print("|---|---|---|---|---|---|---|")
    for angle in args.angles:
        for seed in args.seeds:
            f = view_set_frames(angle, seed, (320, 240))
            for stage in (False, True):
                fe = make_frontend("classical", FrontEndConfig(working_size=(320, 240)))
                t = time.perf_counter()
                res = few_view_sfm(f[0].image, [v.image for v in f[1:]], f[0].camera, fe,
                                   SfMConfig(depth_stage=stage))
                dt = time.perf_counter() - t
                m = sfm_reference_depth(res, f[0].depth)
                rot = [rotation_error_deg(T, np.linalg.inv(f[0].T_world_cam) @ v.T_world_cam)
                       for T, v in zip(res.T_ref_view, f[1:])]
                print(f"| {angle:g} | {seed} | {'on' if stage else 'off'} | "
                      f"{m['abs_rel']:.3f} | {m['delta_1.25']:.3f} | {np.mean(rot):.2f} | {dt:.1f} |",
                      flush=True)


if __name__ == "__main__":
    main()
