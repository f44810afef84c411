"""Prior factors of the SuperPrimitive graphs (thin, documented wrappers of
GTSAM's prior factors so every graph uses the same conventions).

* :func:`log_scale_prior` -- pulls a primitive's log-scale to a value; the paper
  uses weight 1e-5 (sigma = 1/sqrt(weight)): it fixes the global scale gauge of
  monocular problems without biasing well-observed scales.
* :func:`pose_gauge_prior` -- pins a Pose3 (the reference keyframe).
* :func:`planar_slope_prior` -- pulls a planar primitive's slopes ``(a, b)``
  towards fronto-parallel, leaving its inverse depth ``c`` nearly free.
* :func:`brightness_prior` -- keeps an affine brightness ``(a, b)`` near 0.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

import gtsam

__all__ = ["LOG_SCALE_PRIOR_WEIGHT", "log_scale_prior", "pose_gauge_prior",
           "planar_slope_prior", "brightness_prior", "LogScalePrior"]

LOG_SCALE_PRIOR_WEIGHT = 1e-5
"""The paper's weight of the scale prior in few-view SfM."""


def log_scale_prior(key: int, log_scale: float = 0.0,
                    weight: float = LOG_SCALE_PRIOR_WEIGHT) -> gtsam.PriorFactorVector:
    """Prior ``weight * (s - log_scale)^2`` on a 1-vector log-scale variable."""
    if not weight > 0:
        raise ValueError(f"log_scale_prior: weight must be > 0, got {weight}")
    return gtsam.PriorFactorVector(key, np.array([float(log_scale)]),
                                   gtsam.noiseModel.Isotropic.Sigma(1, 1.0 / np.sqrt(weight)))


LogScalePrior = log_scale_prior  # the name used in the design notes


def pose_gauge_prior(key: int, T_world_cam: np.ndarray = None,
                     sigma: float = 1e-6) -> gtsam.PriorFactorPose3:
    """Tight prior fixing a Pose3 (camera-to-world; identity by default)."""
    pose = gtsam.Pose3() if T_world_cam is None else gtsam.Pose3(np.asarray(T_world_cam, float))
    return gtsam.PriorFactorPose3(key, pose, gtsam.noiseModel.Isotropic.Sigma(6, sigma))


def planar_slope_prior(key: int, inverse_depth: float, slope_sigma: float = 2.0,
                       inverse_depth_sigma: float = 1.0 / np.sqrt(LOG_SCALE_PRIOR_WEIGHT),
                       slope: Sequence[float] = (0.0, 0.0)) -> gtsam.PriorFactorVector:
    """Prior on a plane ``1/z = a x + b y + c`` towards ``(a0, b0, inverse_depth)``,
    ``(a0, b0) = slope`` (default fronto-parallel; a front-end's normal gives
    another: :meth:`spgeo.primitives.PrimitiveSet.fit_planes`)."""
    a0, b0 = (float(v) for v in slope)
    return gtsam.PriorFactorVector(key, np.array([a0, b0, float(inverse_depth)]),
                                   gtsam.noiseModel.Diagonal.Sigmas(
                                       np.array([slope_sigma, slope_sigma, inverse_depth_sigma])))


def brightness_prior(key: int, sigmas: Sequence[float] = (0.3, 0.3)) -> gtsam.PriorFactorVector:
    """Prior keeping an affine brightness ``(a, b)`` near ``(0, 0)``."""
    return gtsam.PriorFactorVector(key, np.zeros(2),
                                   gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float)))
