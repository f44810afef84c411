"""Shape that propagates through the VO map (docs/design.md §5.1, *Keyframes*).

A monocular front-end gives a new keyframe's primitives the shapes it can infer
from one image (fronto-parallel for the classical front-end).  The window of
previous keyframes has refined geometry; rendered into the new keyframe
(:func:`spgeo.vo.rendering.render_primitives`) it gives a depth map whose
normals (:func:`spgeo.frontend.depth_normals.normals_from_depth`) are the map's
surface orientations.  :func:`propagate_shapes` re-integrates the shape of every
primitive that the render covers well enough from those normals
(:func:`spgeo.integration.integrate_normals_regions`; pixels of such a primitive
without a rendered normal borrow their neighbours', as front-ends do); the other
primitives keep the front-end's shape.  Log-scales are untouched: the caller
initialises them from the same render afterwards.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..frontend.depth_normals import DepthNormalEstimatorConfig, normals_from_depth
from ..integration import IntegrationConfig, integrate_normals_regions
from ..primitives import PrimitiveSet

__all__ = ["PropagatedShapes", "propagate_shapes"]

log = logging.getLogger(__name__)


@dataclass
class PropagatedShapes:
    """Result of :func:`propagate_shapes`.

    Attributes:
        primitives: the primitives, shapes (and per-entry normals) replaced where
            ``propagated``; log-scales, pixels and anchors unchanged.
        propagated: (N,) bool, the primitives whose shape came from the render.
        coverage: (N,) fraction of each primitive's pixels with a rendered normal.
    """

    primitives: PrimitiveSet
    propagated: np.ndarray
    coverage: np.ndarray


def propagate_shapes(primitives: PrimitiveSet, rendered_depth: np.ndarray,
                     min_coverage: float = 0.6,
                     normals_config: Optional[DepthNormalEstimatorConfig] = None
                     ) -> PropagatedShapes:
    """Give the primitives covered by a rendered depth map the shapes of its normals.

    Args:
        primitives: the new keyframe's primitives (camera = the render's grid).
        rendered_depth: (H, W) metres along the optical axis in ``primitives.camera``;
            NaN / <= 0 where nothing was rendered.
        min_coverage: a primitive takes the rendered shape when at least this
            fraction (0, 1] of its pixels has a rendered normal.
        normals_config: how normals are estimated from the render (default PCA,
            holes left unknown).
    Returns:
        :class:`PropagatedShapes` (the input set itself when nothing is covered).
    Raises:
        ValueError: ``min_coverage`` outside (0, 1] or a depth map of another size.
    """
    if not 0.0 < min_coverage <= 1.0:
        raise ValueError(f"min_coverage must be in (0, 1], got {min_coverage!r}")
    cam = primitives.camera
    depth = np.asarray(rendered_depth, dtype=np.float64)
    if depth.shape != cam.shape:
        raise ValueError(f"rendered depth is {depth.shape}, the primitives' camera {cam.shape}")
    n = len(primitives)
    none = PropagatedShapes(primitives, np.zeros(n, bool), np.zeros(n))
    if not np.any(np.isfinite(depth) & (depth > 0)):
        return none
    normals = normals_from_depth(depth, cam, normals_config or DepthNormalEstimatorConfig())
    entry_normals = normals.reshape(-1, 3)[primitives.pixels]
    known = np.isfinite(entry_normals[:, 0])
    ids = primitives.primitive_ids
    coverage = np.bincount(ids[known], minlength=n) / np.maximum(primitives.sizes, 1)
    take = coverage >= min_coverage
    if not np.any(take):
        return PropagatedShapes(primitives, take, coverage)
    idx = np.flatnonzero(take)
    off = primitives.offsets
    regions = [primitives.pixels[off[i]:off[i + 1]] for i in idx]
    res = integrate_normals_regions(normals, regions, cam, primitives.anchors[idx],
                                    IntegrationConfig(unknown_normals="fill"))
    sel = take[ids]                       # entries of the taken primitives, in region order
    log_depth = primitives.log_depth.copy()
    log_depth[sel] = res.log_depth
    if not np.all(np.isfinite(log_depth)):   # defensive: "fill" gives finite shapes
        raise ValueError("propagate_shapes: integration gave non-finite log-depth")
    new_normals = None
    if primitives.normals is not None:
        new_normals = primitives.normals.copy()
        use = sel & known
        new_normals[use] = entry_normals[use]
    out = PrimitiveSet(cam, primitives.pixels, primitives.offsets, log_depth,
                       primitives.anchors, primitives.log_scales, primitives.scores,
                       new_normals, {**primitives.meta, "shapes_propagated": int(take.sum())})
    log.debug("propagate_shapes: %d of %d primitives took the rendered shape", take.sum(), n)
    return PropagatedShapes(out, take, coverage)
