"""Prior factors of the SuperPrimitive graphs (thin, documented wrappers of
GTSAM's prior factors so every graph uses the same conventions).

* :func:`log_scale_prior` -- pulls a primitive's log-scale to a value; the paper
  uses weight 1e-5 (sigma = 1/sqrt(weight)): it fixes the global scale gauge of
  monocular problems without biasing well-observed scales.
* :func:`pose_gauge_prior` -- pins a Pose3 (the reference keyframe).
* :func:`planar_slope_prior` -- pulls a planar primitive's slopes ``(a, b)``
  towards fronto-parallel, leaving its inverse depth ``c`` nearly free.
* :func:`brightness_prior` -- keeps an affine brightness ``(a, b)`` near 0.
* :func:`mean_log_scale_prior` -- pulls a weighted mean of several log-scales
  (one keyframe's primitives) to a value: a scale prior on the keyframe as a
  whole that leaves the primitives' relative scales free.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

import gtsam

__all__ = ["LOG_SCALE_PRIOR_WEIGHT", "log_scale_prior", "pose_gauge_prior",
           "planar_slope_prior", "brightness_prior", "mean_log_scale_prior", "LogScalePrior"]

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


def mean_log_scale_prior(keys: Sequence[int], weights: Sequence[float], target: float,
                         sigma: float) -> gtsam.CustomFactor:
    """Prior ``(sum_i w_i s_i - target) / sigma`` on 1-vector log-scale variables.

    Args:
        keys: the log-scale variables' keys (1-vectors), at least one.
        weights: one weight per key, finite and >= 0, summing to 1 (e.g. the
            primitives' shares of the pixels the target was measured on).
        target: the weighted mean log-scale the variables are pulled to.
        sigma: standard deviation of that mean, in log units (> 0).

    The error is linear in the variables: its Jacobian with respect to
    ``s_i`` is ``w_i`` (1x1).  Raises ``ValueError`` on mismatched lengths,
    negative / non-finite weights, weights not summing to 1, or ``sigma <= 0``.
    """
    keys = [int(k) for k in keys]
    w = np.asarray(weights, dtype=float).reshape(-1)
    if not keys or w.size != len(keys):
        raise ValueError(f"mean_log_scale_prior: {len(keys)} keys and {w.size} weights")
    if not (np.all(np.isfinite(w)) and np.all(w >= 0) and abs(w.sum() - 1.0) < 1e-9):
        raise ValueError("mean_log_scale_prior: weights must be finite, >= 0 and sum to 1")
    if not (sigma > 0 and np.isfinite(target)):
        raise ValueError(f"mean_log_scale_prior: sigma must be > 0 and target finite, got "
                         f"sigma={sigma}, target={target}")
    blocks = [np.array([[wi]]) for wi in w]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        mean = sum(wi * float(values.atVector(k)[0]) for wi, k in zip(w, keys))
        if jacobians is not None:
            for j, block in enumerate(blocks):
                jacobians[j] = block
        return np.array([mean - float(target)])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, float(sigma)), keys, error)
