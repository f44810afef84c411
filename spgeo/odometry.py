"""Compatibility alias of :mod:`spgeo.vo` (the monocular VO moved there)."""
from .vo import (PRIMITIVE_MODELS, STATUSES, FrameResult, Odometry, OdometryConfig,  # noqa: F401
                 OdometryResult, TrackerConfig, apply_primitive_model, kf_brightness_key,
                 kf_pose_key, kf_scale_key, support_pose_key)

__all__ = ["Odometry", "OdometryConfig", "TrackerConfig", "FrameResult", "OdometryResult",
           "STATUSES", "PRIMITIVE_MODELS", "kf_pose_key", "kf_scale_key", "kf_brightness_key",
           "support_pose_key", "apply_primitive_model"]
