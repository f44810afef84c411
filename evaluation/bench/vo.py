"""Speed of the monocular VO at 160x120 on this machine (one thread).

    python -m spgeo.evaluation.bench.vo [--frames 150] [--seed 0] [--frontend classical]

Four measurements on one rendered synthetic sequence
(:func:`spgeo.evaluation.vo.synthetic.synthetic_sequence`), printed as a table:

1. *Tracking alone*: every frame after the first tracked against keyframe 0
   built from ground-truth depth (frames that see less than half of it are
   skipped), median seconds per frame -> tracking FPS.
2. *Whole pipeline* (:class:`spgeo.vo.Odometry`, default config, the
   chosen front-end): FPS over all frames, mapping seconds per keyframe and
   seconds per stage (tracking, front-end, mapping, two-view initialisation).
3. *Mapping resolution*: the same pipeline mapping at full resolution on the
   highest-gradient half of the pixels (``mapping.level=0``,
   ``mapping.pixel_fraction=0.5``: slower, more accurate) beside the default
   (level 1, all pixels).
4. *Mapping factor granularity*: the same pipeline with one gtsam factor per
   primitive (``mapping.chunk=1``) vs the default chunks, mapping seconds per
   keyframe (same cost, see :class:`spgeo.factors.photometric_group.PhotometricFactorGroup`).

``--settings`` replaces the pipeline rows of 2-4 by its own: one string of
``FIELD=VALUE`` :class:`~spgeo.vo.OdometryConfig` overrides per row, as
``--set-grid`` of :mod:`spgeo.evaluation.vo.frontier` (which adds accuracy on
real data and peak memory).

Timings are wall-clock on whatever else the machine is doing; compare the
numbers of one run with each other (ratios), not across machines.
"""
from __future__ import annotations

import argparse
import os
import time
from typing import Dict, Optional, Sequence

import numpy as np

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.vo.frontier import setting_config
from spgeo.apps.vo_run import VORunConfig, blas_threads
from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, run_synthetic_vo, synthetic_sequence
from spgeo.vo.tracking import Keyframe, TrackerConfig, track_frame
from spgeo.evaluation.tables import cell, markdown_row, markdown_table

__all__ = ["bench_tracking", "build_parser", "run", "main"]

#: the default pipeline rows (``--settings``): defaults, full-resolution mapping
#: on half the pixels, one factor per primitive
_DEFAULT_SETTINGS = ("defaults", "mapping.level=0 mapping.pixel_fraction=0.5", "mapping.chunk=1")


def bench_tracking(frames, config: TrackerConfig = TrackerConfig(),
                   min_overlap: float = 0.5) -> Dict[str, float]:
    """Median / mean seconds per tracked frame against keyframe 0 (primitives
    fitted to its rendered depth, :class:`~spgeo.frontend.FrontEndConfig`
    defaults of the ``depth`` front-end)."""
    from spgeo.frontend import FrontEndConfig, make_frontend

    cam = frames[0].camera
    fe = make_frontend("depth", FrontEndConfig(working_size=cam.size))
    prims = fe.primify(frames[0].image, cam, frames[0].depth)
    kf = Keyframe.build(frames[0].image, prims, frames[0].T_world_cam, config.levels)
    secs, errs = [], []
    T_prev = frames[0].T_world_cam
    for f in frames[1:]:
        t = time.perf_counter()
        tr = track_frame(kf, f.image, T_prev, (0.0, 0.0), config)
        dt = time.perf_counter() - t
        if tr.valid_fraction < min_overlap:
            break
        secs.append(dt)
        errs.append(float(np.linalg.norm(tr.T_world_frame[:3, 3] - f.T_world_cam[:3, 3])))
        T_prev = tr.T_world_frame if tr.ok else f.T_world_cam
    if not secs:
        raise ValueError("bench_tracking: no frame overlaps keyframe 0")
    return {"frames": len(secs), "median_s": float(np.median(secs)),
            "fps": 1.0 / float(np.median(secs)), "median_translation_err_m": float(np.median(errs))}


NAME = "bench_vo"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frontend", default="classical", choices=["classical", "depth"])
    ap.add_argument("--no-chunk-compare", action="store_true")
    ap.add_argument("--settings", nargs="+", default=None, metavar="SETTING",
                    help="pipeline rows: OdometryConfig overrides per row, e.g. 'defaults' "
                         "'mapping.level=0 tracker.levels=4' (default: rows 2-4 above)")
    return ap


def _settings(args: argparse.Namespace):
    """``[(setting, OdometryConfig), ...]`` of the pipeline rows; ValueError naming
    ``--settings``."""
    settings = args.settings or (list(_DEFAULT_SETTINGS)[:2 if args.no_chunk_compare else 3])
    try:
        return [(st, setting_config(st)) for st in settings]
    except (ValueError, TypeError, SyntaxError) as exc:
        raise ValueError(f"--settings: {exc}") from exc


def run(args: argparse.Namespace) -> int:
    """Time tracking alone and each pipeline row; print them (a table)."""
    runs = _settings(args)
    frames = synthetic_sequence(SyntheticVOConfig(args.frames, args.seed))
    print(f"machine: {os.cpu_count()} CPUs, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}; "
          f"{args.frames} synthetic frames (seed {args.seed}) at 160x120")
    with blas_threads(VORunConfig().blas_threads):  # as the VO runner
        tr = bench_tracking(frames)
    print(f"tracking alone: {tr['fps']:.1f} FPS (median {1e3 * tr['median_s']:.1f} ms over "
          f"{tr['frames']} frames vs keyframe 0; median translation error "
          f"{1e3 * tr['median_translation_err_m']:.1f} mm)")
    print("\n".join(markdown_table(
        ["pipeline", "FPS", "track FPS", "mapping s/KF", "KFs", "s track", "s front-end",
         "s mapping", "s init", "per-frame ATE %"], [])))
    for name, cfg in runs:     # a row as each run ends
        r = run_synthetic_vo(frames, args.frontend, cfg)
        st = r["seconds_per_stage"]
        print(markdown_row([f"{args.frontend} {name}", cell(r["fps"], 2),
                            cell(r["tracking_fps"], 1), cell(r["mapping_s_per_kf"], 2),
                            cell(r["keyframes"]), cell(st["track"], 1), cell(st["frontend"], 1),
                            cell(st["mapping"], 1), cell(st["init"], 1),
                            cell(r["per-frame"]["percent"], 2)]), flush=True)
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
