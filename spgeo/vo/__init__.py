"""Keyframe-based monocular visual odometry on SuperPrimitives.

:class:`Odometry` (the per-frame state machine, :mod:`spgeo.vo.odometry`; what a caller
reads of a run, :mod:`spgeo.vo.readout`) and its options (:mod:`spgeo.vo.config`) drive:

* tracking: :mod:`spgeo.vo.frame_tracker`, :mod:`spgeo.vo.tracking`,
  :mod:`spgeo.vo.motion`, :mod:`spgeo.vo.initialisation`;
* keyframes and the map: :mod:`spgeo.vo.keyframe_policy`, :mod:`spgeo.vo.keyframe_builder`,
  :mod:`spgeo.vo.rendering`, :mod:`spgeo.vo.map`;
* mapping, behind one port (:mod:`spgeo.vo.mapping_port`): the back end
  (:mod:`spgeo.vo.backend`: landmarks, loop closure, the fixed-lag window smoother
  :mod:`spgeo.vo.smoother`; its graph's keys and builders: :mod:`spgeo.graph`), in this
  process or in the worker (:mod:`spgeo.vo.mapping_worker`);
* results: :mod:`spgeo.vo.result`.
"""
from ..primitive_models import PRIMITIVE_MODELS
from .config import (InitConfig, KeyframeDecisionConfig, MappingConfig, OdometryConfig,
                     ScaleCheckConfig, TrackerConfig)
from .odometry import Odometry
from .rendering import ScaleInit, init_scales_from_render, render_depth, render_primitives
from .result import STATUSES, FrameResult, FrameStatus, OdometryResult
from .tracking import Keyframe, TrackingCost, TrackResult, constant_velocity_guess, track_frame

__all__ = ["Odometry", "OdometryConfig", "TrackerConfig", "KeyframeDecisionConfig",
           "ScaleCheckConfig", "InitConfig", "MappingConfig", "PRIMITIVE_MODELS", "FrameResult",
           "FrameStatus", "OdometryResult", "STATUSES", "Keyframe",
           "TrackResult", "TrackingCost", "track_frame", "constant_velocity_guess",
           "render_depth", "render_primitives", "init_scales_from_render", "ScaleInit"]
