"""The batched photometric cost of pose-only tracking (:class:`TrackingCost`).

The cost is *exactly* the one of the factor graph (docs/design.md §4): for every
primitive ``i`` of the keyframe the
:class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` of the pair
(keyframe, frame) contributes ``0.5 |e_i|^2`` with

    e_ik = w_ik r_ik,   r_ik = exp(-a) I_t(pi(T_tgt_kf X_ik)) + b - I_kf(u_ik),
    w_ik = rho(r_ik) / sqrt(|Omega_i, valid|)

(Huber IRLS weight ``rho``, per-primitive mean over the pixels valid in the
target, constant penalty rows for points behind the frame's camera), built at
each pyramid level exactly as :func:`spgeo.graph.builders.build_level_graph` builds it,
on the pixels of :meth:`spgeo.vo.keyframe.Keyframe.level_data` and the frame's
level-``l`` image and camera.  The brightness has no prior
(``TrackerConfig``'s docstring says why).

Instead of one gtsam factor per primitive, all primitives' pixels are
concatenated into one batch; residuals and the 8 columns of the Jacobian
(6 frame-pose + 2 brightness) are computed once per iteration with the
factor's own formulas (its bilinear sampler inlined, the same robust weights; the
per-primitive normalisation uses ``np.bincount`` over primitive ids).
``tests/test_tracking.py`` checks cost and gradient against the factors.
"""
from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np

from ..camera import PinholeCamera
from ..factors import kernels
from ..factors.photometric import residual_pass, robust_weights
from .config import TrackerConfig
from .keyframe import Keyframe
from .pixels import PixelSelectionConfig

__all__ = ["TrackingCost"]


class TrackingCost:
    """The batched photometric cost of one pyramid level.

    ``cost = sum_i 0.5 |e_i|^2``: the sum of the errors of the
    :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` of every
    keyframe primitive (built as :func:`spgeo.graph.builders.build_level_graph` builds
    them at this level).

    Args:
        keyframe: the :class:`Keyframe`.
        image: the frame's grey image at ``level`` (float32, from
            :meth:`Keyframe.frame_pyramid`).
        camera: the camera of ``image``.
        level: pyramid level.
        config: :class:`TrackerConfig` (photometric options, brightness,
            ``min_level_pixels``).
        selection: pixel selection (:meth:`Keyframe.level_data`; default the
            keyframe's own).
        subsample: extra lattice stride on the level (default 1: every pixel
            of the level's lattice).
    """

    def __init__(self, keyframe: Keyframe, image: np.ndarray, camera: PinholeCamera,
                 level: int, config: TrackerConfig = TrackerConfig(),
                 selection: Union[PixelSelectionConfig, None, str] = "keyframe",
                 subsample: int = 1) -> None:
        img = np.asarray(image)
        if img.ndim != 2 or img.shape != camera.shape:
            raise ValueError(f"TrackingCost: image must be (H, W) = {camera.shape}, got {img.shape}")
        self.image = img
        self.camera = camera
        self.level = int(level)
        self.config = config
        self.data = keyframe.level_data(self.level, int(subsample), config.min_level_pixels,
                                        selection)
        self.T_world_kf = keyframe.T_world_kf
        self.dim = 8 if config.brightness else 6
        pc = config.photometric
        self._pen_row = float(robust_weights(np.array([pc.behind_penalty]), pc)[0]
                              * pc.behind_penalty)

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
        ``prior_cost`` (0: no brightness prior), ``cost`` (their sum),
        ``valid_fraction`` (rows valid in the target); with ``jacobians``:
        ``J`` (K, 6|8) (frame pose in gtsam's tangent ``(omega, v)``, then
        ``(a, b)``), ``H = J^T J`` and ``g = J^T e``, the gradient of ``cost`` as the factors'
        linearisation gives it (weights held fixed: IRLS).
        """
        out = self._residuals(T_world_frame, brightness)
        if jacobians:
            self.linearise(out)
        return out

    def _residuals(self, T_world_frame: np.ndarray, brightness: Sequence[float]) -> dict:
        """Residual pass: the factors' compiled kernel
        (:func:`spgeo.factors.photometric.residual_pass`), or with
        ``photometric.backend="numpy"`` :meth:`_residuals_numpy` (mirrors
        ``PrimitivePhotometricFactor.evaluate``)."""
        T_wt = np.asarray(T_world_frame, dtype=np.float64)
        T_wr = self.T_world_kf
        R_wt, R_wr = T_wt[:3, :3], T_wr[:3, :3]
        R = R_wt.T @ R_wr                                   # R_frame_kf
        t = R_wt.T @ (T_wr[:3, 3] - T_wt[:3, 3])
        if self.config.brightness:
            a, b = float(brightness[0]), float(brightness[1])
        else:
            a, b = 0.0, 0.0
        if kernels.resolve_backend(self.config.photometric.backend) == "numba":
            return self._residuals_kernel(R, t, a, b)
        return self._residuals_numpy(R, t, a, b)

    def _residuals_kernel(self, R: np.ndarray, t: np.ndarray, a: float, b: float) -> dict:
        """:meth:`_residuals` with the compiled kernel."""
        pc = self.config.photometric
        d = self.data
        group_pixels = d.n_pixels if pc.normalise == "all" else np.ones(d.n_primitives)
        res = residual_pass(d.points_t.T, None, np.ascontiguousarray(R), t, self.image,
                            self.camera, d.ref_intensity, a, b, pc, d.ids, group_pixels)
        photo = 0.5 * res["sum_sq"]
        return {"e": res["e"], "r": res["r"], "valid": res["valid"], "behind": res["behind"],
                "ids": d.ids, "photometric_cost": photo, "prior_cost": 0.0, "cost": photo,
                "valid_fraction": res["n_valid"] / max(d.ids.size, 1),
                "_kernel": (res, np.array([a, b]))}

    def _project(self, R: np.ndarray, t: np.ndarray):
        """``(Y, inv_z, u, v, behind, any_behind)`` of the level's points in the
        frame (``inv_z`` 0 and ``u`` -1 behind the camera)."""
        cam = self.camera
        Y = R @ self.data.points_t
        Y += t[:, None]
        Yx, Yy, z = Y[0], Y[1], Y[2]
        behind = z <= self.config.photometric.min_depth
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
        return Y, inv_z, u, v, behind, any_behind

    def _sample(self, u: np.ndarray, v: np.ndarray):
        """Bilinear sample + exact interpolant derivatives (as the factor's
        sampler; rows outside are left unzeroed: their weight is 0):
        ``(inside, I_t, d0, d1, bot - top, av)``."""
        img = self.image
        h, w = img.shape
        with np.errstate(invalid="ignore"):
            inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
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
        return inside, I_t, d0, d1, bot - top, av

    def _residuals_numpy(self, R: np.ndarray, t: np.ndarray, a: float, b: float) -> dict:
        """:meth:`_residuals` in numpy."""
        pc = self.config.photometric
        d = self.data
        Y, inv_z, u, v, behind, any_behind = self._project(R, t)
        inside, I_t, d0, d1, gv, av = self._sample(u, v)
        valid = ~behind
        valid &= inside
        ea = np.exp(-a)
        r = ea * I_t + b - d.ref_intensity
        scale = self._scale(valid | behind)
        w_ = scale * robust_weights(r, pc) * valid
        e = w_ * r
        if any_behind:
            e = np.where(behind, scale * self._pen_row, e)
        photo = 0.5 * float(np.einsum("i,i->", e, e))
        return {"e": e, "r": np.where(valid, r, 0.0), "valid": valid, "behind": behind,
                "ids": d.ids, "photometric_cost": photo, "prior_cost": 0.0, "cost": photo,
                "valid_fraction": float(np.count_nonzero(valid)) / max(valid.size, 1),
                "_lin": (Y, inv_z, w_, ea, I_t, d0, d1, gv, av, np.array([a, b]))}

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
