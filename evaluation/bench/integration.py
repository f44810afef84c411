"""Benchmark of the batched normal integration (not a test).

200 masks (Voronoi cells of seeded random sites) covering a 240x320 grid, with
the normals of a smooth analytic scene (a sphere in front of a tilted plane).
Reports, per solver, the median wall time over runs (solvers interleaved run by
run, so their ratios share the machine's load), the median time of each stage
(``build``: edges and coefficients, ``assemble``: normal equations, components
and pins, ``solve``: factorisation and solves, of which ``factor``), the
factor's memory as the solver reports it, the peak of Python-visible
allocations of one call (tracemalloc), and the accuracy (median relative depth
error after one scale per mask).

    python -m spgeo.evaluation.bench.integration [--runs 20] [--masks 200] [--grid 320x240]
"""
from __future__ import annotations

import argparse
import json
import logging
import time
import tracemalloc
from dataclasses import asdict, dataclass
from typing import Dict, List, Sequence, Tuple

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.integration import IntegrationConfig, integrate_normals_regions

log = logging.getLogger(__name__)

SOLVERS = ("cholesky", "direct", "cg")


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
    factor_mb: float
    peak_traced_mb: float
    max_abs_diff_to_first: float


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


def benchmark(n_masks: int = 200, runs: int = 20, solvers: Sequence[str] = SOLVERS,
              width: int = 320, height: int = 240) -> List[BenchResult]:
    """One :class:`BenchResult` per solver: ``runs`` timed calls each, the solvers
    interleaved, on :func:`make_case` (``n_masks`` masks over ``width`` x ``height``)."""
    cam, normals, depth, regions = make_case(n_masks, width, height)
    logz = np.log(depth).ravel()
    cfgs = {s: IntegrationConfig(solver=s) for s in solvers}
    times: Dict[str, List[float]] = {s: [] for s in solvers}
    stages: Dict[str, List[dict]] = {s: [] for s in solvers}
    last = {}
    for _ in range(runs):
        for s in solvers:
            t0 = time.perf_counter()
            res = integrate_normals_regions(normals, regions, cam, None, cfgs[s])
            times[s].append(time.perf_counter() - t0)
            stages[s].append({k: v for k, v in res.solver_info.items() if k.startswith("t_")})
            last[s] = res
    results = []
    for s in solvers:
        res = last[s]
        tracemalloc.start()
        integrate_normals_regions(normals, regions, cam, None, cfgs[s])
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        errs = []
        for i, reg in enumerate(regions):
            ld = res.region(i)
            sc = np.median(logz[reg] - ld)
            errs.append(np.abs(np.exp(ld + sc - logz[reg]) - 1))
        errs = np.concatenate(errs)
        med_stages = {k: 1e3 * float(np.median([d.get(k, 0.0) for d in stages[s]]))
                      for k in stages[s][0]}
        results.append(BenchResult(
            s, len(regions), cam.shape, 1e3 * float(np.median(times[s])),
            1e3 * float(np.min(times[s])), float(np.median(errs)), float(np.percentile(errs, 95)),
            med_stages, res.solver_info.get("factor_bytes", 0) / 2 ** 20, peak / 2 ** 20,
            float(np.abs(res.log_depth - last[solvers[0]].log_depth).max())))
    return results


def results_table(results: Sequence[BenchResult]) -> str:
    """The results as aligned text columns (ratio: median time over the first solver's)."""
    base = results[0].median_ms
    lines = [f"{'solver':8s} {'masks':>6s} {'grid':>9s} {'median ms':>10s} {'ratio':>6s} "
             f"{'min ms':>8s} {'med rel err':>12s} {'p95 rel err':>12s} {'diff':>8s} "
             f"{'factor MB':>9s} {'peak MB':>8s}  stages (median ms)"]
    for r in results:
        st = " ".join(f"{k[2:]}={v:.1f}" for k, v in r.stages_ms.items() if k != "t_total")
        lines.append(f"{r.solver:8s} {r.n_masks:6d} {r.grid[1]}x{r.grid[0]:<5d} {r.median_ms:10.1f} "
                     f"{r.median_ms / base:6.2f} {r.min_ms:8.1f} {r.median_rel_error:12.2e} "
                     f"{r.p95_rel_error:12.2e} {r.max_abs_diff_to_first:8.1e} {r.factor_mb:9.1f} "
                     f"{r.peak_traced_mb:8.1f}  {st}")
    return "\n".join(lines)


NAME = "bench_integration"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--masks", type=int, default=200, help="Voronoi sites (default 200)")
    ap.add_argument("--runs", type=int, default=20, help="timed runs per solver (default 20)")
    ap.add_argument("--grid", default="320x240", help="WIDTHxHEIGHT (default 320x240)")
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=SOLVERS,
                    help="solvers to compare, interleaved (default: all)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return ap


def run(args: argparse.Namespace) -> int:
    """Benchmark (:func:`benchmark`) and print the table or JSON."""
    width, height = (int(x) for x in args.grid.lower().split("x"))
    results = benchmark(args.masks, args.runs, args.solvers, width, height)
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
        return 0
    print(results_table(results))
    return 0


def main(argv=None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
