"""A metric-depth network's depth aligned to sparse metric points.

A network such as FastDepth predicts metric depth, but its scale drifts
between scenes and within one (blurry boundaries, out-of-domain surfaces).
The sparse points align it (:func:`align_network_depth`), with one of
:data:`ALIGNMENTS`:

* ``"global"``: one scale, ``exp(median_k (log d_k - log N(u_k)))``;
* ``"primitive"``: one scale per region of a label image (the primitives),
  the median log-ratio of its points where it holds at least ``min_points``
  of them, the global scale elsewhere;
* ``"interp"``: the log-ratios at the points interpolated linearly over the
  image (nearest outside their hull) and applied as a factor;
* ``"inverse_affine"``: ``1/D = a / N + b`` fitted by least squares on the
  points' inverse depths (scale and shift in inverse depth), the global scale
  where the fit is not positive everywhere.

Depth maps are (H, W) metres; pixel coordinates ``uv`` (K, 2) integer-valued,
u = column, v = row.
"""
from __future__ import annotations

import logging
from typing import Optional

import numpy as np

from .fill import nearest_fill, scattered_fill
from .scales import grouped_median

__all__ = ["ALIGNMENTS", "network_depth", "align_network_depth"]

log = logging.getLogger(__name__)

ALIGNMENTS = ("global", "primitive", "interp", "inverse_affine")


def network_depth(model, image: np.ndarray) -> np.ndarray:
    """``model.predict_metric(image)`` at the image size, invalid pixels filled
    with the nearest valid value.

    Args:
        model: an object with ``predict_metric(image) -> (H, W)`` metres, NaN
            invalid (:func:`spgeo.frontend.metric_depth_from_cache`).
        image: (H, W, 3) or (H, W) image as the model takes it.
    Returns:
        (H, W) float64 metres, finite and > 0.
    Raises:
        ValueError: an output of another size or without a valid pixel (plus
            whatever ``predict_metric`` raises for a model that does not fit).
    """
    net = np.asarray(model.predict_metric(image), dtype=np.float64)
    h, w = np.asarray(image).shape[:2]
    what = getattr(model, "what", type(model).__name__)
    if net.shape != (h, w):
        raise ValueError(f"{what}: predict_metric returned shape {net.shape}, expected {(h, w)}")
    ok = np.isfinite(net) & (net > 0)
    if not ok.any():
        raise ValueError(f"{what}: predict_metric returned no valid depth")
    return nearest_fill(net, ok)


def _global_log_scale(ratio: np.ndarray) -> float:
    return float(np.median(ratio)) if ratio.size else 0.0


def align_network_depth(net: np.ndarray, uv: np.ndarray, depth: np.ndarray,
                        mode: str = "primitive", labels: Optional[np.ndarray] = None,
                        min_points: int = 3) -> np.ndarray:
    """The network depth ``net`` aligned to the points (module docstring).

    Args:
        net: (H, W) metres, finite and > 0 (:func:`network_depth`).
        uv: (K, 2) integer-valued pixel coordinates inside the map.
        depth: (K,) metres > 0.
        mode: one of :data:`ALIGNMENTS`.
        labels: ``"primitive"``: (H, W) int region per pixel, -1 = none.
        min_points: ``"primitive"``: points a region needs for its own scale (>= 1).
    Returns:
        (H, W) float64 metres, finite and > 0.
    Raises:
        ValueError: an unknown ``mode``; ``"primitive"`` without ``labels`` of
            the map's shape.
    """
    if mode not in ALIGNMENTS:
        raise ValueError(f"align_network_depth: mode must be one of {ALIGNMENTS}, got {mode!r}")
    uv = np.asarray(uv).reshape(-1, 2).astype(np.int64)
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    u, v = uv[:, 0], uv[:, 1]
    ratio = np.log(depth) - np.log(net[v, u])
    s = _global_log_scale(ratio)
    if mode == "global" or ratio.size == 0:
        return net * np.exp(s)
    if mode == "interp":
        return net * np.exp(scattered_fill(uv, ratio, net.shape))
    if mode == "inverse_affine":
        return _inverse_affine(net, 1.0 / net[v, u], 1.0 / depth, s)
    if labels is None or np.shape(labels) != net.shape:
        raise ValueError("align_network_depth: mode 'primitive' needs labels of the map's shape")
    lab = np.asarray(labels, dtype=np.int64)
    n = int(lab.max()) + 1 if lab.size else 0
    pl = lab[v, u]
    has = pl >= 0
    med, cnt = grouped_median(pl[has], ratio[has], n)
    scale = np.where((cnt >= min_points) & np.isfinite(med), med, s)
    per_pixel = np.where(lab >= 0, scale[np.maximum(lab, 0)] if n else s, s)
    return net * np.exp(per_pixel)


def _inverse_affine(net: np.ndarray, x: np.ndarray, y: np.ndarray, s: float) -> np.ndarray:
    """``1 / (a / net + b)`` with ``(a, b)`` the least-squares fit of ``y ~ a x + b``;
    ``net * exp(s)`` when fewer than 3 points or the result is not positive."""
    if x.size < 3:
        return net * np.exp(s)
    A = np.stack([x, np.ones_like(x)], 1)
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    inv = a / net + b
    if not (a > 0 and np.all(inv > 0)):
        log.debug("inverse-affine alignment not positive (a=%g, b=%g); global scale", a, b)
        return net * np.exp(s)
    return 1.0 / inv
