"""Does GTSAM's Python wrapper release the interpreter lock while it solves? (issue 32)

A thread spins a counter while the main thread runs Levenberg-Marquardt on a pose graph made
only of GTSAM's C++ factors (no Python callback); the counter's progress during the solve,
over its progress alone in the same time, is ~1 where the solve releases the lock (a mapper
thread could then run beside the tracker) and ~0 where it holds it.

Usage: python scripts/gil_during_solve.py [--poses N]
"""
from __future__ import annotations

import argparse
import threading
import time


def _problem(n: int):
    import gtsam
    from gtsam.symbol_shorthand import X

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    step = gtsam.Pose3(gtsam.Rot3.Rz(0.01), gtsam.Point3(1, 0, 0))
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise))
    for i in range(n):
        values.insert(X(i), gtsam.Pose3(gtsam.Rot3.Rz(0.01 * i + 0.3), gtsam.Point3(i + 0.5, 0.2, 0)))
        if i:
            graph.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), step, noise))
    return graph, values


def _spin_while(work) -> int:
    """Counter increments of a spinning thread while ``work()`` runs."""
    count, stop = [0], [False]

    def spin():
        while not stop[0]:
            count[0] += 1

    th = threading.Thread(target=spin)
    th.start()
    work()
    stop[0] = True
    th.join()
    return count[0]


def main() -> None:
    import gtsam

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=3000)
    graph, values = _problem(ap.parse_args().poses)

    def solve():
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(5)
        gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()

    t = time.perf_counter()
    solve()
    seconds = time.perf_counter() - t
    free = _spin_while(lambda: time.sleep(seconds))
    during = _spin_while(solve)
    print(f"solve {seconds:.3f} s; a Python thread's progress during the solve: "
          f"{during / max(free, 1):.2f} of its progress alone (1: lock released, 0: held)")


if __name__ == "__main__":
    main()
