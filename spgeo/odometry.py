"""Compatibility alias of :mod:`spgeo.vo` (the monocular VO moved there)."""
from .vo import (PRIMITIVE_MODELS, STATUSES, FrameResult, Odometry, OdometryConfig,  # noqa: F401
                 OdometryResult, TrackerConfig)

__all__ = ["Odometry", "OdometryConfig", "TrackerConfig", "FrameResult", "OdometryResult",
           "STATUSES", "PRIMITIVE_MODELS"]
