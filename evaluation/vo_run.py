"""Run spgeo's monocular VO on a data set and report Sim(3) ATE (evaluation
wrapper over :mod:`spgeo.vo_runner`; ``spgeo vo`` is the user-facing command).

    python -m spgeo.evaluation.vo_run --dataset 7scenes PATH --frames 0:100 \\
        [--resolution 160x120] [--frontend classical|depth|onnx] [--out DIR]

The ``depth`` front-end reads the sensor depth (oracle normals and initial
scales); ``classical`` and ``onnx`` never read depth.  ATE is Sim(3)-aligned
(evo), per-frame and keyframe-only, over the frames not flagged 'lost'.
"""
from __future__ import annotations

import argparse
from typing import Iterable, List, Optional, Sequence, Tuple

import numpy as np

from spgeo.cli_args import add_dataset_arguments
from spgeo.frame import Frame
from spgeo.odometry import Odometry, OdometryConfig
from spgeo.vo_runner import VORunConfig, parse_resolution, run_dataset, run_odometry

__all__ = ["run_vo", "main"]


def run_vo(frames: Iterable[Frame], resolution: Tuple[int, int] = (160, 120),
           frontend: str = "classical", config: OdometryConfig = OdometryConfig(),
           progress: bool = True) -> Tuple[Odometry, List[Optional[np.ndarray]], float]:
    """VO over a frame sequence resized to ``resolution`` (width, height pixels).

    Returns ``(odometry, ground-truth camera-to-world poses (None per frame
    without), frames per wall-clock second)``; see
    :func:`spgeo.vo_runner.run_odometry` (which this wraps) for the details.
    """
    run = run_odometry(frames, VORunConfig(resolution=tuple(resolution), frontend=frontend,
                                           odometry=config, progress=progress))
    return run.odometry, run.gt_poses, run.fps


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_dataset_arguments(ap)
    ap.add_argument("--resolution", default="160x120", help="WxH (default 160x120)")
    ap.add_argument("--frontend", default="classical", choices=["classical", "depth", "onnx"])
    ap.add_argument("--out", default=None, help="write trajectory.txt, keyframes.txt, report.json")
    args = ap.parse_args(argv)
    try:
        cfg = VORunConfig(resolution=parse_resolution(args.resolution), frontend=args.frontend)
        run = run_dataset(args.dataset[0], args.dataset[1], frames=args.frames, config=cfg)
    except (ValueError, FileNotFoundError) as exc:
        ap.error(str(exc))
    ate = run.ate()
    if args.out:
        run.save(args.out, ate=ate)
    for line in run.summary_lines(ate):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
