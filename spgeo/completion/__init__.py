"""Zero-shot depth completion with SuperPrimitives (docs/design.md §5).

The pipeline and its steps are described in :mod:`spgeo.completion.complete`.
Modules, one job each:

* :mod:`~spgeo.completion.config`: :class:`CompletionConfig` (the options).
* :mod:`~spgeo.completion.complete`: :func:`complete_depth`, the pipeline
  (front-end, scales, shapes, render, fill, fallback) and :class:`CompletionResult`.
* :mod:`~spgeo.completion.scales`: sparse points per primitive, median and
  joint (GTSAM) log-scales, flat-primitive test.
* :mod:`~spgeo.completion.graph`: ``method="graph"``: scales, and planes,
  solved jointly with coupling across weak image edges (the default path).
* :mod:`~spgeo.completion.planes`: ``shape_model="plane"``: per-primitive
  robust plane fits and depth lent across weak edges.
* :mod:`~spgeo.completion.fill`: hole filling, resampling and the residual
  correction.
"""
from .complete import CompletionResult, complete_depth, working_size_for
from .config import CompletionConfig
from .fill import (CONFIDENCE_LINEAR, CONFIDENCE_NEAREST, CONFIDENCE_PRIMITIVE, linear_fill,
                   nearest_fill)
from .scales import grouped_median, solve_log_scales_joint, sparse_point_assignments
from ..validation import check_sparse_depth

__all__ = [
    "CompletionConfig", "CompletionResult", "complete_depth", "check_sparse_depth",
    "nearest_fill", "linear_fill", "sparse_point_assignments", "grouped_median",
    "solve_log_scales_joint", "working_size_for", "CONFIDENCE_PRIMITIVE", "CONFIDENCE_LINEAR",
    "CONFIDENCE_NEAREST",
]
