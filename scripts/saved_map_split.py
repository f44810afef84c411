"""Issue 53's goal measured: a sequence split in two, the first half run and its map saved
(``Odometry.saved_map``), the second half run in the loaded map; both trajectories joined and
aligned to the ground truth by one Sim(3), against one run over the whole sequence.

    python scripts/saved_map_split.py 7scenes kitti syn0 syn1 syn0_60 syn2_60

``7scenes`` (../shared 0:300), ``kitti`` (the shared 51-frame clip), ``synS[_N]`` (synthetic
room of seed S, N frames (default 80) at every third pose, 320x240).  Defaults of ``spgeo
vo`` (``VORunConfig()``); prints one line per sequence: joined ATE, one-run ATE, ratio, and
the second half's own Sim(3) ATE.
"""
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_dataset, run_odometry
from spgeo.metrics.ate import ate_sim3
from spgeo.vo.saved_map import SavedMap

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CFG = VORunConfig(progress=False)


def posed(run):
    res = run.result()
    return [(t, p, g) for t, p, s, g in zip(res.timestamps, res.poses, res.statuses, run.gt_poses)
            if s.has_pose and g is not None]


def ate(rows):
    ts = np.array([r[0] for r in rows])
    return ate_sim3((ts, np.array([r[1] for r in rows])), (ts, np.array([r[2] for r in rows])))


def split(name, part):
    whole, first = part(None, None), part("first", None)
    with tempfile.TemporaryDirectory() as d:
        first.odometry.saved_map().save(Path(d) / "map")
        second = part("second", SavedMap.load(Path(d) / "map"))
    joined, one = ate(posed(first) + posed(second)).rmse, ate(posed(whole)).rmse
    print(f"{name}: joined {joined:.4f} one-run {one:.4f} ratio {joined / one:.2f} "
          f"(second half alone {ate(posed(second)).rmse:.4f})", flush=True)


def dataset(kind, path, n):
    def part(which, saved):
        frames = {None: f"0:{n}", "first": f"0:{n // 2}", "second": f"{n // 2}:{n}"}[which]
        return run_dataset(kind, path, frames=frames, config=CFG, saved_map=saved)
    return part


def room(seed, n):
    cam = synthetic.default_camera(320, 240)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(seed), cam,
                                     synthetic.make_trajectory(3 * n, seed)[::3])

    def part(which, saved):
        chosen = {None: frames, "first": frames[:n // 2], "second": frames[n // 2:]}[which]
        return run_odometry(chosen, CFG, saved_map=saved)
    return part


def main(names):
    logging.basicConfig(level=logging.ERROR)
    for name in names:
        if name == "7scenes":
            split(name, dataset("7scenes", SHARED / "7scenes_redkitchen_dev", 300))
        elif name == "kitti":
            split(name, dataset("kitti", SHARED / "kitti_odometry_clip_51", 51))
        elif name.startswith("syn"):
            seed, n = (int(x) for x in (name[3:] + "_80").split("_")[:2])
            split(name, room(seed, n))
        else:
            raise SystemExit(f"unknown sequence {name!r}")


if __name__ == "__main__":
    main(sys.argv[1:])
