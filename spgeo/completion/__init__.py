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
* :mod:`~spgeo.completion.choose`: the default ``choose="heldout"``: per
  region, the blend of the depth sources with the lowest error on held-out
  sparse points.
* :mod:`~spgeo.completion.network`: a metric-depth network's depth aligned to
  the sparse points (a candidate of the choice).
* :mod:`~spgeo.completion.baselines`: linear interpolation, IP-Basic and the
  colorization fill (candidates of the choice, and the baselines of the
  evaluation).
* :mod:`~spgeo.completion.sparse_points`: sparse inputs sampled from a dense
  reference depth (FAST keypoints, uniform pixels, KLT tracks), as the demo
  and the benchmarks make them.
"""
from .baselines import (ColorizationConfig, IPBasicConfig, colorization_completion,
                        ip_basic_completion, linear_interpolation_completion)
from .choose import ChooseConfig, HeldoutChoice, choose_by_heldout, fold_ids
from .complete import CompletionResult, complete_depth, working_size_for
from .config import CompletionConfig
from .fill import (CONFIDENCE_LINEAR, CONFIDENCE_NEAREST, CONFIDENCE_PRIMITIVE, linear_fill,
                   nearest_fill)
from .network import align_network_depth, network_depth
from .scales import grouped_median, solve_log_scales_joint, sparse_point_assignments
from ..validation import check_sparse_depth

__all__ = [
    "CompletionConfig", "CompletionResult", "complete_depth", "check_sparse_depth",
    "nearest_fill", "linear_fill", "sparse_point_assignments", "grouped_median",
    "solve_log_scales_joint", "working_size_for", "CONFIDENCE_PRIMITIVE", "CONFIDENCE_LINEAR",
    "CONFIDENCE_NEAREST", "ChooseConfig", "HeldoutChoice", "choose_by_heldout", "fold_ids",
    "align_network_depth", "network_depth", "linear_interpolation_completion",
    "ip_basic_completion", "colorization_completion", "IPBasicConfig", "ColorizationConfig",
]
