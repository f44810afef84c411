"""Depth metrics of the evaluation protocols (metres in, the units stated per key out).

:func:`depth_metrics` and :func:`primitive_fit_errors` live in the core,
:mod:`spgeo.metrics.depth` (the demo reports them too); they are re-exported here.
"""
from spgeo.metrics.depth import depth_metrics, primitive_fit_errors

__all__ = ["depth_metrics", "primitive_fit_errors"]
