"""Benchmark of the photometric factors (not a test): time to linearise
300 primitives x 4 target views at 240x320, i.e. 1200 PrimitivePhotometricFactors
over all 76800 pixels per target, the size the issue asks about.

    python -m spgeo.evaluation.bench.factors [--runs 5] [--primitives 300] [--targets 4]
        [--chunk C] [--backends numpy numba] [--tracking 160x120 320x240]

Reports, per photometric backend (``PhotometricConfig.backend``, the runs
interleaved), the median wall time of ``graph.linearize(values)`` and of
``graph.error(values)`` and the time per factor; ``--chunk C`` builds the
graph from :class:`PhotometricFactorGroup` with ``chunk=C`` instead.
``--tracking`` also times :func:`spgeo.vo.tracking.track_frame` of one
synthetic frame (depth front-end keyframe) at each resolution per backend.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import gtsam

from spgeo.camera import PinholeCamera
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.factors.photometric import PhotometricConfig, PrimitivePhotometricFactor, ScaledShape
from spgeo.factors.photometric_group import PhotometricFactorGroup
from spgeo.frontend.pipeline import split_regions
from spgeo.geometry import so3_exp
from spgeo.graph.keys import brightness_key, pose_key, scale_key


def build(n_prims: int = 300, n_targets: int = 4, width: int = 320, height: int = 240,
          seed: int = 0, config: PhotometricConfig = PhotometricConfig(), chunk: int = 0):
    """``(graph, values, number of primitives, groups)``: a graph of n_prims x
    n_targets factors over Voronoi primitives covering the image (``chunk >
    0``: one :class:`PhotometricFactorGroup` per target with that chunk size,
    listed in ``groups``)."""
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
    values.insert(pose_key(0), gtsam.Pose3())
    graph = gtsam.NonlinearFactorGraph()
    for t in range(n_targets):
        T = np.eye(4)
        T[:3, :3] = so3_exp(rng.normal(scale=0.02, size=3))
        T[:3, 3] = rng.normal(scale=0.05, size=3)
        values.insert(pose_key(t + 1), gtsam.Pose3(T))
        values.insert(brightness_key(t + 1), np.zeros(2))
    for i, reg in enumerate(regions):
        values.insert(scale_key(i), np.array([np.log(2.0)]))
        if chunk > 0:
            continue
        shape = ScaledShape(rays[reg], np.zeros(reg.size))
        ref = img.reshape(-1)[reg]
        for t in range(n_targets):
            f = PrimitivePhotometricFactor(pose_key(0), pose_key(t + 1),
                                           scale_key(i), shape, ref, img, cam,
                                           brightness_key(t + 1), config)
            graph.add(f.factor)
    groups = []
    if chunk > 0:
        pix = np.concatenate(regions)
        offsets = np.concatenate([[0], np.cumsum([r.size for r in regions])])
        keys = [scale_key(i) for i in range(len(regions))]
        for t in range(n_targets):
            g = PhotometricFactorGroup(pose_key(0), pose_key(t + 1), keys,
                                       ScaledShape(rays[pix], np.zeros(pix.size)), offsets,
                                       img.reshape(-1)[pix], img, cam, brightness_key(t + 1),
                                       config, chunk=chunk)
            for f in g.factors:
                graph.add(f)
            groups.append(g)
    return graph, values, len(regions), groups


def _tracking_case(width: int, height: int, config: PhotometricConfig):
    """A synthetic keyframe and a frame moved by 2 deg / 2.7 cm at ``width x height``."""
    from spgeo import synthetic
    from spgeo.frontend import make_frontend
    from spgeo.vo.tracking import Keyframe, TrackerConfig

    cam = synthetic.default_camera(width, height)
    scene = synthetic.SyntheticScene.generate(2)
    T_kf, _ = synthetic.make_view_set(scene, cam, 1, 7.5, 0.05, 2)
    kv = scene.render(cam, T_kf, supersample=2)
    kf = Keyframe.build(kv.rgb, make_frontend("depth").primify(kv.rgb, cam, kv.depth), T_kf)
    D = np.eye(4)
    D[:3, :3] = so3_exp(np.radians(2.0) * np.array([0.3, 1.0, 0.2]) / np.sqrt(1.13))
    D[:3, 3] = [-0.02, 0.01, 0.015]
    frame = scene.render(cam, T_kf @ D, supersample=2).rgb
    return kf, frame, TrackerConfig(photometric=config)


def _interleaved(fns: dict, runs: int) -> dict:
    """Median seconds of each callable, the runs interleaved (one warm-up each)."""
    times = {name: [] for name in fns}
    for fn in fns.values():
        fn()
    for _ in range(runs):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) for name, t in times.items()}


NAME = "bench_factors"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--primitives", type=int, default=300)
    ap.add_argument("--targets", type=int, default=4)
    ap.add_argument("--chunk", type=int, default=0,
                    help="PhotometricFactorGroup chunk size (0: per-primitive factors)")
    ap.add_argument("--backends", nargs="+", default=["numpy", "numba"],
                    choices=["numpy", "numba", "auto"])
    ap.add_argument("--tracking", nargs="*", default=[], metavar="WxH",
                    help="also time track_frame at these resolutions")
    return ap


def _graph_fns(args: argparse.Namespace):
    """``(callables "linearize BACKEND" / "error BACKEND", graph, primitives)``: one
    graph per backend (:func:`build`)."""
    fns = {}
    for bk in args.backends:
        graph, values, n, groups = build(args.primitives, args.targets,
                                         config=PhotometricConfig(backend=bk), chunk=args.chunk)

        def run(method, g=graph, v=values, groups=groups):
            for grp in groups:      # a group serves repeated calls at equal values from cache
                grp.forget_cache()
            return getattr(g, method)(v)
        fns[f"linearize {bk}"] = lambda run=run: run("linearize")
        fns[f"error {bk}"] = lambda run=run: run("error")
    return fns, graph, n


def _time_tracking(args: argparse.Namespace) -> None:
    """Print the median ``track_frame`` time per backend at each ``--tracking`` size."""
    from spgeo.vo.tracking import track_frame
    for res in args.tracking:
        w, h = (int(x) for x in res.lower().split("x"))
        fns = {}
        for bk in args.backends:
            kf, frame, cfg = _tracking_case(w, h, PhotometricConfig(backend=bk))
            fns[f"track {bk}"] = (lambda kf=kf, fr=frame, c=cfg:
                                  track_frame(kf, fr, kf.T_world_kf, config=c))
        med = _interleaved(fns, args.runs)
        for bk in args.backends:
            t = med[f"track {bk}"]
            print(f"{bk:6s} track_frame {w}x{h}: median {1e3 * t:.1f} ms ({1 / t:.0f} FPS)")
        _ratio(med, args.backends, "track")


def run(args: argparse.Namespace) -> int:
    """Time and print linearize / error per backend, then ``--tracking``."""
    fns, graph, n = _graph_fns(args)
    nf = graph.size()
    kind = f"groups chunk={args.chunk}" if args.chunk > 0 else "per-primitive factors"
    print(f"{n} primitives x {args.targets} targets: {nf} gtsam factors ({kind}), "
          f"320x240, all pixels")
    med = _interleaved(fns, args.runs)
    for bk in args.backends:
        lin = med[f"linearize {bk}"]
        print(f"{bk:6s} linearize: median {1e3 * lin:.1f} ms ({1e6 * lin / nf:.0f} us per "
              f"factor); error: median {1e3 * med[f'error {bk}']:.1f} ms")
    _ratio(med, args.backends, "linearize")
    _time_tracking(args)
    return 0


def main(argv=None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


def _ratio(med: dict, backends, what: str) -> None:
    if "numpy" in backends and "numba" in backends:
        print(f"{what}: numpy / numba = {med[f'{what} numpy'] / med[f'{what} numba']:.2f}x")


if __name__ == "__main__":
    raise SystemExit(main())
