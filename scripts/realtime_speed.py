"""One timed VO run for the real-time table (issue 32): prints one JSON line.

``spgeo vo``'s runner (:func:`spgeo.apps.vo_run.run_odometry`, the defaults, classical
front-end) over frames already decoded in memory; the clock stops after
``Odometry.result()`` (the last window update included).  Works with any spgeo
checkout (older ones have no ``OdometryConfig.mapping``), so that a driver can
alternate releases in one session, each with its own interpreter:

    for i in 1 2 3; do
      /path/to/old/venv/bin/python scripts/realtime_speed.py --label old
      python3 scripts/realtime_speed.py --label live
      python3 scripts/realtime_speed.py --label inline --mapping inline
    done

Fields: fps (frames / seconds), tracking_fps (report.json's), keyframes, ate_m
(Sim(3) ATE against the data set's poses), latency_frames mean / max and frames
tracked against an older map (live mapping), peak RSS of this process and of the
mapping worker (MiB).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import time
from pathlib import Path

import numpy as np


def clip_arguments(ap: argparse.ArgumentParser) -> None:
    """``--data``, ``--dataset``, ``--frames`` (the clip), ``--mapping`` and
    ``--schedule``."""
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent
                                          / "shared/data/7scenes_redkitchen_dev"))
    ap.add_argument("--dataset", default="7scenes")
    ap.add_argument("--frames", default="0:300")
    ap.add_argument("--mapping", default=None,
                    help="OdometryConfig.mapping.mode (default: the default)")
    ap.add_argument("--schedule", default=None,
                    help="OdometryConfig.mapping.schedule (default: the default; checkouts "
                         "before issue 37 have none)")


def clip_and_config(args: argparse.Namespace):
    """``(frames decoded in memory, OdometryConfig)`` of :func:`clip_arguments`'
    values (``mapping.mode`` and ``mapping.schedule`` set only when given: checkouts
    before issue 50 name them ``mapping`` and ``mapping_schedule``, older ones have no
    schedule)."""
    from spgeo.datasets import open_dataset
    from spgeo.vo import OdometryConfig

    frames = list(open_dataset(args.dataset, args.data, frames=args.frames))
    odo = OdometryConfig()
    grouped = hasattr(odo.mapping, "mode")
    if args.mapping is not None:
        odo = dataclasses.replace(odo, mapping=dataclasses.replace(odo.mapping, mode=args.mapping)
                                  if grouped else args.mapping)
    if args.schedule is not None:
        odo = (dataclasses.replace(odo, mapping=dataclasses.replace(odo.mapping,
                                                                    schedule=args.schedule))
               if grouped else dataclasses.replace(odo, mapping_schedule=args.schedule))
    return frames, odo


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    clip_arguments(ap)
    ap.add_argument("--label", default="run")
    args = ap.parse_args()

    from spgeo.apps.vo_run import VORunConfig, run_odometry
    from spgeo.evaluation.trajectory import ate_sim3

    frames, odo = clip_and_config(args)
    t = time.perf_counter()
    run = run_odometry(frames, VORunConfig(odometry=odo, progress=False))
    res = run.odometry.result()
    sec = time.perf_counter() - t
    rep = run.odometry.report()
    close = getattr(run.odometry, "close", None)
    if close is not None:
        close()
    gt = (np.array([f.timestamp for f in frames]), np.array([f.T_world_cam for f in frames]))
    live = rep.get("mapping_worker") or {}
    print(json.dumps({
        "label": args.label, "mapping": rep.get("mapping_mode", "inline"),
        "fps": len(frames) / sec, "seconds": sec, "tracking_fps": rep["tracking_fps"],
        "keyframes": rep["n_keyframes"], "ate_m": float(ate_sim3(res, gt).rmse),
        "latency_frames_mean": live.get("latency_frames_mean"),
        "latency_frames_max": live.get("latency_frames_max"),
        "older_map_frames": live.get("frames_tracked_against_older_map"),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "worker_peak_rss_mib": live.get("worker_peak_rss_mib")}), flush=True)


if __name__ == "__main__":
    main()
