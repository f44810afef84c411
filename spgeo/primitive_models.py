"""Primitive models: the shapes a primitive set takes in the VO's ablations, and the
shape variables a factor graph optimises for them.

:data:`PRIMITIVE_MODELS` (``OdometryConfig.primitive_model``): ``"integrated"`` (the
paper's model), ``"constant_depth"``, ``"constant_normal"`` and ``"planar"``
(:func:`apply_primitive_model`).  The graphs' shape variable of a primitive is its
log-scale ``(1,)``, or with ``"planar"`` its inverse-depth plane ``(a, b, c)``
(:func:`shape_values`, :func:`from_shape_values`).
"""
from __future__ import annotations

import numpy as np

from .primitives import PrimitiveSet

__all__ = ["PRIMITIVE_MODELS", "apply_primitive_model", "shape_values", "from_shape_values"]

#: ``OdometryConfig.primitive_model`` values: ``"integrated"`` (the paper's model),
#: ``"constant_depth"`` (each primitive a fronto-parallel plane at its anchor depth),
#: ``"constant_normal"`` (the least-squares plane of its integrated shape) and
#: ``"planar"`` (those planes with their three parameters optimised in mapping).
PRIMITIVE_MODELS = ("integrated", "constant_depth", "constant_normal", "planar")


def apply_primitive_model(primitives: PrimitiveSet, model: str) -> PrimitiveSet:
    """The shapes of an ablation (:data:`PRIMITIVE_MODELS`): ``"integrated"``
    unchanged; ``"constant_depth"``: each primitive fronto-parallel at its
    anchor depth; ``"constant_normal"`` / ``"planar"``: each primitive the
    least-squares inverse-depth plane of its integrated shape.  Raises
    ``ValueError`` for another name."""
    if model == "integrated":
        return primitives
    if model == "constant_depth":
        return primitives.with_scaled_log_depth(np.repeat(primitives.log_scales, primitives.sizes))
    if model in ("constant_normal", "planar"):
        return primitives.with_planes(primitives.fit_planes())[0]
    raise ValueError(f"unknown primitive model {model!r}; expected one of {PRIMITIVE_MODELS}")


def shape_values(prims: PrimitiveSet, primitive_model: str) -> np.ndarray:
    """``(N, dim)`` shape variables of the primitives: ``(N, 1)`` log-scales, or
    with ``primitive_model == "planar"`` the ``(N, 3)`` inverse-depth planes
    ``(a, b, c)`` of :meth:`PrimitiveSet.fit_planes`."""
    if primitive_model == "planar":
        return prims.fit_planes()
    return prims.log_scales.reshape(-1, 1)


def from_shape_values(prims: PrimitiveSet, thetas: np.ndarray,
                      primitive_model: str) -> PrimitiveSet:
    """The primitives with the shape variables ``thetas`` (as :func:`shape_values`
    returns them)."""
    if primitive_model == "planar":
        return prims.with_planes(thetas)[0]
    return prims.with_log_scales(np.asarray(thetas)[:, 0])
