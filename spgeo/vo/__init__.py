"""Keyframe-based monocular visual odometry on SuperPrimitives.

:class:`Odometry` (the per-frame state machine, :mod:`spgeo.vo.odometry`;
its map initialisation, :mod:`spgeo.vo.initialisation`; its keyframe map,
:mod:`spgeo.vo.map`; its motion model, :mod:`spgeo.vo.motion`), its options
(:mod:`spgeo.vo.config`), frame-to-keyframe tracking (:mod:`spgeo.vo.tracking`), rendering of primitives into new keyframes
(:mod:`spgeo.vo.rendering`), the fixed-lag window smoother
(:mod:`spgeo.vo.smoother`; its keyframes: :mod:`spgeo.vo.map`; its graph's keys
and builders: :mod:`spgeo.graph`) and the results (:mod:`spgeo.vo.result`).
"""
from ..primitive_models import PRIMITIVE_MODELS
from .config import InitConfig, KeyframeDecisionConfig, OdometryConfig, ScaleCheckConfig, TrackerConfig
from .odometry import Odometry
from .rendering import ScaleInit, init_scales_from_render, render_depth, render_primitives
from .result import STATUSES, FrameResult, FrameStatus, OdometryResult
from .tracking import Keyframe, TrackingCost, TrackResult, constant_velocity_guess, track_frame

__all__ = ["Odometry", "OdometryConfig", "TrackerConfig", "KeyframeDecisionConfig",
           "ScaleCheckConfig", "InitConfig", "PRIMITIVE_MODELS", "FrameResult",
           "FrameStatus", "OdometryResult", "STATUSES", "Keyframe",
           "TrackResult", "TrackingCost", "track_frame", "constant_velocity_guess",
           "render_depth", "render_primitives", "init_scales_from_render", "ScaleInit"]
