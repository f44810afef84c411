"""Front-ends: image (+ optional depth) + camera -> :class:`~spgeo.primitives.PrimitiveSet`.

* ``classical``: opencv-contrib superpixels + fronto-parallel normals (constant
  depth per primitive; offline default, reads no depth, needs no model file).
* ``manhattan``: classical segments + vanishing-point (Manhattan) normals
  (:class:`~spgeo.frontend.manhattan.ManhattanNormals`, one orientation per
  segment from line segments and vanishing directions, fronto-parallel where
  unknown; offline, reads no depth, needs no model file).
* ``depth``: classical segments + normals computed from a depth image
  (**uses depth**: RGB-D input or oracle ablations).
* ``onnx``: SAM-style promptable segmenter + surface-normal network run with
  onnxruntime (the design's main path; models via ``spgeo models``).
* ``onnx-depth``: classical (or SAM) segments + normals of a monocular depth
  network's output (:class:`~spgeo.frontend.onnx_depth.OnnxDepthNormals`;
  reads no sensor depth; models via ``spgeo models``).

The *oracle* (ground-truth segments and normals, the pipeline's upper bound; not a
named front-end): :func:`spgeo.frontend.oracle.oracle_frontend`.

Metric depth from one image (not a front-end): :class:`MetricDepthEstimator`
(``predict_metric(image) -> metres``) and :func:`metric_depth_from_cache` (a
metric-depth ONNX network, e.g. FastDepth with the ``"fastdepth"`` preset).
"""
from __future__ import annotations

from typing import Optional, Tuple

from .base import (MetricDepthEstimator, NormalEstimator, Segmentation, Segmenter,
                   masks_to_segmentation)
from .pipeline import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd, split_regions

__all__ = [
    "FRONTENDS", "MONOCULAR_FRONTENDS", "FrontEndConfig", "LabelSegmenter", "NormalEstimator", "PrimitiveFrontEnd",
    "Segmentation", "Segmenter", "make_frontend", "masks_to_segmentation", "split_regions",
    "MetricDepthEstimator", "metric_depth_from_cache", "build_frontend", "check_model_options",
]

FRONTENDS = ("classical", "manhattan", "depth", "onnx", "onnx-depth")
#: the front-ends that never read a depth image (all but ``depth``)
MONOCULAR_FRONTENDS = tuple(f for f in FRONTENDS if f != "depth")


def make_frontend(name: str, config: FrontEndConfig = FrontEndConfig(),
                  segmenter: Optional[Segmenter] = None, sam: Optional[dict] = None,
                  normals: Optional[dict] = None) -> PrimitiveFrontEnd:
    """Build a named front-end (see the module docstring).

    ``segmenter`` replaces the default segmenter (e.g. a :class:`LabelSegmenter`
    of ground-truth surface ids for oracle ablations).  For ``onnx``, ``sam``
    holds keyword arguments of :func:`spgeo.frontend.from_cache.sam_frontend_from_cache`
    (registry family or ``encoder=``/``decoder=`` paths) and ``normals`` those
    of :func:`spgeo.frontend.from_cache.normal_model_from_cache` (registry
    name or path).  For ``onnx-depth``, ``normals`` holds keyword arguments of
    :func:`spgeo.frontend.from_cache.depth_normals_from_cache` and the segments
    are SAM's when ``sam`` is given, else classical.  Raises ``ValueError`` for
    an unknown name.
    """
    from .classical import ClassicalSegmenter
    from .depth_normals import DepthNormalEstimator, FrontoParallelNormals

    if name == "classical":
        return PrimitiveFrontEnd(segmenter or ClassicalSegmenter(), FrontoParallelNormals(),
                                 config, name="classical")
    if name == "manhattan":
        from .manhattan import ManhattanNormals, SharedSegmenter

        shared = SharedSegmenter(segmenter or ClassicalSegmenter())
        return PrimitiveFrontEnd(shared, ManhattanNormals(segmenter=shared), config,
                                 name="manhattan")
    if name == "depth":
        return PrimitiveFrontEnd(segmenter or ClassicalSegmenter(), DepthNormalEstimator(),
                                 config, name="depth (uses depth)")
    if name == "onnx":
        from .from_cache import normal_model_from_cache, sam_frontend_from_cache

        seg = segmenter or sam_frontend_from_cache(**(sam or {}))
        return PrimitiveFrontEnd(seg, normal_model_from_cache(**(normals or {})), config,
                                 name="onnx")
    if name == "onnx-depth":
        from .from_cache import depth_normals_from_cache, sam_frontend_from_cache

        seg = segmenter or (sam_frontend_from_cache(**sam) if sam is not None
                            else ClassicalSegmenter())
        return PrimitiveFrontEnd(seg, depth_normals_from_cache(**(normals or {})), config,
                                 name="onnx-depth")
    raise ValueError(f"unknown front-end {name!r}; choose one of {FRONTENDS}")


def check_model_options(name: str, normal_model: Optional[str] = None,
                        depth_model: Optional[str] = None) -> None:
    """Refuse a model option the front-end ``name`` would not use.

    ``normal_model`` names the ``onnx`` front-end's normal network only; the
    ``onnx-depth`` front-end's depth network is ``depth_model``
    (``--depth-model NAME|PATH``), which no other front-end uses.  Raises
    ``ValueError`` saying so (naming the value) when ``name`` is ``"onnx-depth"``
    and ``normal_model`` is given, or ``name`` is another front-end and
    ``depth_model`` is given.
    """
    if name == "onnx-depth" and normal_model:
        raise ValueError(f"the normal model {normal_model!r} names the onnx front-end's normal "
                         "network; onnx-depth takes its depth network as the depth model "
                         f"(--depth-model {normal_model})")
    if name != "onnx-depth" and depth_model:
        raise ValueError(f"the depth model {depth_model!r} is the onnx-depth front-end's depth "
                         f"network; the front-end {name!r} does not use it (choose the "
                         "onnx-depth front-end or leave the depth model out)")


def build_frontend(name: str, working_size: Optional[Tuple[int, int]] = None, *,
                   sam_family: Optional[str] = None, normal_model: Optional[str] = None,
                   depth_model: Optional[str] = None) -> PrimitiveFrontEnd:
    """A named front-end from the options users hold (the ``spgeo vo`` / ``sfm`` flags).

    Args:
        name: one of :data:`FRONTENDS`.
        working_size: ``(width, height)`` of the primitives (None: each image's size).
        sam_family: ``onnx`` / ``onnx-depth``: SAM registry family (``onnx``
            default ``efficientsam-vitt``; ``onnx-depth`` uses classical segments
            unless it is given).
        normal_model: ``onnx``: normal network, registry name (built-in or
            :func:`spgeo.models.register_model`) or ``.onnx`` path (default
            ``metric3d-vit-small-fp16``).  Refused for ``onnx-depth``
            (:func:`check_model_options`).
        depth_model: ``onnx-depth``: depth network, registry name or path
            (default ``depth-anything-v2-small``; a path without a registry entry
            gets the ``generic-depth-518`` preset).  Refused for the other
            front-ends (:func:`check_model_options`).

    Raises ``ValueError`` for an unknown name, a normal model with ``onnx-depth``,
    a depth model with another front-end, or a model that breaks its preset's
    contract (the message names the file, the sizes and the fix); ``FileNotFoundError`` for a model neither in the
    cache nor on disk.  Nothing is downloaded.
    """
    check_model_options(name, normal_model, depth_model)
    sam = normals = None
    if name == "onnx":
        sam = {"family": sam_family} if sam_family else None
        normals = {"name_or_path": normal_model} if normal_model else None
    elif name == "onnx-depth":
        sam = {"family": sam_family} if sam_family else None
        normals = {"name_or_path": depth_model} if depth_model else None
    size = None if working_size is None else tuple(int(v) for v in working_size)
    return make_frontend(name, FrontEndConfig(working_size=size), sam=sam, normals=normals)


def __getattr__(name: str):
    """``spgeo.frontend.metric_depth_from_cache``: imported on first use
    (:mod:`spgeo.frontend.from_cache` loads the ONNX adapters)."""
    if name == "metric_depth_from_cache":
        from . import from_cache

        return from_cache.metric_depth_from_cache
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
