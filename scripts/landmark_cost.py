"""Where the sparse landmarks' time goes (issue 30): CPU seconds of their parts and of the
window solve in one ``spgeo eval vo_long_run`` run.

Runs one (sequence, variant) of :mod:`spgeo.evaluation.vo.long_run` in this process (one
BLAS thread, as the benchmark's child) with timers (``time.process_time``: CPU seconds of
the process, all threads, so less sensitive to other jobs than wall time) around the
landmarks' SIFT detection, descriptor matching, :meth:`LandmarkMap.add_keyframe`, factor
insertion, point read-back, the smoother update, and ``run_odometry``; it also counts the
smoother's LM iterations and linear solves (``getIntermediateSteps``).  Prints one JSON
object; the run's outputs go to ``OUT``.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python scripts/landmark_cost.py \\
        7scenes default /tmp/lmcost [--set odometry.landmarks.features.max_features=500]
"""
from __future__ import annotations

import argparse
import collections
import json
import time

from spgeo.configs import parse_assignments
from spgeo.evaluation.vo import long_run
from spgeo.vo import landmarks, smoother

SECONDS: dict = collections.defaultdict(float)
CALLS: collections.Counter = collections.Counter()
SOLVES = {"updates": 0, "iterations": 0, "linear_solves": 0}


def timed(owner, name: str, label: str) -> None:
    """Replace ``owner.name`` with a wrapper adding its CPU seconds to ``SECONDS[label]``."""
    func = getattr(owner, name)

    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            return func(*args, **kwargs)
        finally:
            SECONDS[label] += time.process_time() - t
            CALLS[label] += 1

    setattr(owner, name, wrapper)


def count_solves() -> None:
    """Count the LM iterations and linear solves of every smoother update."""
    update = smoother.gtsam.BatchFixedLagSmoother.update

    def counted(self, *args):
        res = update(self, *args)
        SOLVES["updates"] += 1
        SOLVES["iterations"] += int(res.getIterations())
        SOLVES["linear_solves"] += int(res.getIntermediateSteps())
        return res

    smoother.gtsam.BatchFixedLagSmoother.update = counted


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence")
    ap.add_argument("variant")
    ap.add_argument("out")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="extra overrides: run as the variant 'custom' on top of VARIANT")
    args = ap.parse_args()
    variant = args.variant
    if args.set:
        long_run.VARIANTS["custom"] = {**long_run.VARIANTS[variant], **parse_assignments(args.set)}
        variant = "custom"
    import spgeo.apps.vo_run as vo_run
    timed(landmarks, "opencv_features", "landmarks.sift")
    timed(landmarks, "ratio_matches", "landmarks.matching")
    timed(landmarks.LandmarkMap, "add_keyframe", "landmarks.add_keyframe (all)")
    timed(smoother, "add_landmark_factors", "landmarks.factors")
    timed(smoother, "read_landmarks", "landmarks.read")
    timed(smoother.WindowMapper, "_solve", "smoother update")
    timed(vo_run, "run_odometry", "run_odometry")
    count_solves()
    long_run.main(["--_run", args.sequence, variant, "0", args.out])
    print(json.dumps({"sequence": args.sequence, "variant": args.variant, "set": args.set,
                      "cpu_seconds": {k: round(v, 3) for k, v in SECONDS.items()},
                      "calls": dict(CALLS), **SOLVES}, indent=1))


if __name__ == "__main__":
    main()
