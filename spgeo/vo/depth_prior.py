"""A learned scale anchor for the monocular VO: a metric depth network's depth
of each keyframe becomes a weak prior on the keyframe's scale.

A monocular map has one free scale, and the window mapper passes it from
keyframe to keyframe through rendered depth, so it drifts.  With a depth
model given (:class:`~spgeo.frontend.base.MetricDepthEstimator`, e.g.
:func:`spgeo.frontend.metric_depth_from_cache`), each new
keyframe's image goes through the network once; every primitive's log-scale
that best fits the network's depth is stored (:class:`DepthTargets`, a few
numbers per primitive, not the depth map).  When the keyframe enters the
smoother, one :func:`~spgeo.factors.priors.mean_log_scale_prior` pulls the
pixel-weighted mean of its log-scales towards the network's: the target is
the keyframe's current mean plus the weighted *median* of the per-primitive
offsets (robust to primitives the network gets wrong), with standard
deviation ``OdometryConfig.depth_prior_sigma``.  The relative scales of the
primitives stay free (the network is blurry at boundaries), only the
keyframe's overall scale is anchored; the prior's information is kept when
the keyframe is marginalised, so over many keyframes the map's scale is held
near the network's.  A monocular map also *starts* at the network's scale
(keyframe 0's primitives take the weighted median of their fitted
log-scales).

Planar primitive models have no log-scale variable: the prior is refused
there (``ValueError`` at :class:`~spgeo.vo.Odometry` construction).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

import gtsam

from ..factors.priors import mean_log_scale_prior
from ..frontend.base import MetricDepthEstimator
from ..primitives import PrimitiveSet

__all__ = ["DepthTargets", "depth_targets", "keyframe_scale_prior",
           "weighted_median", "check_depth_model"]

#: fewest pixels with network depth for a primitive to take part
MIN_POINTS = 20


@dataclass(frozen=True)
class DepthTargets:
    """The network's scale of one keyframe's primitives.

    Attributes:
        log_scales: (N,) log-scale of each primitive that fits the network's
            depth (median of log depth - log unscaled depth), NaN where fewer
            than :data:`MIN_POINTS` pixels had depth.
        n_points: (N,) pixels with network depth per primitive.
    """

    log_scales: np.ndarray
    n_points: np.ndarray

    def offset(self, log_scales: np.ndarray) -> Optional[float]:
        """Weighted median (weights: pixels) of ``targets - log_scales`` over the
        fitted primitives: how far the network puts the keyframe from
        ``log_scales`` (N,); None when no primitive was fitted or the count
        differs from ``log_scales``."""
        s = np.asarray(log_scales, dtype=float).reshape(-1)
        ok = self._fitted()
        if s.size != self.log_scales.size or not ok.any():
            return None
        return weighted_median(self.log_scales[ok] - s[ok], self.n_points[ok])

    def weights(self) -> np.ndarray:
        """(N,) shares of the fitted pixels (0 for unfitted primitives; sum 1)."""
        w = np.where(self._fitted(), self.n_points, 0).astype(float)
        return w / w.sum()

    def _fitted(self) -> np.ndarray:
        return np.isfinite(self.log_scales) & (self.n_points >= MIN_POINTS)


def check_depth_model(model: Optional[MetricDepthEstimator], frontend, config) -> None:
    """``ValueError`` when a depth model cannot anchor the VO's scale: it has
    no ``predict_metric``, the front-end uses depth (scales already metric) or
    ``config.primitive_model`` is ``"planar"`` (no log-scale variables)."""
    if model is None:
        return
    if not callable(getattr(model, "predict_metric", None)):
        raise ValueError(f"depth model {model!r} has no predict_metric(image) method "
                         "(spgeo.frontend.MetricDepthEstimator)")
    if getattr(frontend, "uses_depth", False):
        raise ValueError("a depth model anchors a monocular front-end's scale; the front-end "
                         f"{getattr(frontend, 'name', frontend)!r} reads sensor depth already")
    if config.primitive_model == "planar":
        raise ValueError("the depth model's scale prior needs log-scale primitives; "
                         "OdometryConfig.primitive_model 'planar' has none")


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value at which the cumulative weight of sorted ``values`` reaches half
    (``values``, ``weights``: (M,), M >= 1, weights > 0)."""
    v = np.asarray(values, dtype=float)
    order = np.argsort(v)
    cw = np.cumsum(np.asarray(weights, dtype=float)[order])
    return float(v[order][np.searchsorted(cw, 0.5 * cw[-1])])


def depth_targets(model: MetricDepthEstimator, image: np.ndarray,
                  primitives: PrimitiveSet) -> DepthTargets:
    """The network's depth of ``image`` fitted to each primitive's shape.

    ``image`` is the keyframe's input image at the primitives' camera size.
    Raises ``ValueError`` when the model returns a map of another size.
    """
    depth = np.asarray(model.predict_metric(image), dtype=np.float32)
    if depth.shape != tuple(primitives.camera.size[::-1]):
        raise ValueError(f"depth model {model!r} returned a {depth.shape} map for a "
                         f"{primitives.camera.size[0]}x{primitives.camera.size[1]} image")
    s, n = primitives.fit_log_scales(depth, min_points=MIN_POINTS)
    return DepthTargets(s, n)


def keyframe_scale_prior(targets: DepthTargets, keys: Sequence[int], log_scales: np.ndarray,
                         sigma: float) -> Optional[gtsam.CustomFactor]:
    """The keyframe's mean-log-scale prior (module docstring) over the
    log-scale variables ``keys`` at their current values ``log_scales`` (N,);
    None when no primitive fits the network's depth."""
    c = targets.offset(log_scales)
    if c is None:
        return None
    w = targets.weights()
    used = w > 0
    keys = [k for k, u in zip(keys, used) if u]
    target = float(np.dot(w[used], np.asarray(log_scales, float)[used]) + c)
    return mean_log_scale_prior(keys, w[used], target, sigma)
