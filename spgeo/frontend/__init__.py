"""Front-ends: image (+ optional depth) + camera -> :class:`~spgeo.primitives.PrimitiveSet`.

* ``classical``: opencv-contrib superpixels + fronto-parallel normals (constant
  depth per primitive; offline default, reads no depth, needs no model file).
* ``depth``: classical segments + normals computed from a depth image
  (**uses depth**: RGB-D input or oracle ablations).
* ``onnx``: SAM-style promptable segmenter + surface-normal network run with
  onnxruntime (the design's main path; models via ``spgeo models``).
"""
from __future__ import annotations

from typing import Optional

from .base import NormalEstimator, Segmentation, Segmenter, masks_to_segmentation
from .pipeline import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd, split_regions

__all__ = [
    "FRONTENDS", "FrontEndConfig", "LabelSegmenter", "NormalEstimator", "PrimitiveFrontEnd",
    "Segmentation", "Segmenter", "make_frontend", "masks_to_segmentation", "split_regions",
]

FRONTENDS = ("classical", "depth", "onnx")


def make_frontend(name: str, config: FrontEndConfig = FrontEndConfig(),
                  segmenter: Optional[Segmenter] = None, sam: Optional[dict] = None,
                  normals: Optional[dict] = None) -> PrimitiveFrontEnd:
    """Build a named front-end (see the module docstring).

    ``segmenter`` replaces the default segmenter (e.g. a :class:`LabelSegmenter`
    of ground-truth surface ids for oracle ablations).  For ``onnx``, ``sam``
    holds keyword arguments of :func:`spgeo.frontend.from_cache.sam_frontend_from_cache`
    (registry family or ``encoder=``/``decoder=`` paths) and ``normals`` those
    of :func:`spgeo.frontend.from_cache.normal_model_from_cache` (registry
    name or path).  Raises ``ValueError`` for an unknown name.
    """
    from .classical import ClassicalSegmenter
    from .depth_normals import DepthNormalEstimator, FrontoParallelNormals

    if name == "classical":
        return PrimitiveFrontEnd(segmenter or ClassicalSegmenter(), FrontoParallelNormals(),
                                 config, name="classical")
    if name == "depth":
        return PrimitiveFrontEnd(segmenter or ClassicalSegmenter(), DepthNormalEstimator(),
                                 config, name="depth (uses depth)")
    if name == "onnx":
        from .from_cache import normal_model_from_cache, sam_frontend_from_cache

        seg = segmenter or sam_frontend_from_cache(**(sam or {}))
        return PrimitiveFrontEnd(seg, normal_model_from_cache(**(normals or {})), config,
                                 name="onnx")
    raise ValueError(f"unknown front-end {name!r}; choose one of {FRONTENDS}")
