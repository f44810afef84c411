"""Benchmark of the photometric factors (not a test): time to linearise
300 primitives x 4 target views at 240x320, i.e. 1200 PrimitivePhotometricFactors
over all 76800 pixels per target, the size the issue asks about.

    python -m spgeo.evaluation.bench_factors [--runs 5] [--primitives 300] [--targets 4]

Reports the median wall time of ``graph.linearize(values)`` and of
``graph.error(values)``, and the time per factor.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import gtsam

from spgeo.camera import PinholeCamera
from spgeo.factors.photometric import PhotometricConfig, PrimitivePhotometricFactor, ScaledShape
from spgeo.frontend.pipeline import split_regions
from spgeo.geometry import so3_exp


def build(n_prims: int = 300, n_targets: int = 4, width: int = 320, height: int = 240,
          seed: int = 0):
    """A graph of n_prims x n_targets factors over Voronoi primitives covering the image."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    cam = PinholeCamera(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    u, v = cam.pixel_grid()
    sites = rng.uniform([0, 0], [width, height], size=(n_prims, 2))
    _, lab = cKDTree(sites).query(np.stack([u.ravel(), v.ravel()], -1))
    regions = [np.flatnonzero(lab == k) for k in range(n_prims)]
    regions, _ = split_regions(regions, width, height, 1)
    rays = cam.rays().reshape(-1, 3)
    img = (0.5 + 0.3 * np.sin(u / 7.0) * np.cos(v / 5.0)).astype(np.float64)
    values = gtsam.Values()
    values.insert(gtsam.symbol("x", 0), gtsam.Pose3())
    graph = gtsam.NonlinearFactorGraph()
    for t in range(n_targets):
        T = np.eye(4)
        T[:3, :3] = so3_exp(rng.normal(scale=0.02, size=3))
        T[:3, 3] = rng.normal(scale=0.05, size=3)
        values.insert(gtsam.symbol("x", t + 1), gtsam.Pose3(T))
        values.insert(gtsam.symbol("b", t + 1), np.zeros(2))
    for i, reg in enumerate(regions):
        values.insert(gtsam.symbol("s", i), np.array([np.log(2.0)]))
        shape = ScaledShape(rays[reg], np.zeros(reg.size))
        ref = img.reshape(-1)[reg]
        for t in range(n_targets):
            f = PrimitivePhotometricFactor(gtsam.symbol("x", 0), gtsam.symbol("x", t + 1),
                                           gtsam.symbol("s", i), shape, ref, img, cam,
                                           gtsam.symbol("b", t + 1), PhotometricConfig())
            graph.add(f.factor)
    return graph, values, len(regions)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--primitives", type=int, default=300)
    ap.add_argument("--targets", type=int, default=4)
    args = ap.parse_args(argv)
    graph, values, n = build(args.primitives, args.targets)
    lin, err = [], []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        graph.linearize(values)
        lin.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        graph.error(values)
        err.append(time.perf_counter() - t0)
    nf = graph.size()
    print(f"{n} primitives x {args.targets} targets = {nf} factors, 320x240, all pixels")
    print(f"linearize: median {1e3 * np.median(lin):.0f} ms ({1e6 * np.median(lin) / nf:.0f} us "
          f"per factor); error: median {1e3 * np.median(err):.0f} ms")


if __name__ == "__main__":
    main()
