"""Boundary-quality benchmark of the classical segmenters on synthetic scenes.

Renders views of :mod:`spgeo.synthetic` scenes (exact per-surface ids), runs
:class:`spgeo.frontend.classical.ClassicalSegmenter` variants and reports

* ``BR``   boundary recall: fraction of ground-truth surface-boundary pixels
  within ``tolerance`` px (Euclidean) of a segment boundary pixel;
* ``UE``   under-segmentation (leakage) error: fraction of pixels of segments
  that lie outside the segment's majority surface, ``1 - ASA`` — the error
  that matters for SuperPrimitives (a segment crossing a depth discontinuity
  breaks the one-scale-per-primitive assumption);
* ``UEnp`` Neubert-Protzel under-segmentation error
  ``(1/N) sum_G sum_{S cap G != 0} min(|S cap G|, |S - G|)``;
* ``UEobj`` the leakage error w.r.t. *objects* (faces of one box merged):
  leaks across object / depth-discontinuity boundaries only;
* ``ASA``  achievable segmentation accuracy;
* ``cov``  fraction of pixels covered by a returned region;
* ``nseg`` mean number of regions, ``ms`` mean time per ``segment`` call.

Run ``python -m spgeo.evaluation.frontend.segmenters`` (or the file directly);
``--help`` lists the options.  The library functions
(:func:`segmentation_metrics`, :func:`render_views`, :func:`run_benchmark`,
:func:`format_table`) can be used from notebooks.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

import numpy as np
from scipy import ndimage

from spgeo.frontend.classical import ClassicalSegmenter, ClassicalSegmenterConfig

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_table

__all__ = ["BenchView", "boundary_mask", "boundary_recall", "leakage_error",
           "neubert_protzel_error", "segmentation_metrics", "render_views", "default_variants",
           "run_benchmark", "format_table", "build_parser", "run", "main"]

logger = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- metrics
def boundary_mask(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels with a 4-neighbour of a different label (both sides)."""
    labels = np.asarray(labels)
    b = np.zeros(labels.shape, dtype=bool)
    dh = labels[:, 1:] != labels[:, :-1]
    dv = labels[1:, :] != labels[:-1, :]
    b[:, 1:] |= dh
    b[:, :-1] |= dh
    b[1:, :] |= dv
    b[:-1, :] |= dv
    return b


def boundary_recall(seg: np.ndarray, gt: np.ndarray, tolerance: float = 2.0,
                    gt_valid: Optional[np.ndarray] = None) -> float:
    """Fraction of ground-truth boundary pixels within ``tolerance`` px of a
    segment boundary pixel (pixels next to invalid ground truth are ignored)."""
    gt_b = boundary_mask(gt)
    if gt_valid is not None:
        gt_b &= ndimage.binary_erosion(gt_valid, border_value=1)
    n = int(gt_b.sum())
    if n == 0:
        return 1.0
    seg_b = boundary_mask(seg)
    if not seg_b.any():
        return 0.0
    dist = ndimage.distance_transform_edt(~seg_b)
    return float(np.count_nonzero(dist[gt_b] <= tolerance)) / n


def _contingency(seg: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> np.ndarray:
    s = seg[mask].astype(np.int64)
    g = gt[mask].astype(np.int64)
    _, s = np.unique(s, return_inverse=True)
    _, g = np.unique(g, return_inverse=True)
    ng = int(g.max()) + 1 if g.size else 1
    ns = int(s.max()) + 1 if s.size else 1
    return np.bincount(s * ng + g, minlength=ns * ng).reshape(ns, ng)


def leakage_error(seg: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """``1 - ASA``: fraction of (masked) pixels outside their segment's majority label."""
    c = _contingency(seg, gt, mask)
    total = c.sum()
    return float(total - c.max(axis=1).sum()) / max(total, 1)


def neubert_protzel_error(seg: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """Neubert & Protzel (2012) under-segmentation error."""
    c = _contingency(seg, gt, mask)
    size = c.sum(axis=1, keepdims=True)
    return float(np.minimum(c, size - c).sum()) / max(c.sum(), 1)


def segmentation_metrics(labels: np.ndarray, keep: np.ndarray, surface_ids: np.ndarray,
                         object_ids: Optional[np.ndarray] = None,
                         tolerance: float = 2.0) -> Dict[str, float]:
    """Metrics of one label image (``keep`` marks returned regions) against surface ids
    (``-1`` = no ground truth).  ``object_ids`` adds the object-level leakage ``UEobj``."""
    gt_valid = surface_ids >= 0
    covered = keep[labels]
    mask = gt_valid & covered
    out = {
        "BR": boundary_recall(labels, surface_ids, tolerance, gt_valid),
        "UE": leakage_error(labels, surface_ids, mask),
        "UEnp": neubert_protzel_error(labels, surface_ids, mask),
        "cov": float(np.count_nonzero(mask)) / max(int(np.count_nonzero(gt_valid)), 1),
        "nseg": float(np.count_nonzero(keep)),
    }
    out["ASA"] = 1.0 - out["UE"]
    if object_ids is not None:
        out["UEobj"] = leakage_error(labels, object_ids, mask)
    return out


# ----------------------------------------------------------------------------- data
@dataclass
class BenchView:
    """One rendered view: image and ground truth."""

    rgb: np.ndarray
    surface_ids: np.ndarray
    object_ids: np.ndarray
    camera: object
    name: str


def render_views(seeds: Sequence[int], n_views: int, width: int, height: int,
                 supersample: int = 2, frame_step: int = 30) -> List[BenchView]:
    """``n_views`` views per scene seed: frames ``0, frame_step, ...`` of
    ``make_trajectory`` rendered at ``width`` x ``height`` (anti-aliased rgb)."""
    from spgeo.synthetic import SyntheticScene, default_camera, make_trajectory

    camera = default_camera(width, height)
    views = []
    for seed in seeds:
        scene = SyntheticScene.generate(int(seed))
        poses = make_trajectory(n_views * frame_step, int(seed))[::frame_step]
        for i, T in enumerate(poses):
            v = scene.render(camera, T, supersample=supersample)
            obj = np.where(v.surface_ids >= 0, scene.surface_object(v.surface_ids), -1)
            views.append(BenchView(v.rgb, v.surface_ids, np.asarray(obj), camera,
                                   f"seed{seed}/view{i}"))
    return views


# ----------------------------------------------------------------------------- benchmark
def default_variants(num_segments: int = 200) -> Dict[str, ClassicalSegmenterConfig]:
    """Method variants compared at comparable segment counts (``num_segments``
    drives the superpixel methods; the graph method's count follows ``k``)."""
    base = ClassicalSegmenterConfig(num_segments=num_segments, working_width=None)
    rep = dataclasses.replace
    graph = rep(base, method="graph")
    slic = rep(base, method="slic", color_space="lab")
    return {
        "graph rgb k150 (default)": graph,
        "graph rgb k100": rep(graph, graph_k=100.0),
        "graph rgb k300": rep(graph, graph_k=300.0),
        "graph lab k100": rep(graph, color_space="lab", graph_k=100.0),
        "graph s0.8": rep(graph, graph_sigma=0.8),
        "graph m80": rep(graph, graph_min_size=80),
        "graph merge": rep(graph, small_components="merge"),
        "slic lab": slic,
        "slic x1.5 segs": rep(slic, num_segments=int(1.5 * num_segments)),
        "slic c5": rep(slic, compactness=5.0),
        "slic c20": rep(slic, compactness=20.0),
        "slic it5": rep(slic, num_iterations=5),
        "slic rgb": rep(slic, color_space="rgb"),
        "slic blur1": rep(slic, blur_sigma=1.0),
        "slic merge": rep(slic, small_components="merge"),
        "slico": rep(slic, method="slico"),
        "mslic": rep(slic, method="mslic"),
        "seeds": rep(slic, method="seeds"),
        "lsc": rep(slic, method="lsc"),
    }


def run_benchmark(variants: Dict[str, ClassicalSegmenterConfig], views: Sequence[BenchView],
                  tolerance: float = 2.0, repeats: int = 1) -> List[Dict[str, object]]:
    """Mean metrics of every variant over ``views`` (time: best of ``repeats``)."""
    rows = []
    for name, cfg in variants.items():
        seg = ClassicalSegmenter(cfg)
        acc: Dict[str, List[float]] = {}
        if views:  # warm-up (first-call allocations)
            seg.segment(views[0].rgb, views[0].camera)
        for view in views:
            times = []
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                result = seg.segment(view.rgb, view.camera)
                times.append(time.perf_counter() - t0)
            labels, keep, _, _ = seg.label_image(view.rgb, view.camera)
            m = segmentation_metrics(labels, keep, view.surface_ids, view.object_ids, tolerance)
            m["nseg"] = float(len(result))
            m["ms"] = 1e3 * min(times)
            for k, v in m.items():
                acc.setdefault(k, []).append(v)
        row: Dict[str, object] = {"variant": name}
        row.update({k: float(np.mean(v)) for k, v in acc.items()})
        rows.append(row)
        logger.info("%s: %s", name, row)
    return rows


_COLUMNS = [("BR", 3), ("UE", 4), ("UEnp", 4), ("UEobj", 4), ("ASA", 4), ("cov", 3),
            ("nseg", 0), ("ms", 1)]


def format_table(rows: Sequence[Dict[str, object]], title: str = "") -> str:
    """Markdown table of :func:`run_benchmark` rows (``-`` for a missing value)."""
    body = markdown_table(["variant"] + [c for c, _ in _COLUMNS],
                          [[r["variant"]] + [cell(r.get(c), d) for c, d in _COLUMNS]
                           for r in rows], "l" + "r" * len(_COLUMNS))
    return "\n".join(([f"**{title}**", ""] if title else []) + body)


NAME = "bench_segmenters"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = protocol_parser(None, __doc__.split("\n\n")[0], dataset=False)
    parser.formatter_class = argparse.ArgumentDefaultsHelpFormatter
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="scene seeds")
    parser.add_argument("--views", type=int, default=10, help="views per seed")
    parser.add_argument("--sizes", type=str, nargs="+", default=["320x240", "160x120"],
                        help="image sizes WxH")
    parser.add_argument("--num-segments", type=int, nargs="+", default=[200],
                        help="target segment counts")
    parser.add_argument("--variants", type=str, nargs="*", default=None,
                        help="subset of variant names (default: all)")
    parser.add_argument("--tolerance", type=float, default=2.0, help="boundary tolerance, px")
    parser.add_argument("--repeats", type=int, default=2, help="timing repeats (best of)")
    parser.add_argument("--supersample", type=int, default=2, help="render anti-aliasing")
    return parser


def _chosen_variants(num_segments: int,
                     names: Optional[Sequence[str]]) -> Dict[str, ClassicalSegmenterConfig]:
    """:func:`default_variants` (only ``names`` when given); ``ValueError`` for an
    unknown name."""
    variants = default_variants(num_segments)
    if names:
        unknown = set(names) - set(variants)
        if unknown:
            raise ValueError(f"unknown variants {sorted(unknown)}; known: {sorted(variants)}")
        variants = {k: v for k, v in variants.items() if k in names}
    return variants


def run(args: argparse.Namespace) -> int:
    """One table per (size, segment count), written as soon as it is measured; an
    unknown ``--variants`` name exits with the usage message (code 2)."""
    out = sys.stdout
    for size in args.sizes:
        w, h = (int(s) for s in size.lower().split("x"))
        views = render_views(args.seeds, args.views, w, h, args.supersample)
        for n in args.num_segments:
            try:
                variants = _chosen_variants(n, args.variants)
            except ValueError as exc:
                build_parser().error(str(exc))
            rows = run_benchmark(variants, views, args.tolerance, args.repeats)
            out.write(format_table(rows, f"{w}x{h}, num_segments={n}, {len(views)} views "
                                         f"(seeds {args.seeds})") + "\n\n")
            out.flush()
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The segmenter benchmark (module docstring): print one table per size and
    segment count."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
