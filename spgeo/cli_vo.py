"""``spgeo vo``: argument wiring for :func:`spgeo.vo_runner.run_dataset`.

    spgeo vo --dataset {tum,7scenes,icl,folder} PATH [--frames A:B[:STEP]]
             [--resolution 160x120] [--frontend classical|depth|onnx] --out DIR

Writes ``DIR/trajectory.txt`` (every processed frame, TUM format, camera-to-world;
timestamps are frame numbers for data sets without timestamps),
``DIR/keyframes.txt``, ``DIR/trajectory.status.txt``, ``DIR/report.json``
(with the per-frame and keyframe-only Sim(3) ATE under ``"ate"`` when the data
set has ground truth) and keyframe point clouds in ``DIR/clouds/``.
"""
from __future__ import annotations

import argparse

from .cli_args import DATASET_KINDS

__all__ = ["add_vo_cli"]


_DESCRIPTION = """Monocular visual odometry (SuperPrimitives) on a data set.

Writes OUT/trajectory.txt (every processed frame, TUM 'timestamp tx ty tz qx qy
qz qw', camera-to-world; timestamps are frame numbers for data sets without
timestamps such as 7-Scenes), OUT/keyframes.txt, OUT/trajectory.status.txt,
OUT/report.json (with the per-frame and keyframe-only Sim(3) ATE under "ate"
when the data set has ground truth) and keyframe point clouds in OUT/clouds/.
The classical and onnx front-ends never read depth; 'depth' uses the sensor
depth (RGB-D / oracle)."""


def _run(args: argparse.Namespace) -> int:
    from .vo_runner import VORunConfig, parse_resolution, run_dataset

    kind, path = args.dataset
    if kind.lower() not in DATASET_KINDS:
        raise ValueError(f"--dataset KIND must be one of {', '.join(DATASET_KINDS)}, "
                         f"got {kind!r}")
    cfg = VORunConfig(resolution=parse_resolution(args.resolution), frontend=args.frontend,
                      progress=not args.no_progress, sam_family=args.sam_family,
                      normal_model=args.normal_model)
    run = run_dataset(kind.lower(), path, frames=args.frames, config=cfg)
    ate = run.ate()
    paths = run.save(args.out, ate=ate)
    for line in run.summary_lines(ate):
        print(line)
    n_clouds = len(paths.get("clouds") or [])
    print(f"wrote {paths['trajectory']}, keyframes.txt, report.json"
          f"{f', {n_clouds} keyframe clouds' if n_clouds else ''} in {args.out}")
    return 0


def add_vo_cli(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "vo", help="monocular visual odometry on a data set -> trajectory, keyframes, ATE",
        description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", nargs=2, metavar=("KIND", "PATH"), required=True,
                   help=f"data-set kind ({', '.join(DATASET_KINDS)}) and sequence folder")
    p.add_argument("--frames", default=None, metavar="A:B[:STEP]",
                   help="frame numbers A <= n < B, every STEP-th (default: all)")
    p.add_argument("--resolution", default="160x120", metavar="WxH",
                   help="processing resolution (default 160x120)")
    p.add_argument("--frontend", default="classical", choices=["classical", "onnx", "depth"],
                   help="classical (default, monocular), onnx (needs `spgeo models fetch`) or "
                        "depth (reads the sensor depth: RGB-D / oracle)")
    p.add_argument("--sam-family", default=None,
                   help="onnx: SAM model family in the cache (default efficientsam-vitt)")
    p.add_argument("--normal-model", default=None,
                   help="onnx: normal model name or .onnx path (default metric3d-vit-small-fp16)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="more logging (-v, -vv; also accepted before 'vo')")
    p.set_defaults(func=_run)
    return p
