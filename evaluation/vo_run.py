"""Run spgeo's monocular VO (first version) on a data set and report Sim(3) ATE.

    python -m spgeo.evaluation.vo_run --dataset 7scenes PATH --frames 0:100 \\
        [--resolution 160x120] [--frontend classical|depth] [--out DIR]

The ``depth`` front-end reads the sensor depth (oracle normals and initial
scales); ``classical`` never reads depth.  ATE is per-frame, Sim(3)-aligned
(evo), over the frames not flagged 'lost'.
"""
from __future__ import annotations

import argparse
import time
from typing import Optional, Sequence, Tuple

import cv2
import numpy as np
from tqdm import tqdm

from spgeo.datasets import open_dataset
from spgeo.evaluation.trajectory import ate_sim3
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.odometry import Odometry, OdometryConfig

__all__ = ["run_vo", "main"]


def run_vo(frames, resolution: Tuple[int, int] = (160, 120), frontend: str = "classical",
           config: OdometryConfig = OdometryConfig(), progress: bool = True):
    """VO over a frame sequence resized to ``resolution``; returns
    ``(odometry, ground-truth poses (or None per frame), frames per second)``."""
    frames = list(frames)
    if not frames:
        raise ValueError("run_vo: no frames")
    cam = frames[0].camera.resized(*resolution)
    fe = make_frontend(frontend, FrontEndConfig(working_size=resolution))
    vo = Odometry(cam, config, fe)
    gt = []
    t0 = time.perf_counter()
    for f in tqdm(frames, disable=not progress, desc="vo", unit="frame"):
        img = cv2.resize(f.image, resolution, interpolation=cv2.INTER_AREA)
        depth = None
        if fe.uses_depth and f.depth is not None:
            depth = cv2.resize(f.depth, resolution, interpolation=cv2.INTER_NEAREST)
        vo.track(Frame(img, cam, f.timestamp, depth, f.T_world_cam, f.name))
        gt.append(f.T_world_cam)
    return vo, gt, len(frames) / (time.perf_counter() - t0)


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", nargs=2, metavar=("KIND", "PATH"), required=True)
    ap.add_argument("--frames", default=None, help="A:B[:S] frame numbers")
    ap.add_argument("--resolution", default="160x120", help="WxH (default 160x120)")
    ap.add_argument("--frontend", default="classical", choices=["classical", "depth"])
    ap.add_argument("--out", default=None, help="write trajectory.txt, keyframes.txt, report.json")
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.resolution.lower().split("x"))
    seq = open_dataset(args.dataset[0], args.dataset[1], frames=args.frames)
    vo, gt, fps = run_vo(seq, (w, h), args.frontend)
    r = vo.result()
    if args.out:
        vo.save(args.out)
    ok = np.array([s != "lost" for s in r.statuses])
    print(f"{len(r.statuses)} frames, {int((~ok).sum())} lost, {int(np.sum(r.is_keyframe))} "
          f"keyframes, {fps:.1f} FPS (front-end {args.frontend}, {w}x{h})")
    if all(T is not None for T in gt):
        a = ate_sim3((r.timestamps[ok], r.poses[ok]), (r.timestamps, np.array(gt)))
        print(f"Sim(3) ATE per-frame: {a.rmse:.3f} m = {a.rmse_percent_of_length:.1f}% of "
              f"{a.trajectory_length:.2f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
