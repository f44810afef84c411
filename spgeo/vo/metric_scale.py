"""Metric output scale of a monocular VO run, from a metric-depth network.

A monocular map is in an arbitrary unit (the VO's: keyframe 0's median depth is about
one).  :func:`estimate_metric_scale` turns it into metres with one global factor ``s``
(metres per VO unit) read off a single-image metric-depth network (e.g. FastDepth,
:meth:`spgeo.frontend.onnx_depth.OnnxDepthNormals.predict_metric`):

1. per keyframe, over the pixels valid in both maps (finite, > 0), the median of
   ``log(network depth / keyframe depth)`` (robust to the network's blur at
   boundaries and to wrong primitives); a keyframe with fewer than
   ``MetricScaleConfig.min_pixels`` such pixels gives no ratio;
2. ``s = exp(median over keyframes of those log ratios)``;
3. its spread: ``exp(1.4826 * MAD)`` of the per-keyframe log ratios (a robust
   one-sigma factor, >= 1; 1 for one keyframe) and the 16th / 84th percentiles
   of the per-keyframe scales.

It is an OUTPUT scale: the VO never sees it (no prior in the optimisation).
:class:`ScaledOdometry` applies it to a run's outputs as the similarity
``x -> s x`` about the world origin (keyframe 0's camera): trajectory
translations, keyframe poses and depths (so clouds, fused meshes and exports),
rotations unchanged.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Callable, Dict, Iterable, Iterator, List, Optional, Tuple

import numpy as np

from ..configs import config_class
from ..trajectory import METRES, Trajectory
from .tracking import Keyframe
from .readout import OdometryReadout

__all__ = ["MetricScaleConfig", "MetricScale", "estimate_metric_scale", "scaled_keyframe",
           "scaled_trajectory", "ScaledOdometry"]

log = logging.getLogger(__name__)

#: MAD -> standard deviation of a normal distribution
_MAD_TO_SIGMA = 1.4826

#: ``image -> metric depth``: (H, W[, 3]) image -> (H, W) metres, NaN / <= 0 invalid
DepthPredictor = Callable[[np.ndarray], np.ndarray]


@config_class
@dataclass(frozen=True)
class MetricScaleConfig:
    """Options of :func:`estimate_metric_scale`.

    Attributes:
        min_pixels: a keyframe counts only with at least this many pixels valid
            in both depth maps (default 100).
    """

    min_pixels: int = 100

    def __post_init__(self) -> None:
        if isinstance(self.min_pixels, bool) or int(self.min_pixels) != self.min_pixels \
                or self.min_pixels < 1:
            raise ValueError(f"MetricScaleConfig.min_pixels must be an integer >= 1, "
                             f"got {self.min_pixels!r}")


@dataclass(frozen=True)
class MetricScale:
    """A run's estimated metric scale (metres per VO unit).

    Attributes:
        scale: the global factor ``s`` (module docstring), > 0.
        spread: ``exp(1.4826 * MAD)`` of the per-keyframe log ratios (>= 1; a
            factor: most keyframes lie within ``[s / spread, s * spread]``).
        interval: ``(16th, 84th)`` percentile of the per-keyframe scales.
        n_keyframes: keyframes that gave a ratio.
        per_keyframe: per input keyframe, in order, its scale (None: too few
            pixels valid in both maps).
        n_pixels: per input keyframe, the pixels valid in both maps.
        model: the depth network's name or path (set by the caller; None here).
        seconds: wall time of the estimate incl. the network (set by the caller).
    """

    scale: float
    spread: float
    interval: Tuple[float, float]
    n_keyframes: int
    per_keyframe: Tuple[Optional[float], ...]
    n_pixels: Tuple[int, ...]
    model: Optional[str] = None
    seconds: Optional[float] = None

    def to_dict(self) -> Dict[str, object]:
        """JSON-ready (``report.json``'s ``"metric_scale"``; ``estimated``: True)."""
        return {"scale": self.scale, "spread": self.spread, "interval": list(self.interval),
                "n_keyframes": self.n_keyframes, "per_keyframe": list(self.per_keyframe),
                "n_pixels": list(self.n_pixels), "model": self.model, "seconds": self.seconds,
                "estimated": True}


def _keyframe_log_ratio(image: np.ndarray, depth: np.ndarray, predict_depth: DepthPredictor,
                        min_pixels: int) -> Tuple[Optional[float], int]:
    """``(median log(network / keyframe depth) or None, pixels valid in both)``; the
    prediction is resized (nearest) to ``depth``'s shape when it differs."""
    depth = np.asarray(depth, dtype=np.float64)
    net = np.asarray(predict_depth(image), dtype=np.float64)
    if net.ndim != 2 or depth.ndim != 2:
        raise ValueError(f"estimate_metric_scale: depth maps must be (H, W), got network "
                         f"{net.shape} and keyframe {depth.shape}")
    if net.shape != depth.shape:
        import cv2

        net = cv2.resize(net, (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_NEAREST)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(net) & np.isfinite(depth) & (net > 0) & (depth > 0)
    n = int(valid.sum())
    if n < min_pixels:
        return None, n
    return float(np.median(np.log(net[valid]) - np.log(depth[valid]))), n


def estimate_metric_scale(keyframes: Iterable[Tuple[np.ndarray, np.ndarray]],
                          predict_depth: DepthPredictor,
                          config: MetricScaleConfig = MetricScaleConfig()) -> MetricScale:
    """The metric scale of a map from its keyframes (module docstring).

    Args:
        keyframes: ``(image, keyframe depth map)`` pairs, read once in order (a
            generator keeps one in memory): the image as ``predict_depth`` takes
            it, the depth (H, W) in VO units, NaN / <= 0 where unknown.
        predict_depth: image -> (H', W') metric depth in metres (NaN / <= 0
            invalid), e.g. a network's ``predict_metric`` or an oracle; resized
            (nearest) to the keyframe depth's size when it differs.
        config: :class:`MetricScaleConfig`.

    Returns a :class:`MetricScale` (``model`` and ``seconds`` None).

    Raises:
        ValueError: no keyframe has ``config.min_pixels`` pixels valid in both
            maps (naming the counts), or a depth map that is not 2-D.
    """
    ratios: List[Optional[float]] = []
    counts: List[int] = []
    for image, depth in keyframes:
        r, n = _keyframe_log_ratio(image, depth, predict_depth, config.min_pixels)
        ratios.append(r)
        counts.append(n)
    logs = np.array([r for r in ratios if r is not None], dtype=np.float64)
    if logs.size == 0:
        what = ("no keyframe was given" if not counts else
                f"none of the {len(counts)} keyframes has {config.min_pixels} pixels with "
                f"valid depth in both the network's and the keyframe's map (most: {max(counts)})")
        raise ValueError(f"no metric scale: {what}")
    centre = float(np.median(logs))
    mad = float(np.median(np.abs(logs - centre)))
    lo, hi = np.percentile(logs, [16.0, 84.0])
    res = MetricScale(float(np.exp(centre)), float(np.exp(_MAD_TO_SIGMA * mad)),
                      (float(np.exp(lo)), float(np.exp(hi))), int(logs.size),
                      tuple(None if r is None else float(np.exp(r)) for r in ratios),
                      tuple(counts))
    log.info("metric scale %.4g (spread x%.3g) from %d of %d keyframes", res.scale,
             res.spread, res.n_keyframes, len(counts))
    return res


def scaled_trajectory(trajectory: Trajectory, scale: float) -> Trajectory:
    """``trajectory`` with every camera centre multiplied by ``scale`` (the
    similarity ``x -> scale x`` about the world origin; rotations unchanged)."""
    poses = np.array(trajectory.poses, dtype=np.float64)
    poses[:, :3, 3] *= float(scale)
    return dataclasses.replace(trajectory, poses=poses)


def scaled_keyframe(keyframe: Keyframe, scale: float) -> Keyframe:
    """``keyframe`` under ``x -> scale x`` about the world origin: camera centre
    times ``scale``, every primitive's depth times ``scale`` (log-scales ``+=
    log scale``), rotation, pixels and image unchanged."""
    prims = keyframe.primitives
    T = np.array(keyframe.T_world_kf, dtype=np.float64)
    T[:3, 3] *= float(scale)
    return keyframe.rebuilt(prims.with_log_scales(prims.log_scales + float(np.log(scale))), T)


class ScaledOdometry:
    """Read-only view of a :class:`spgeo.vo.Odometry` whose map and trajectory
    are those of the odometry under ``x -> scale x`` about the world origin.

    :meth:`result`, :attr:`keyframes`, :meth:`keyframe`, :meth:`iter_keyframes`
    and :meth:`window_keyframes` are scaled (:func:`scaled_trajectory`,
    :func:`scaled_keyframe`), and so is what :meth:`save` writes; every other attribute is the odometry's
    (``camera``, ``frames``, ``n_keyframes``, ``keyframe_image``,
    ``keyframes_with_depth``, ``report``, ...: frame records and reports stay
    in VO units).  Give it wherever an odometry's outputs are read (clouds,
    :func:`spgeo.io.fusion.fuse_odometry`, the COLMAP / nerfstudio exports);
    do not track with it.
    """

    def __init__(self, odometry, scale: float) -> None:
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"ScaledOdometry: scale must be finite and > 0, got {scale!r}")
        self.odometry = odometry
        self.scale = float(scale)

    def __getattr__(self, name: str):
        return getattr(self.odometry, name)

    #: the unit of the positions read out: the view exists for the metric output scale
    units = METRES

    def result(self) -> Trajectory:
        return dataclasses.replace(scaled_trajectory(self.odometry.result(), self.scale),
                                   units=self.units)

    @property
    def keyframes(self) -> List[Keyframe]:
        return [scaled_keyframe(kf, self.scale) for kf in self.odometry.keyframes]

    def keyframe(self, k: int) -> Keyframe:
        return scaled_keyframe(self.odometry.keyframe(k), self.scale)

    def iter_keyframes(self, indices: Optional[Iterable[int]] = None
                       ) -> Iterator[Tuple[int, np.ndarray, Keyframe]]:
        for k, image, kf in self.odometry.iter_keyframes(indices):
            yield k, image, scaled_keyframe(kf, self.scale)

    def window_keyframes(self) -> Dict[int, Keyframe]:
        return {k: scaled_keyframe(kf, self.scale)
                for k, kf in self.odometry.window_keyframes().items()}

    #: :meth:`spgeo.vo.readout.OdometryReadout.save` over this view: trajectory and
    #: clouds scaled (without it the odometry's own ``save`` would write them in VO units)
    save = OdometryReadout.save
