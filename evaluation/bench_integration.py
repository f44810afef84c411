"""Benchmark of the batched normal integration (not a test).

200 masks (Voronoi cells of seeded random sites) covering a 240x320 grid, with
the normals of a smooth analytic scene (a sphere in front of a tilted plane).
Reports the median wall time over runs for each solver, and the accuracy
(median relative depth error after one scale per mask).

    python -m spgeo.evaluation.bench_integration [--runs 20] [--masks 200]
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import asdict, dataclass
from typing import Dict, List, Tuple

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.integration import IntegrationConfig, integrate_normals_regions

log = logging.getLogger(__name__)


@dataclass
class BenchResult:
    solver: str
    n_masks: int
    grid: Tuple[int, int]
    median_ms: float
    min_ms: float
    median_rel_error: float
    p95_rel_error: float
    stages_ms: Dict[str, float]


def make_case(n_masks: int = 200, width: int = 320, height: int = 240, seed: int = 0):
    """Camera, exact normals, exact depth and Voronoi regions covering the grid."""
    from scipy.spatial import cKDTree

    cam = PinholeCamera(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    r = cam.rays()
    # tilted plane n.X = d
    n_pl = np.array([0.25, -0.3, -1.0])
    n_pl /= np.linalg.norm(n_pl)
    z_pl = -3.0 / (r @ n_pl)
    # sphere in front
    C, R = np.array([0.2, 0.1, 2.2]), 0.8
    rr = np.sum(r * r, -1)
    rc = r @ C
    disc = rc ** 2 - rr * (C @ C - R ** 2)
    with np.errstate(invalid="ignore"):
        z_sp = (rc - np.sqrt(disc)) / rr
    on_sp = (disc > 0) & (z_sp < z_pl)
    z = np.where(on_sp, z_sp, z_pl)
    n = np.where(on_sp[..., None], (r * z[..., None] - C) / R, n_pl)
    # Voronoi cells, additionally split along the sphere silhouette
    rng = np.random.default_rng(seed)
    sites = rng.uniform([0, 0], [width, height], size=(n_masks, 2))
    u, v = cam.pixel_grid()
    _, lab = cKDTree(sites).query(np.stack([u.ravel(), v.ravel()], -1))
    lab = lab * 2 + on_sp.ravel()
    regions = [np.flatnonzero(lab == k) for k in np.unique(lab)]
    return cam, n, z, regions


def run(n_masks: int = 200, runs: int = 20, solvers=("direct", "cg")) -> List[BenchResult]:
    cam, normals, depth, regions = make_case(n_masks)
    logz = np.log(depth).ravel()
    results = []
    for solver in solvers:
        cfg = IntegrationConfig(solver=solver)
        times, stages = [], []
        res = None
        for _ in range(runs):
            t0 = time.perf_counter()
            res = integrate_normals_regions(normals, regions, cam, None, cfg)
            times.append(time.perf_counter() - t0)
            stages.append({k: v for k, v in res.solver_info.items() if k.startswith("t_")})
        errs = []
        for i, reg in enumerate(regions):
            ld = res.region(i)
            s = np.median(logz[reg] - ld)
            errs.append(np.abs(np.exp(ld + s - logz[reg]) - 1))
        errs = np.concatenate(errs)
        med_stages = {k: 1e3 * float(np.median([s[k] for s in stages])) for k in stages[0]}
        results.append(BenchResult(solver, len(regions), cam.shape, 1e3 * float(np.median(times)),
                                   1e3 * float(np.min(times)), float(np.median(errs)),
                                   float(np.percentile(errs, 95)), med_stages))
    return results


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--masks", type=int, default=200, help="Voronoi sites (default 200)")
    ap.add_argument("--runs", type=int, default=20, help="timed runs per solver (default 20)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = ap.parse_args(argv)
    results = run(args.masks, args.runs)
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
        return
    print(f"{'solver':8s} {'masks':>6s} {'grid':>9s} {'median ms':>10s} {'min ms':>8s} "
          f"{'med rel err':>12s} {'p95 rel err':>12s}  stages (median ms)")
    for r in results:
        st = " ".join(f"{k[2:]}={v:.1f}" for k, v in r.stages_ms.items() if k != "t_total")
        print(f"{r.solver:8s} {r.n_masks:6d} {r.grid[1]}x{r.grid[0]:<5d} {r.median_ms:10.1f} "
              f"{r.min_ms:8.1f} {r.median_rel_error:12.2e} {r.p95_rel_error:12.2e}  {st}")


if __name__ == "__main__":
    main()
