"""Pose-only photometric tracking of a frame against a keyframe's primitives.

The VO front-end (DESIGN.md §5) aligns every new frame to the latest keyframe
with the keyframe's primitive scales held fixed.  The cost minimised here is
*exactly* the one of the factor graph (DESIGN.md §4): for every primitive
``i`` of the keyframe the :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor`
of the pair (keyframe, frame) contributes ``0.5 |e_i|^2`` with

    e_ik = w_ik r_ik,   r_ik = exp(-a) I_t(pi(T_tgt_kf X_ik)) + b - I_kf(u_ik),
    w_ik = rho(r_ik) / sqrt(|Omega_i, valid|)

(Huber IRLS weight ``rho``, per-primitive mean over the pixels valid in the
target, constant penalty rows for points behind the frame's camera), built at
each pyramid level exactly as :func:`spgeo.sfm._build_graph` builds it: level
``l`` uses the primitive pixels on the ``2^l`` lattice, keyframe intensities
from level ``l`` of the keyframe's pyramid, and the frame's level-``l`` image
and camera; primitives with fewer than ``min_level_pixels`` pixels at a level
are left out.  Optionally a prior ``0.5 |(a, b) / sigma|^2`` on the brightness
(the graph's :func:`spgeo.factors.priors.brightness_prior`) is added.

Instead of one gtsam factor per primitive, all primitives' pixels are
concatenated into one batch; residuals and the 8 columns of the Jacobian
(6 frame-pose + 2 brightness) are computed once per iteration with the
factor's own formulas (same bilinear sampler, same robust weights; the
per-primitive normalisation uses ``np.bincount`` over primitive ids), and the
8x8 normal equations are solved with Levenberg-Marquardt damping; a step is
taken only if the cost decreases.  The pose update is gtsam's retraction
``T_world_frame <- T_world_frame Exp(xi)``, ``xi = (omega, v)``.
``tests/test_tracking.py`` checks cost and gradient against the factors.

Pixel subsampling (``TrackerConfig.subsample``) keeps every ``s``-th lattice
pixel along each axis at a level; it is a speed option that changes the cost
(the per-primitive means are then taken over fewer pixels) and is off at the
finest level by default.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

import gtsam

from .camera import PinholeCamera
from .factors.photometric import PhotometricConfig, _sample_with_gradient, robust_weights
from .geometry import check_pose, invert_pose
from .images import Pyramid, gaussian_pyramid, to_float_image, to_gray
from .primitives import PrimitiveSet

__all__ = ["TrackerConfig", "Keyframe", "TrackResult", "track_frame",
           "constant_velocity_guess", "TrackingCost"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackerConfig:
    """Options of :func:`track_frame`.

    Attributes:
        levels: pyramid levels used, coarse-to-fine (default 3: 160x120 ->
            40x30 coarsest).  Limited by the keyframe's pyramid.
        iterations: maximum LM iterations per level, coarsest first (the last
            value repeats for further levels); default ``(20, 12, 8)``.
        photometric: per-pixel cost options, identical to the factors'
            (:class:`PhotometricConfig`; default Huber 0.04, per-primitive
            mean over valid pixels, behind-camera penalty 0.5).
        brightness: estimate the frame's affine brightness ``(a, b)``
            (``exp(-a) I_frame + b`` is compared with the keyframe).
        brightness_prior_sigma: sigmas of the prior pulling ``(a, b)`` to
            ``(0, 0)``, as :func:`spgeo.factors.priors.brightness_prior`;
            None: no prior.  Default ``(0.3, 0.3)`` (the SfM graph's).
        lm_lambda_initial: initial LM damping (multiplies ``diag(H)``).
        lm_lambda_factor: damping multiplier on a rejected step / divisor
            on an accepted one.
        lm_lambda_max: a level stops when the damping exceeds this (no step
            decreases the cost any more).
        relative_cost_tol: a level stops when an accepted step decreases the
            cost by less than this fraction.
        rotation_tol: a level stops when the rotation step is below this
            (radians) and the translation step below ``translation_tol``.
        translation_tol: translation step threshold as a fraction of the
            keyframe's median depth.
        min_level_pixels: primitives with fewer pixels at a level are left
            out of that level (as :class:`spgeo.sfm.SfMConfig`; default 4).
        subsample: extra pixel stride per level (level 0 first; the last
            value repeats): at level ``l`` only pixels on the
            ``2^l * subsample[l]`` lattice are used.  Default ``(1,)``: the
            exact factor-graph cost at every level.
        min_valid_fraction: status ``"lost"`` when fewer keyframe primitive
            pixels (all of them, full resolution) project inside the frame at
            the final pose (default 0.3).
        max_relative_cost: status ``"lost"`` when the final photometric cost
            exceeds this fraction of the cost of a featureless frame (every
            residual ``mean(I_kf) - I_kf``, all pixels valid): default 0.5
            (well-tracked synthetic frames: ~0.01-0.05; a different scene or
            a blank frame: ~0.8-2).
        max_cost_increase: with ``reference_cost`` given to
            :func:`track_frame` (e.g. the previous frame's final cost against
            the same keyframe), status ``"lost"`` when the final cost exceeds
            ``max_cost_increase * reference_cost`` (default 10).
    """

    levels: int = 3
    iterations: Tuple[int, ...] = (20, 12, 8)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    brightness: bool = True
    brightness_prior_sigma: Optional[Tuple[float, float]] = (0.3, 0.3)
    lm_lambda_initial: float = 1e-4
    lm_lambda_factor: float = 10.0
    lm_lambda_max: float = 1e5
    relative_cost_tol: float = 1e-5
    rotation_tol: float = 1e-6
    translation_tol: float = 1e-6
    min_level_pixels: int = 4
    subsample: Tuple[int, ...] = (1,)
    min_valid_fraction: float = 0.3
    max_relative_cost: float = 0.5
    max_cost_increase: float = 10.0

    def __post_init__(self) -> None:
        if self.levels < 1:
            raise ValueError(f"TrackerConfig.levels must be >= 1, got {self.levels}")
        if not self.iterations or any(int(i) < 0 for i in self.iterations):
            raise ValueError("TrackerConfig.iterations must be a non-empty tuple of counts >= 0")
        if not self.subsample or any(int(s) < 1 for s in self.subsample):
            raise ValueError("TrackerConfig.subsample must be a non-empty tuple of strides >= 1")
        if self.brightness_prior_sigma is not None and (
                len(self.brightness_prior_sigma) != 2
                or not all(s > 0 for s in self.brightness_prior_sigma)):
            raise ValueError("TrackerConfig.brightness_prior_sigma must be None or two sigmas > 0")
        if not (self.lm_lambda_initial > 0 and self.lm_lambda_factor > 1 and self.lm_lambda_max > 0):
            raise ValueError("TrackerConfig: LM damping parameters must be positive "
                             "(lambda_factor > 1)")
        if not 0 <= self.min_valid_fraction <= 1:
            raise ValueError("TrackerConfig.min_valid_fraction must be in [0, 1]")
        if not self.max_relative_cost > 0 or not self.max_cost_increase > 0:
            raise ValueError("TrackerConfig.max_relative_cost and max_cost_increase must be > 0")


# ====================================================================== keyframe
def _prepare_grey(image: np.ndarray, shape: Tuple[int, int], work_shape: Tuple[int, int],
                  name: str) -> np.ndarray:
    """float32 grey image at the primitives' resolution (as :mod:`spgeo.sfm` does)."""
    image = np.asarray(image)
    if image.ndim not in (2, 3) or image.shape[:2] != tuple(shape):
        raise ValueError(f"{name} has shape {image.shape}, expected {tuple(shape)}[+channels]")
    grey = to_gray(to_float_image(image))
    if grey.shape != tuple(work_shape):
        grey = cv2.resize(grey, (work_shape[1], work_shape[0]), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(grey, dtype=np.float32)


@dataclass
class _LevelData:
    """The batched pixels of one (level, subsample) pair."""

    level: int
    entries: np.ndarray        # (K,) indices into the PrimitiveSet's entries
    points: np.ndarray         # (K, 3) keyframe-frame points
    ref_intensity: np.ndarray  # (K,) float64 keyframe intensities at the level
    ids: np.ndarray            # (K,) compact primitive id 0..P-1
    prim_index: np.ndarray     # (P,) original primitive index of each compact id
    n_pixels: np.ndarray       # (P,) pixels per primitive at the level

    @property
    def n_primitives(self) -> int:
        return int(self.prim_index.size)


@dataclass
class Keyframe:
    """A keyframe as the tracker sees it.

    Attributes:
        primitives: the keyframe's :class:`PrimitiveSet` with its (fixed)
            log-scales; its camera is the working resolution.
        pyramid: grey float32 pyramid of the keyframe image at that resolution.
        T_world_kf: 4x4 camera-to-world pose of the keyframe.
        input_shape: ``(H, W)`` of the images given to :meth:`build`; frames
            passed to :func:`track_frame` must have it too (they are resized
            to the primitives' resolution the same way).
        points: (M, 3) keyframe-frame points of all primitive entries.
        median_depth: median depth of those points.
    """

    primitives: PrimitiveSet
    pyramid: Pyramid
    T_world_kf: np.ndarray
    input_shape: Tuple[int, int]
    points: np.ndarray
    median_depth: float
    _cache: Dict[Tuple[int, int, int], _LevelData] = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, image: np.ndarray, primitives: PrimitiveSet, T_world_kf: np.ndarray,
              levels: int = 3) -> "Keyframe":
        """Keyframe from its image (H, W[, 3]; uint8 or float [0, 1]), primitives
        and pose.  An image of another size than the primitives' camera is
        resized to it (``INTER_AREA``)."""
        if len(primitives) == 0:
            raise ValueError("Keyframe.build: the primitive set is empty")
        T = check_pose(np.asarray(T_world_kf, dtype=np.float64), "T_world_kf")
        cam = primitives.camera
        image = np.asarray(image)
        if image.ndim not in (2, 3):
            raise ValueError(f"Keyframe.build: image must be (H, W[, C]), got {image.shape}")
        grey = _prepare_grey(image, image.shape[:2], cam.shape, "keyframe image")
        pyr = gaussian_pyramid(grey, cam, int(levels))
        rays = cam.rays().reshape(-1, 3)[primitives.pixels]
        X = rays * np.exp(primitives.scaled_log_depth())[:, None]
        return cls(primitives, pyr, T.copy(), tuple(image.shape[:2]), X,
                   float(np.median(X[:, 2])))

    @property
    def camera(self) -> PinholeCamera:
        return self.primitives.camera

    def level_data(self, level: int, subsample: int = 1,
                   min_level_pixels: int = 4) -> _LevelData:
        """Batched pixels at ``level`` (lattice ``2^level * subsample``), cached."""
        key = (int(level), int(subsample), int(min_level_pixels))
        if key in self._cache:
            return self._cache[key]
        prims = self.primitives
        w = prims.camera.width
        stride = 2 ** int(level)
        lattice = stride * int(subsample)
        on = ((prims.pixels % w) % lattice == 0) & ((prims.pixels // w) % lattice == 0)
        ids_all = prims.primitive_ids
        counts = np.bincount(ids_all[on], minlength=len(prims))
        keep_prim = counts >= max(int(min_level_pixels), 1)
        entries = np.flatnonzero(on & keep_prim[ids_all])
        prim_index = np.flatnonzero(keep_prim)
        compact = np.full(len(prims), -1, dtype=np.int64)
        compact[prim_index] = np.arange(prim_index.size)
        ids = compact[ids_all[entries]]
        pix = prims.pixels[entries]
        img = self.pyramid.images[level]
        # ScaledShape: X = rays * exp(log_depth + s) (same expression as the factor)
        rays = prims.camera.rays().reshape(-1, 3)[pix]
        s = prims.log_scales[ids_all[entries]]
        X = rays * np.exp(prims.log_depth[entries] + s)[:, None]
        ref = img[(pix // w) // stride, (pix % w) // stride].astype(np.float64)
        n_pix = np.bincount(ids, minlength=prim_index.size).astype(np.float64)
        data = _LevelData(int(level), entries, X, ref, ids, prim_index, n_pix)
        self._cache[key] = data
        return data
