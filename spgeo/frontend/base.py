"""Front-end interfaces: image (+ optional depth) + camera -> PrimitiveSet.

A front-end is a :class:`Segmenter` (image -> regions with anchor pixels) and a
:class:`NormalEstimator` (image -> unit normals) composed by
:class:`spgeo.frontend.pipeline.PrimitiveFrontEnd`, which splits regions into
connected parts, integrates normals into log-depth and returns a
:class:`spgeo.primitives.PrimitiveSet`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, List, Optional, Protocol, runtime_checkable

import numpy as np

from ..camera import PinholeCamera

__all__ = ["Segmentation", "Segmenter", "NormalEstimator", "MetricDepthEstimator",
           "masks_to_segmentation", "config_with_overrides"]


@dataclass
class Segmentation:
    """Regions of one image.  Regions may overlap.

    Attributes:
        height, width: image size in pixels.
        regions: list of N int64 arrays of flat pixel indices ``v * width + u``
            (sorted, unique, non-empty).
        anchors: (N,) int64 flat index of each region's anchor pixel (inside the
            region; for a promptable segmenter, the prompt point).
        scores: (N,) float quality score (predicted IoU for SAM, 1.0 otherwise).
        meta: segmenter-specific information (counts of dropped queries etc.).
    """

    height: int
    width: int
    regions: List[np.ndarray]
    anchors: np.ndarray
    scores: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.regions)
        self.anchors = np.asarray(self.anchors, dtype=np.int64).reshape(-1)
        self.scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        if self.anchors.shape != (n,) or self.scores.shape != (n,):
            raise ValueError(f"Segmentation: {n} regions but {self.anchors.shape[0]} anchors and "
                             f"{self.scores.shape[0]} scores")
        npix = self.height * self.width
        for i, r in enumerate(self.regions):
            r = np.asarray(r, dtype=np.int64)
            if r.ndim != 1 or r.size == 0:
                raise ValueError(f"Segmentation: region {i} is empty")
            if r[0] < 0 or r[-1] >= npix or np.any(np.diff(r) <= 0):
                raise ValueError(f"Segmentation: region {i} indices must be sorted, unique and "
                                 f"inside [0, {npix})")
            self.regions[i] = r

    def __len__(self) -> int:
        return len(self.regions)

    def mask(self, i: int) -> np.ndarray:
        """Dense (H, W) bool mask of region ``i``."""
        m = np.zeros(self.height * self.width, dtype=bool)
        m[self.regions[i]] = True
        return m.reshape(self.height, self.width)

    def coverage(self) -> np.ndarray:
        """(H, W) int count of regions covering each pixel."""
        c = np.zeros(self.height * self.width, dtype=np.int32)
        for r in self.regions:
            c[r] += 1
        return c.reshape(self.height, self.width)


def masks_to_segmentation(masks: np.ndarray, anchors_uv: Optional[np.ndarray] = None,
                          scores: Optional[np.ndarray] = None, meta: Optional[dict] = None
                          ) -> Segmentation:
    """Build a :class:`Segmentation` from dense (N, H, W) bool masks.

    Anchors default to each mask's most interior pixel (maximum of the distance
    transform); ``anchors_uv`` (N, 2) gives (u, v) pixels instead.  Empty masks
    raise ``ValueError``.
    """
    from ..primitives import interior_anchor

    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise ValueError(f"masks must be (N, H, W), got shape {masks.shape}")
    n, h, w = masks.shape
    regions = [np.flatnonzero(m) for m in masks]
    for i, r in enumerate(regions):
        if r.size == 0:
            raise ValueError(f"mask {i} is empty")
    if anchors_uv is None:
        anchors = np.array([interior_anchor(masks[i]) for i in range(n)], dtype=np.int64)
    else:
        anchors_uv = np.asarray(anchors_uv)
        anchors = np.round(anchors_uv[:, 1]).astype(np.int64) * w + np.round(
            anchors_uv[:, 0]).astype(np.int64)
    return Segmentation(h, w, regions, anchors,
                        np.ones(n) if scores is None else scores, meta or {})


@runtime_checkable
class Segmenter(Protocol):
    """Cuts an image into (possibly overlapping) regions."""

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        """``image``: float32 [0, 1], (H, W, 3) RGB or (H, W) grey, matching ``camera``."""
        ...


@runtime_checkable
class NormalEstimator(Protocol):
    """Predicts per-pixel unit surface normals in spgeo's camera convention.

    Camera frame x right, y down, z forward; normals point towards the camera
    (a wall facing the camera has ``n = (0, 0, -1)``).  Returns float32
    (H, W, 3); NaN where no normal is known.  ``uses_depth`` is True for
    estimators that read the depth image (RGB-D / oracle only).
    """

    uses_depth: bool

    def estimate(self, image: np.ndarray, camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        ...


@runtime_checkable
class MetricDepthEstimator(Protocol):
    """Predicts metric depth from one image (no sensor depth read).

    ``predict_metric(image)``: ``image`` (H, W) grey or (H, W, 3) RGB, uint8 /
    uint16 or float in [0, 1] (grey is used as RGB with equal channels);
    returns float32 (H, W) depth in metres along the optical axis at the image
    size, NaN where invalid.  Raises ``ValueError`` for a bad image or a model
    that cannot give metric depth.  Implemented by
    :class:`spgeo.frontend.onnx_depth.OnnxDepthNormals` with a metric config.
    """

    def predict_metric(self, image: np.ndarray) -> np.ndarray:
        ...


def config_with_overrides(config_type: type, config: Optional[Any], overrides: dict) -> Any:
    """``config_type(**overrides)`` when ``config`` is None, else ``config`` with
    ``overrides`` applied (:func:`dataclasses.replace`)."""
    if config is None:
        return config_type(**overrides)
    return dataclasses.replace(config, **overrides) if overrides else config
