"""Pose-only photometric tracking of a frame against a keyframe's primitives.

Longer than 500 lines because its one job's parts (the keyframe's batched
pixels, the tracking cost with its Jacobian, the LM loop) share private per-level data.

The VO front-end (docs/design.md §5) aligns every new frame to the latest keyframe
with the keyframe's primitive scales held fixed.  The cost minimised here is
*exactly* the one of the factor graph (docs/design.md §4): for every primitive
``i`` of the keyframe the :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor`
of the pair (keyframe, frame) contributes ``0.5 |e_i|^2`` with

    e_ik = w_ik r_ik,   r_ik = exp(-a) I_t(pi(T_tgt_kf X_ik)) + b - I_kf(u_ik),
    w_ik = rho(r_ik) / sqrt(|Omega_i, valid|)

(Huber IRLS weight ``rho``, per-primitive mean over the pixels valid in the
target, constant penalty rows for points behind the frame's camera), built at
each pyramid level exactly as :func:`spgeo.sfm_graph.build_graph` builds it: level
``l`` uses the primitive pixels on the ``2^l`` lattice, keyframe intensities
from level ``l`` of the keyframe's pyramid, and the frame's level-``l`` image
and camera; primitives with fewer than ``min_level_pixels`` pixels at a level
are left out.  Optionally a prior ``0.5 |(a, b) / sigma|^2`` on the brightness
(the graph's :func:`spgeo.factors.priors.brightness_prior`) is added.

Instead of one gtsam factor per primitive, all primitives' pixels are
concatenated into one batch; residuals and the 8 columns of the Jacobian
(6 frame-pose + 2 brightness) are computed once per iteration with the
factor's own formulas (its bilinear sampler inlined, the same robust weights; the
per-primitive normalisation uses ``np.bincount`` over primitive ids), and the
8x8 normal equations are solved with Levenberg-Marquardt damping; a step is
taken only if the cost decreases.  The pose update is gtsam's retraction
``T_world_frame <- T_world_frame Exp(xi)``, ``xi = (omega, v)``.
``tests/test_tracking.py`` checks cost and gradient against the factors.

Pixel subsampling (``TrackerConfig.subsample``) keeps every ``s``-th lattice
pixel along each axis at a level; it is a speed option that changes the cost
(the per-primitive means are then taken over fewer pixels) and is off at the
finest level by default.

Pixel selection (``Keyframe.selection``, a
:class:`~spgeo.vo.pixels.PixelSelectionConfig`) keeps, at each level, a budget
of well-spread high-gradient pixels of the lattice (:func:`spgeo.vo.pixels.select_pixels`)
instead of all of them; the primitives keep their dense shape.  The mapping
factors take their pixels from the same :meth:`Keyframe.level_data`, so tracker
and factors keep computing one cost on the same pixels.

Decisions (``TrackResult.relative_cost`` and ``valid_fraction``, which the
failure test and the VO's keyframe test compare with thresholds) are taken on
*decision pixels* that do not depend on the pixels optimised on: every
primitive pixel of the finest level on a lattice of stride
``round(width / TrackerConfig.decision_width)``.  When the finest level was
optimised on fewer pixels (a selection), ``TrackerConfig.decision_iterations``
LM steps on the decision pixels refine the pose first; otherwise (all pixels)
the decision pixels are evaluated once, or, when they are the finest level's
own pixels (160x120 without selection), its evaluation is reused.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors import kernels
from ..factors.photometric import residual_pass, robust_weights
from ..geometry import check_pose, invert_pose
from ..images import Pyramid, gaussian_pyramid, to_float_image, to_gray
from ..primitives import PrimitiveSet
from .config import TrackerConfig
from .pixels import PixelSelectionConfig, gradient_magnitude, select_pixels

__all__ = ["TrackerConfig", "Keyframe", "TrackResult", "track_frame",
           "constant_velocity_guess", "TrackingCost"]

log = logging.getLogger(__name__)


# ====================================================================== keyframe
def _prepare_grey(image: np.ndarray, shape: Tuple[int, int], work_shape: Tuple[int, int],
                  name: str) -> np.ndarray:
    """float32 grey image at the primitives' resolution (as :mod:`spgeo.sfm` does)."""
    image = np.asarray(image)
    if image.ndim not in (2, 3) or image.shape[:2] != tuple(shape):
        raise ValueError(f"{name} has shape {image.shape}, expected {tuple(shape)}[+channels]")
    grey = to_gray(to_float_image(image))   # raises on NaN / inf / bad range
    if grey.shape != tuple(work_shape):
        grey = cv2.resize(grey, (work_shape[1], work_shape[0]), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(grey, dtype=np.float32)


@dataclass
class _LevelData:
    """The batched pixels of one (level, subsample) pair."""

    level: int
    entries: np.ndarray        # (K,) indices into the PrimitiveSet's entries
    points_t: np.ndarray       # (3, K) keyframe-frame points (transposed)
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
        selection: pixel selection of :meth:`level_data` (None: every
            lattice pixel).
    """

    primitives: PrimitiveSet
    pyramid: Pyramid
    T_world_kf: np.ndarray
    input_shape: Tuple[int, int]
    points: np.ndarray
    median_depth: float
    selection: Optional[PixelSelectionConfig] = None
    _cache: Dict[tuple, _LevelData] = field(default_factory=dict, repr=False)
    # selected entries per (level, lattice, selection): they depend on the image and masks only
    _selected: Dict[tuple, np.ndarray] = field(default_factory=dict, repr=False)
    # indices of the entries on each pixel lattice (they depend on the pixels only)
    _lattice: Dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _lattice_points: Dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, image: np.ndarray, primitives: PrimitiveSet, T_world_kf: np.ndarray,
              levels: int = 3, selection: Optional[PixelSelectionConfig] = None) -> "Keyframe":
        """Keyframe from its image (H, W[, 3]; uint8 or float [0, 1]), primitives
        and pose.  An image of another size than the primitives' camera is
        resized to it (``INTER_AREA``).  ``selection``: see :meth:`level_data`."""
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
                   float(np.median(X[:, 2])), selection)

    def rebuilt(self, primitives: PrimitiveSet, T_world_kf: np.ndarray) -> "Keyframe":
        """The keyframe with new shapes / scales and pose: same image, and
        the same primitive pixels (``primitives.pixels`` and ``offsets`` equal
        to the current ones), so its pyramid and pixel selection are reused.
        Raises ValueError when the pixels differ."""
        old = self.primitives
        if not (np.array_equal(primitives.pixels, old.pixels)
                and np.array_equal(primitives.offsets, old.offsets)):
            raise ValueError("Keyframe.rebuilt: the primitives' pixels changed")
        T = check_pose(np.asarray(T_world_kf, dtype=np.float64), "T_world_kf")
        rays = primitives.camera.rays().reshape(-1, 3)[primitives.pixels]
        X = rays * np.exp(primitives.scaled_log_depth())[:, None]
        return Keyframe(primitives, self.pyramid, T.copy(), self.input_shape, X,
                        float(np.median(X[:, 2])), self.selection, _selected=self._selected,
                        _lattice=self._lattice)

    @property
    def camera(self) -> PinholeCamera:
        return self.primitives.camera

    def lattice_entries(self, stride: int) -> np.ndarray:
        """Indices of the primitive entries on the pixel lattice of ``stride``
        (cached)."""
        stride = int(stride)
        if stride not in self._lattice:
            w = self.primitives.camera.width
            pix = self.primitives.pixels
            self._lattice[stride] = np.flatnonzero(((pix % w) % stride == 0)
                                                   & ((pix // w) % stride == 0))
        return self._lattice[stride]

    def lattice_points(self, stride: int) -> np.ndarray:
        """(3, K) keyframe-frame points of :meth:`lattice_entries` (cached)."""
        stride = int(stride)
        if stride not in self._lattice_points:
            P = self.points if stride == 1 else self.points[self.lattice_entries(stride)]
            self._lattice_points[stride] = np.ascontiguousarray(P.T)
        return self._lattice_points[stride]

    def _select(self, level: int, lattice: int, on: np.ndarray,
                selection: PixelSelectionConfig) -> np.ndarray:
        """Mask (over all entries) of the selected lattice entries at ``level``."""
        key = (int(level), int(lattice), selection)
        if key not in self._selected:
            prims = self.primitives
            w = prims.camera.width
            stride = 2 ** int(level)
            cand = np.flatnonzero(on)
            pix = prims.pixels[cand]
            img = self.pyramid.images[level]
            sel = select_pixels(img, (pix // w) // stride, (pix % w) // stride,
                                prims.primitive_ids[cand], selection, len(prims),
                                magnitude=gradient_magnitude(img))
            self._selected[key] = cand[sel.indices]
            log.debug("keyframe level %d: %d of %d pixels selected, %d primitives without",
                      level, sel.indices.size, cand.size, sel.empty.size)
        mask = np.zeros(on.size, dtype=bool)
        mask[self._selected[key]] = True
        return mask

    def level_data(self, level: int, subsample: int = 1, min_level_pixels: int = 4,
                   selection: Union[PixelSelectionConfig, None, str] = "keyframe"
                   ) -> _LevelData:
        """Batched pixels at ``level`` (lattice ``2^level * subsample``), cached.

        With a pixel selection (``selection``; ``"keyframe"``: :attr:`selection`)
        only the lattice pixels chosen by :func:`~spgeo.vo.pixels.select_pixels`
        on the level's image (at level 0 always, above it when
        ``selection.coarse_levels == "select"``); the per-primitive means are
        taken over them.  Primitives with fewer than ``min_level_pixels``
        pixels are left out."""
        if isinstance(selection, str):
            if selection != "keyframe":
                raise ValueError("level_data: selection must be a config, None or 'keyframe'")
            selection = self.selection
        key = (int(level), int(subsample), int(min_level_pixels), selection)
        if key in self._cache:
            return self._cache[key]
        prims = self.primitives
        w = prims.camera.width
        stride = 2 ** int(level)
        lattice = stride * int(subsample)
        on = ((prims.pixels % w) % lattice == 0) & ((prims.pixels // w) % lattice == 0)
        if selection is not None and (level == 0 or selection.coarse_levels == "select"):
            on = self._select(level, lattice, on, selection)
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
        data = _LevelData(int(level), entries, np.ascontiguousarray(X.T), ref, ids, prim_index, n_pix)
        self._cache[key] = data
        return data

    def frame_pyramid(self, image: np.ndarray, levels: Optional[int] = None) -> Pyramid:
        """Grey pyramid of a frame, prepared exactly as the keyframe's."""
        grey = _prepare_grey(image, self.input_shape, self.camera.shape, "frame image")
        n = len(self.pyramid) if levels is None else min(int(levels), len(self.pyramid))
        return gaussian_pyramid(grey, self.camera, max(n, 1))


# ====================================================================== cost
class TrackingCost:
    """The batched photometric cost of one pyramid level.

    ``cost = sum_i 0.5 |e_i|^2 (+ 0.5 |(a, b) / sigma|^2)``: the sum of the
    errors of the :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor`
    of every keyframe primitive (built as :func:`spgeo.sfm_graph.build_graph` builds
    them at this level) plus the optional brightness prior.

    Args:
        keyframe: the :class:`Keyframe`.
        image: the frame's grey image at ``level`` (float32, from
            :meth:`Keyframe.frame_pyramid`).
        camera: the camera of ``image``.
        level: pyramid level.
        config: :class:`TrackerConfig` (photometric options, brightness,
            prior, subsampling, ``min_level_pixels``).
        selection: pixel selection (:meth:`Keyframe.level_data`; default the
            keyframe's own).
        subsample: lattice stride on the level (default ``config.subsample``).
    """

    def __init__(self, keyframe: Keyframe, image: np.ndarray, camera: PinholeCamera,
                 level: int, config: TrackerConfig = TrackerConfig(),
                 selection: Union[PixelSelectionConfig, None, str] = "keyframe",
                 subsample: Optional[int] = None) -> None:
        img = np.asarray(image)
        if img.ndim != 2 or img.shape != camera.shape:
            raise ValueError(f"TrackingCost: image must be (H, W) = {camera.shape}, got {img.shape}")
        self.image = img
        self.camera = camera
        self.level = int(level)
        self.config = config
        if subsample is None:
            subsample = config.subsample[min(self.level, len(config.subsample) - 1)]
        self.data = keyframe.level_data(self.level, int(subsample), config.min_level_pixels,
                                        selection)
        self.T_world_kf = keyframe.T_world_kf
        self.dim = 8 if config.brightness else 6
        pc = config.photometric
        self._pen_row = float(robust_weights(np.array([pc.behind_penalty]), pc)[0]
                              * pc.behind_penalty)
        if config.brightness and config.brightness_prior_sigma is not None:
            self._prior_info = 1.0 / np.asarray(config.brightness_prior_sigma, float) ** 2
        else:
            self._prior_info = None

    @property
    def n_pixels(self) -> int:
        return int(self.data.entries.size)

    def _scale(self, counted: Optional[np.ndarray]) -> np.ndarray:
        """Per-pixel normalisation ``1/sqrt(n)`` (or ``1/pixel_sigma``)."""
        pc = self.config.photometric
        d = self.data
        if pc.normalise == "valid":
            cnt = np.bincount(d.ids, weights=counted, minlength=d.n_primitives)
            return (1.0 / np.sqrt(np.maximum(cnt, 1.0)))[d.ids]
        if pc.normalise == "none":
            return np.full(d.ids.size, 1.0 / pc.pixel_sigma)
        return (1.0 / np.sqrt(d.n_pixels))[d.ids]

    def featureless_cost(self, out: Optional[dict] = None) -> float:
        """Photometric cost of a featureless frame: every residual is
        ``mean(I_kf) - I_kf``.  With ``out`` (a dict from :meth:`evaluate`)
        the same pixels are valid / behind as there (the yardstick of
        :attr:`TrackerConfig.max_relative_cost`: primitives that left the
        image cost nothing in either); otherwise every pixel is valid."""
        d = self.data
        if d.entries.size == 0:
            return 0.0
        r = float(np.mean(d.ref_intensity)) - d.ref_intensity
        if out is None:
            valid = np.ones(r.size, dtype=bool)
            behind = ~valid
        else:
            valid, behind = out["valid"], out["behind"]
        scale = self._scale(valid | behind)
        e = scale * robust_weights(r, self.config.photometric) * r * valid
        if behind.any():
            e = np.where(behind, scale * self._pen_row, e)
        return 0.5 * float(np.einsum("i,i->", e, e))   # einsum: no BLAS threads for a dot

    def evaluate(self, T_world_frame: np.ndarray, brightness: Sequence[float] = (0.0, 0.0),
                 jacobians: bool = True) -> dict:
        """Residuals and (optionally) Jacobians at a frame pose / brightness.

        Returns a dict with ``e`` (K,) residual rows (the factors' rows,
        concatenated), ``r`` photometric errors (0 where invalid), ``valid``,
        ``behind``, ``ids`` (compact primitive id per row), ``photometric_cost``,
        ``prior_cost``, ``cost`` (their sum), ``valid_fraction`` (rows valid in
        the target); with ``jacobians``: ``J`` (K, 6|8) (frame pose in gtsam's
        tangent ``(omega, v)``, then ``(a, b)``), ``H = J^T J (+ prior)`` and
        ``g = J^T e (+ prior)``, the gradient of ``cost`` as the factors'
        linearisation gives it (weights held fixed: IRLS).
        """
        out = self._residuals(T_world_frame, brightness)
        if jacobians:
            self.linearise(out)
        return out

    def _residuals(self, T_world_frame: np.ndarray, brightness: Sequence[float]) -> dict:
        """Residual pass: the factors' compiled kernel
        (:func:`spgeo.factors.photometric.residual_pass`), or with
        ``photometric.backend="numpy"`` the numpy code below (mirrors
        ``PrimitivePhotometricFactor.evaluate``)."""
        pc = self.config.photometric
        d = self.data
        cam = self.camera
        T_wt = np.asarray(T_world_frame, dtype=np.float64)
        T_wr = self.T_world_kf
        R_wt, R_wr = T_wt[:3, :3], T_wr[:3, :3]
        R = R_wt.T @ R_wr                                   # R_frame_kf
        t = R_wt.T @ (T_wr[:3, 3] - T_wt[:3, 3])
        if self.config.brightness:
            a, b = float(brightness[0]), float(brightness[1])
        else:
            a, b = 0.0, 0.0
        ab = np.array([a, b])
        prior = 0.0
        if self._prior_info is not None:
            prior = 0.5 * float(np.dot(self._prior_info * ab, ab))
        if kernels.resolve_backend(pc.backend) == "numba":
            group_pixels = d.n_pixels if pc.normalise == "all" else np.ones(d.n_primitives)
            res = residual_pass(d.points_t.T, None, np.ascontiguousarray(R), t, self.image, cam,
                                d.ref_intensity, a, b, pc, d.ids, group_pixels)
            photo = 0.5 * res["sum_sq"]
            return {"e": res["e"], "r": res["r"], "valid": res["valid"], "behind": res["behind"],
                    "ids": d.ids, "photometric_cost": photo, "prior_cost": prior,
                    "cost": photo + prior,
                    "valid_fraction": res["n_valid"] / max(d.ids.size, 1),
                    "_kernel": (res, ab)}
        Y = R @ d.points_t
        Y += t[:, None]
        Yx, Yy, z = Y[0], Y[1], Y[2]
        behind = z <= pc.min_depth
        valid = ~behind
        any_behind = bool(behind.any())
        if any_behind:
            inv_z = np.where(valid, 1.0 / np.where(valid, z, 1.0), 0.0)
        else:
            inv_z = 1.0 / z
        u = cam.fx * Yx * inv_z + cam.cx
        if any_behind:
            u[behind] = -1.0
        v = cam.fy * Yy * inv_z + cam.cy
        # bilinear sample + exact interpolant derivatives (as the factor's
        # sampler; rows outside are left unzeroed: their weight is 0)
        img = self.image
        h, w = img.shape
        with np.errstate(invalid="ignore"):
            inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        valid &= inside
        all_inside = bool(inside.all())
        uc = u if all_inside else np.where(inside, u, 0.0)
        vc = v if all_inside else np.where(inside, v, 0.0)
        u0 = np.minimum(uc.astype(np.int64), w - 2)
        v0 = np.minimum(vc.astype(np.int64), h - 2)
        au = uc - u0
        av = vc - v0
        i00 = v0 * w
        i00 += u0
        flat = img.reshape(-1)
        p00 = flat[i00]
        p01 = flat[i00 + 1]
        p10 = flat[i00 + w]
        p11 = flat[i00 + (w + 1)]
        d0 = p01 - p00
        d1 = p11 - p10
        top = p00 + d0 * au
        bot = p10 + d1 * au
        I_t = top + (bot - top) * av
        ea = np.exp(-a)
        r = ea * I_t + b - d.ref_intensity
        scale = self._scale(valid | behind)
        w_ = scale * robust_weights(r, pc) * valid
        e = w_ * r
        if any_behind:
            e = np.where(behind, scale * self._pen_row, e)
        photo = 0.5 * float(np.einsum("i,i->", e, e))
        return {"e": e, "r": np.where(valid, r, 0.0), "valid": valid, "behind": behind,
                "ids": d.ids, "photometric_cost": photo, "prior_cost": prior,
                "cost": photo + prior,
                "valid_fraction": float(np.count_nonzero(valid)) / max(valid.size, 1),
                "_lin": (Y, inv_z, w_, ea, I_t, d0, d1, bot - top, av, ab)}

    def linearise(self, out: dict) -> dict:
        """Add ``J``, ``H`` and ``g`` to a dict from :meth:`evaluate`."""
        if "_kernel" in out:
            res, ab = out["_kernel"]
            Jt = np.empty((self.dim, res["e"].size))
            H = np.empty((self.dim, self.dim))
            g = np.empty(self.dim)
            kernels.pose_normal_equations(res["Y"], res["g"], res["weights"], res["I_t"],
                                          res["ea"], res["e"], Jt, H, g)
            J = Jt.T
        else:
            J, H, g, ab = self._linearise_numpy(out)
        if self._prior_info is not None:
            H[6:, 6:] += np.diag(self._prior_info)
            g[6:] += self._prior_info * ab
        out.update(J=J, H=H, g=g)
        return out

    def _linearise_numpy(self, out: dict):
        """``(J, J^T J, J^T e, (a, b))`` of a numpy-backend :meth:`_residuals` dict."""
        Y, inv_z, w_, ea, I_t, d0, d1, gv, av, ab = out["_lin"]
        cam = self.camera
        gu = d0 * (1 - av) + d1 * av
        wg = w_ * ea * inv_z
        du = wg * gu * cam.fx
        dv = wg * gv * cam.fy
        Yx, Yy, Yz = Y[0], Y[1], Y[2]
        dz = -(du * Yx + dv * Yy) * inv_z
        Jt = np.empty((self.dim, du.size))
        # de/dxi_frame = [g x Y, -g]  with g = de/dY = (du, dv, dz)
        Jt[0] = dv * Yz - dz * Yy
        Jt[1] = dz * Yx - du * Yz
        Jt[2] = du * Yy - dv * Yx
        Jt[3] = -du
        Jt[4] = -dv
        Jt[5] = -dz
        if self.config.brightness:
            Jt[6] = -w_ * ea * I_t
            Jt[7] = w_
        return Jt.T, Jt @ Jt.T, Jt @ out["e"], ab


# ====================================================================== tracking
@dataclass
class TrackResult:
    """Output of :func:`track_frame`.

    Attributes:
        T_world_frame: 4x4 camera-to-world pose of the frame.
        brightness: ``(a, b)`` of the frame relative to the keyframe.
        cost: final cost (photometric + brightness prior) at the finest level.
        photometric_cost: its photometric part (the factors' total error).
        relative_cost: photometric cost over the cost of a featureless frame
            on the same valid pixels (see ``TrackerConfig.max_relative_cost``),
            both on the *decision pixels*: every primitive pixel of the
            finest level on the lattice of ``decision_stride`` (no pixel
            selection), so it does not depend on the pixels the pose was
            optimised on.
        valid_fraction: fraction of the decision pixels that project inside
            the frame (in front of it) at the final pose.
        iterations: LM iterations (tried steps) per level, coarsest first.
        levels: the pyramid levels processed, coarsest first.
        status: ``"ok"`` or ``"lost"``.
        reason: why ``"lost"`` (``"diverged"``, ``"no_pixels"``,
            ``"low_overlap"``, ``"high_cost"``, ``"cost_increase"``); None if ok.
        timings: seconds: ``prepare`` (frame pyramid), ``level<l>`` per level,
            ``total``.
        report: per level: pixels, primitives, initial/final cost, accepted
            steps, final damping.
        decision_stride: lattice stride of the decision pixels
            (:func:`decision_stride`).
        decision_steps: LM steps tried on the decision pixels after the
            pyramid (``TrackerConfig.decision_iterations``); ``T_world_frame``
            and ``brightness`` include them, ``cost`` and
            ``photometric_cost`` are the finest level's before them.
    """

    T_world_frame: np.ndarray
    brightness: np.ndarray
    cost: float
    photometric_cost: float
    relative_cost: float
    valid_fraction: float
    iterations: List[int]
    levels: List[int]
    status: str
    reason: Optional[str]
    timings: Dict[str, float]
    report: List[dict]
    decision_stride: int = 1
    decision_steps: int = 0

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def T_kf_frame(self, keyframe: Keyframe) -> np.ndarray:
        """The frame's pose in the keyframe's camera."""
        return invert_pose(keyframe.T_world_kf) @ self.T_world_frame


def _retract(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """gtsam's Pose3 retraction ``T Exp(xi)``, ``xi = (omega, v)``."""
    return gtsam.Pose3(T).retract(np.asarray(xi, dtype=np.float64)).matrix()


def _valid_fraction(keyframe: Keyframe, T_world_frame: np.ndarray, min_depth: float,
                    stride: int = 1) -> float:
    """Fraction of the keyframe primitive points on the lattice of ``stride``
    (1: all of them) inside the frame's image."""
    T = invert_pose(T_world_frame) @ keyframe.T_world_kf
    P = keyframe.lattice_points(stride)
    Y = [T[i, 0] * P[0] + T[i, 1] * P[1] + T[i, 2] * P[2] + T[i, 3] for i in range(3)]
    cam = keyframe.camera
    z = Y[2]
    front = z > min_depth
    zs = np.where(front, z, 1.0)
    u = cam.fx * Y[0] / zs + cam.cx
    v = cam.fy * Y[1] / zs + cam.cy
    inside = front & (u >= 0) & (u <= cam.width - 1) & (v >= 0) & (v <= cam.height - 1)
    return float(np.count_nonzero(inside)) / max(inside.size, 1)


def _levenberg_marquardt(fn: TrackingCost, T: np.ndarray, ab: np.ndarray, cur: dict,
                         max_it: int, tr_tol: float, config: TrackerConfig):
    """LM over one :class:`TrackingCost` from ``(T, ab)`` (``cur``: its
    linearised evaluation there); returns ``(T, ab, evaluation (not
    linearised after an accepted last step), tried steps, accepted steps,
    final damping)``."""
    nd = fn.dim
    lam = config.lm_lambda_initial
    its = accepted = 0
    while its < max_it and np.isfinite(cur["cost"]):
        H, g = cur["H"], cur["g"]
        diag = np.diag(H).copy()
        diag = np.maximum(diag, 1e-9 * max(float(diag.max()), 1e-12))
        its += 1
        try:
            delta = np.linalg.solve(H + lam * np.diag(diag), -g)
        except np.linalg.LinAlgError:
            delta = np.full(nd, np.nan)
        if not np.all(np.isfinite(delta)):
            lam *= config.lm_lambda_factor
            if lam > config.lm_lambda_max:
                break
            continue
        T_new = _retract(T, delta[:6])
        ab_new = ab + delta[6:] if config.brightness else ab
        new = fn.evaluate(T_new, ab_new, jacobians=False)
        small = (np.linalg.norm(delta[:3]) < config.rotation_tol
                 and np.linalg.norm(delta[3:6]) < tr_tol)
        if np.isfinite(new["cost"]) and new["cost"] < cur["cost"]:
            rel = (cur["cost"] - new["cost"]) / max(cur["cost"], 1e-300)
            T, ab, cur = T_new, ab_new, new
            accepted += 1
            lam = max(lam / config.lm_lambda_factor, 1e-12)
            if rel < config.relative_cost_tol or small or its >= max_it:
                break
            fn.linearise(cur)
        else:
            # a rejected step that was already negligible: converged
            lam *= config.lm_lambda_factor
            if small or lam > config.lm_lambda_max:
                break
    return T, ab, cur, its, accepted, lam


def decision_stride(width: int, decision_width: int) -> int:
    """Lattice stride of the decision pixels of an image ``width`` wide:
    ``round(width / decision_width)``, at least 1."""
    return max(1, int(round(int(width) / int(decision_width))))


def _decision_quantities(keyframe: Keyframe, pyr: Pyramid, stride: int, T: np.ndarray,
                         ab: np.ndarray, config: TrackerConfig, final: dict,
                         final_fn: TrackingCost, tr_tol: float
                         ) -> Tuple[np.ndarray, np.ndarray, float, float, int]:
    """``(T, ab, relative cost, valid fraction, refinement steps)`` on the
    decision pixels (the finest level's lattice of ``stride``,
    :class:`TrackResult`) from the pose ``T`` and brightness ``ab``;
    ``final`` / ``final_fn``: the last level's evaluation at that state
    (reused when it ran on the decision pixels).  When the last level had
    fewer pixels than the decision pixels, up to
    ``config.decision_iterations`` LM steps on the decision pixels refine
    ``(T, ab)`` first."""
    its = 0
    if (final_fn.level == 0
            and final_fn.data is keyframe.level_data(0, stride, config.min_level_pixels, None)):
        out, fn = final, final_fn
    else:
        fn = TrackingCost(keyframe, pyr.images[0], pyr.cameras[0], 0, config,
                          selection=None, subsample=stride)
        if fn.n_pixels == 0:
            return T, ab, float("nan"), _valid_fraction(
                keyframe, T, config.photometric.min_depth, stride), 0
        if config.decision_iterations > 0 and final_fn.n_pixels < fn.n_pixels:
            out = fn.evaluate(T, ab, jacobians=True)
            T, ab, out, its, _, _ = _levenberg_marquardt(fn, T, ab, out,
                                                         config.decision_iterations, tr_tol,
                                                         config)
        else:
            out = fn.evaluate(T, ab, jacobians=False)
    vfrac = _valid_fraction(keyframe, T, config.photometric.min_depth, stride)
    flat = fn.featureless_cost(out)
    rel = float(out["photometric_cost"]) / flat if flat > 0 else float("inf")
    return T, ab, rel, vfrac, its


def constant_velocity_guess(T_world_prev: np.ndarray,
                            T_world_prevprev: Optional[np.ndarray] = None) -> np.ndarray:
    """Initial pose of the next frame: the previous frame's pose moved by the
    last inter-frame motion (in the camera frame), ``T_prev (T_prevprev^-1 T_prev)``.
    Without ``T_world_prevprev`` the previous pose itself."""
    T_p = check_pose(np.asarray(T_world_prev, dtype=np.float64), "T_world_prev")
    if T_world_prevprev is None:
        return T_p.copy()
    T_pp = check_pose(np.asarray(T_world_prevprev, dtype=np.float64), "T_world_prevprev")
    T = T_p @ (invert_pose(T_pp) @ T_p)
    # re-orthonormalise the rotation (products accumulate rounding)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ Vt
    return T


def track_frame(keyframe: Keyframe, image: np.ndarray, T_world_init: np.ndarray,
                brightness_init: Sequence[float] = (0.0, 0.0),
                config: TrackerConfig = TrackerConfig(),
                reference_cost: Optional[float] = None) -> TrackResult:
    """Photometric pose-only alignment of ``image`` against ``keyframe``.

    Coarse-to-fine Levenberg-Marquardt over the frame pose (and affine
    brightness) minimising the factor graph's photometric cost with the
    keyframe's primitive scales fixed (module docstring).

    Args:
        keyframe: :class:`Keyframe` (see :meth:`Keyframe.build`).
        image: the frame, same size as the keyframe's input image;
            uint8/uint16 or float in [0, 1], grey or RGB.
        T_world_init: initial 4x4 camera-to-world pose (e.g. the previous
            frame's, or :func:`constant_velocity_guess`).
        brightness_init: initial ``(a, b)``.
        config: :class:`TrackerConfig`.
        reference_cost: optional cost to compare with (cost blow-up check,
            ``config.max_cost_increase``).
    Returns:
        :class:`TrackResult`; a failed alignment is reported in ``status``
        (``"lost"``) and ``reason``, never raised.
    Raises:
        ValueError: malformed input (wrong image size, NaN/inf in the image,
            invalid pose or brightness).
    """
    t_start = time.perf_counter()
    T = check_pose(np.asarray(T_world_init, dtype=np.float64), "T_world_init").copy()
    ab = np.asarray(brightness_init, dtype=np.float64).reshape(-1)
    if ab.shape != (2,) or not np.all(np.isfinite(ab)):
        raise ValueError(f"brightness_init must be two finite numbers, got {brightness_init!r}")
    if not config.brightness:
        ab = np.zeros(2)
    pyr = keyframe.frame_pyramid(image, config.levels)
    n_levels = len(pyr)
    timings: Dict[str, float] = {"prepare": time.perf_counter() - t_start}
    report: List[dict] = []
    iterations: List[int] = []
    levels: List[int] = []
    tr_tol = config.translation_tol * keyframe.median_depth
    final: Optional[dict] = None
    final_cost_fn: Optional[TrackingCost] = None
    for lvl in reversed(range(n_levels)):
        t0 = time.perf_counter()
        fn = TrackingCost(keyframe, pyr.images[lvl], pyr.cameras[lvl], lvl, config)
        max_it = int(config.iterations[min(n_levels - 1 - lvl, len(config.iterations) - 1)])
        levels.append(lvl)
        if fn.n_pixels == 0:
            iterations.append(0)
            report.append({"level": lvl, "pixels": 0, "primitives": 0})
            continue
        cur = fn.evaluate(T, ab, jacobians=True)
        cost0 = cur["cost"]
        T, ab, cur, its, accepted, lam = _levenberg_marquardt(fn, T, ab, cur, max_it, tr_tol,
                                                              config)
        iterations.append(its)
        final, final_cost_fn = cur, fn
        dt = time.perf_counter() - t0
        timings[f"level{lvl}"] = dt
        report.append({"level": lvl, "pixels": fn.n_pixels,
                       "primitives": fn.data.n_primitives, "initial_cost": cost0,
                       "final_cost": cur["cost"], "accepted": accepted, "lambda": lam,
                       "valid_fraction": cur["valid_fraction"], "seconds": dt})
        log.debug("tracking level %d: %d px, %d its (%d accepted), cost %.4g -> %.4g",
                  lvl, fn.n_pixels, its, accepted, cost0, cur["cost"])

    # ---- assessment on the decision pixels
    reason: Optional[str] = None
    finite = bool(np.all(np.isfinite(T)) and np.all(np.isfinite(ab)))
    dec = decision_stride(keyframe.camera.width, config.decision_width)
    rel_cost, vfrac, decision_steps = float("nan"), 0.0, 0
    if final is None:
        reason = "no_pixels"
        cost = photo = float("nan")
        if finite:
            vfrac = _valid_fraction(keyframe, T, config.photometric.min_depth, dec)
    else:
        cost, photo = float(final["cost"]), float(final["photometric_cost"])
        if finite:
            t0 = time.perf_counter()
            T, ab, rel_cost, vfrac, decision_steps = _decision_quantities(
                keyframe, pyr, dec, T, ab, config, final, final_cost_fn, tr_tol)

            timings["decision"] = time.perf_counter() - t0
    if reason is None:
        if not (finite and np.isfinite(cost)):
            reason = "diverged"
        elif vfrac < config.min_valid_fraction:
            reason = "low_overlap"
        elif not rel_cost <= config.max_relative_cost:
            reason = "high_cost"
        elif (reference_cost is not None and np.isfinite(reference_cost)
              and cost > config.max_cost_increase * float(reference_cost)):
            reason = "cost_increase"
    if not finite:
        vfrac = 0.0
        T, ab = check_pose(np.asarray(T_world_init, dtype=np.float64)).copy(), np.zeros(2)
    status = "ok" if reason is None else "lost"
    timings["total"] = time.perf_counter() - t_start
    if reason is not None:
        log.info("tracking lost (%s): valid fraction %.2f, relative cost %.3g",
                 reason, vfrac, rel_cost)
    return TrackResult(T, ab.copy(), cost, photo, float(rel_cost), vfrac, iterations, levels,
                       status, reason, timings, report, dec, decision_steps)
