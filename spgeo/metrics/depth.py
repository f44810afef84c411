"""Depth accuracy against ground truth (metres in, the units stated per key out): a depth
map's errors, the shape accuracy of primitives, and the VOID completion metrics.

The demo (:mod:`spgeo.apps.demo`) and the evaluation protocols (:mod:`spgeo.evaluation.metrics`,
:mod:`spgeo.evaluation.completion.void`) report them.
"""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

__all__ = ["depth_metrics", "primitive_fit_errors", "void_metrics", "VOID_MIN_DEPTH",
           "VOID_MAX_DEPTH", "VOID_METRIC_KEYS"]

#: Evaluation range of the VOID protocol's ground truth (metres, exclusive).
VOID_MIN_DEPTH, VOID_MAX_DEPTH = 0.2, 5.0
#: The VOID metrics of :func:`void_metrics` (besides ``n_pixels`` and ``coverage``).
VOID_METRIC_KEYS = ("mae_mm", "rmse_mm", "imae_per_km", "irmse_per_km")


def depth_metrics(pred: np.ndarray, gt: np.ndarray, mask: Optional[np.ndarray] = None,
                  min_depth: float = 0.0, max_depth: float = np.inf) -> Dict[str, float]:
    """Errors of a predicted depth map against ground truth on pixels where both are valid.

    Returns ``median_rel`` / ``mean_rel`` (|pred - gt| / gt), ``mae_m``, ``rmse_m``
    (metres), ``imae_per_km``, ``irmse_per_km`` (inverse depth, 1/km),
    ``delta_1.25`` (fraction with max(pred/gt, gt/pred) < 1.25) and
    ``n_pixels`` / ``coverage`` (fraction of valid ground-truth pixels predicted).
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"pred shape {pred.shape} != gt shape {gt.shape}")
    gt_ok = np.isfinite(gt) & (gt > min_depth) & (gt < max_depth)
    if mask is not None:
        gt_ok &= np.asarray(mask, bool)
    ok = gt_ok & np.isfinite(pred) & (pred > 0)
    n = int(ok.sum())
    if n == 0:
        return {"n_pixels": 0, "coverage": 0.0}
    p, g = pred[ok], gt[ok]
    rel = np.abs(p - g) / g
    inv = np.abs(1.0 / p - 1.0 / g) * 1000.0
    return {
        "median_rel": float(np.median(rel)), "mean_rel": float(np.mean(rel)),
        "mae_m": float(np.mean(np.abs(p - g))), "rmse_m": float(np.sqrt(np.mean((p - g) ** 2))),
        "imae_per_km": float(np.mean(inv)), "irmse_per_km": float(np.sqrt(np.mean(inv ** 2))),
        "delta_1.25": float(np.mean(np.maximum(p / g, g / p) < 1.25)),
        "n_pixels": n, "coverage": float(n / max(int(gt_ok.sum()), 1)),
    }


def primitive_fit_errors(primitives, gt_depth: np.ndarray) -> Dict[str, float]:
    """Shape accuracy of primitives: fit one log-scale per primitive to
    ``gt_depth`` (median, docs/design.md §5), then :func:`depth_metrics` of the
    resulting depth map.  Primitives with no valid ground truth are dropped."""
    s, _ = primitives.fit_log_scales(gt_depth)
    keep = np.flatnonzero(np.isfinite(s))
    if keep.size == 0:
        return {"n_pixels": 0, "coverage": 0.0, "n_primitives": len(primitives)}
    sub = primitives.subset(keep).with_log_scales(s[keep])
    out = depth_metrics(sub.depth_map(), gt_depth)
    out["n_primitives"] = len(primitives)
    return out


def void_metrics(pred: np.ndarray, gt: np.ndarray, min_depth: float = VOID_MIN_DEPTH,
                 max_depth: float = VOID_MAX_DEPTH) -> Dict[str, float]:
    """VOID metrics of one image (the protocol of :mod:`spgeo.evaluation.completion.void`):
    ``mae_mm``, ``rmse_mm``, ``imae_per_km``, ``irmse_per_km`` on pixels with
    ``min_depth < gt < max_depth`` (metres), plus ``n_pixels`` and ``coverage``
    (fraction of those pixels predicted); NaN metrics when no pixel is predicted."""
    m = depth_metrics(pred, gt, min_depth=min_depth, max_depth=max_depth)
    if m["n_pixels"] == 0:
        return {k: float("nan") for k in VOID_METRIC_KEYS} | {"n_pixels": 0, "coverage": 0.0}
    return {"mae_mm": 1e3 * m["mae_m"], "rmse_mm": 1e3 * m["rmse_m"],
            "imae_per_km": m["imae_per_km"], "irmse_per_km": m["irmse_per_km"],
            "n_pixels": m["n_pixels"], "coverage": m["coverage"]}
