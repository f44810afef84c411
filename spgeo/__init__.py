"""spgeo: dense monocular 3-D reconstruction with SuperPrimitives.

Stable entry points:

* :class:`spgeo.PinholeCamera` (``fx, fy, cx, cy, width, height``)
* :func:`spgeo.integrate_normals` ``(normals, masks, camera) -> log-depth``
* :class:`spgeo.PrimitiveSet`, :class:`spgeo.SuperPrimitive`
* front-ends in :mod:`spgeo.frontend`, synthetic scenes in :mod:`spgeo.synthetic`,
  data-set readers in :mod:`spgeo.datasets`.
"""
import logging

from .camera import PinholeCamera
from .frame import Frame
from .integration import IntegrationConfig, integrate_normals, integrate_normals_regions
from .primitives import PointCloud, PrimitiveSet, SuperPrimitive

__version__ = "0.1.0"

__all__ = [
    "PinholeCamera", "Frame", "IntegrationConfig", "integrate_normals",
    "integrate_normals_regions", "PointCloud", "PrimitiveSet", "SuperPrimitive", "__version__",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
