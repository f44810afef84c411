"""Library loop against the runner on the same frames (issue 25, "one speed").

A research stack's loop (``Odometry(camera, OdometryConfig(), make_frontend(...))`` and
``track(frame)`` on every full-size frame) against :func:`spgeo.apps.vo_run.run_dataset`
(what ``spgeo vo`` calls), alternating, ``--repeats`` times each, on frames already in
memory (no decoding in the timing).  Prints FPS of each run, the median ratio and whether
the trajectories are equal.

    python3 scripts/library_vs_cli_speed.py [DATA] [--frames 0:300] [--repeats 2]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from spgeo.apps.vo_run import VORunConfig, blas_threads, run_odometry
from spgeo.datasets import open_dataset
from spgeo.frame import Frame
from spgeo.frontend import make_frontend
from spgeo.vo import Odometry, OdometryConfig


def library_loop(frames):
    """The researcher's loop; returns (poses, seconds)."""
    cam = frames[0].camera
    vo = Odometry(cam, OdometryConfig(), make_frontend("classical"))
    t = time.perf_counter()
    with blas_threads(1):
        for f in frames:
            vo.track(Frame(f.image, cam, f.timestamp))
    return vo.result().poses, time.perf_counter() - t


def runner(frames):
    """run_odometry with the defaults of ``spgeo vo``; returns (poses, seconds)."""
    t = time.perf_counter()
    run = run_odometry(frames, VORunConfig(progress=False))
    return run.result().poses, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="../shared/data/7scenes_redkitchen_dev")
    ap.add_argument("--frames", default="0:300")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    frames = list(open_dataset("7scenes", args.data, frames=args.frames, load_depth=False))
    n = len(frames)
    ratios, same = [], True
    for r in range(args.repeats):
        p_lib, s_lib = library_loop(frames)
        p_run, s_run = runner(frames)
        same &= bool(np.allclose(p_lib, p_run, atol=1e-9))
        ratios.append(s_run / s_lib)
        print(f"repeat {r}: library {n / s_lib:.1f} FPS, runner {n / s_run:.1f} FPS, "
              f"library / runner speed {s_run / s_lib:.3f}")
    print(f"{n} frames {frames[0].camera.size[0]}x{frames[0].camera.size[1]}: median "
          f"library / runner speed {np.median(ratios):.3f}; trajectories equal: {same}")


if __name__ == "__main__":
    main()
