"""Per-primitive photometric factor (docs/design.md §4) and the primitive shape models.

One factor per (primitive of a reference frame, target frame).  For every pixel
``u_k`` of the primitive with ray ``r_k = K^-1 [u_k, 1]`` the shape model gives a
reference-frame point ``X_k(theta)``; it is moved into the target camera with
``T_tgt_ref = inv(T_world_tgt) T_world_ref`` and projected:

    Y_k = T_tgt_ref X_k,    u'_k = pi(Y_k),
    r_k = exp(-a) I_t(u'_k) + b - I_r(u_k)          (a, b: optional affine brightness)
    e_k = w_k r_k,          w_k = rho_k / sqrt(|Omega_valid|)

``rho_k`` is a per-pixel robust weight computed inside the factor (IRLS:
``sqrt(psi(r)/r)``; Huber by default, an L1-like cost for small ``delta``);
GTSAM's own robust noise models would act on the whole factor instead.
Pixels that project outside the target image give zero rows (fixed residual
length).  Pixels whose point is geometrically impossible (behind the
reference camera, which a plane parameter can cause, or behind the target
camera) get a constant penalty row with zero Jacobian instead: with zero rows
LM can "solve" a primitive by flipping its plane behind the camera, where
every residual vanishes (observed with the planar model).  By default the mean is taken over the pixels
that are valid in the target (``|Omega_valid|``, constant within a
linearisation): with the full ``|Omega|`` the cost *drops* when pixels leave
the image, and at coarse pyramid levels LM then happily rotates primitives out
of view (see docs/results.md).  The
factor's error ``0.5 |e|^2`` is half the per-primitive mean of the
(robustified) squared photometric errors.

Jacobians (gtsam Pose3 retraction ``T Exp(xi)``, ``xi = (omega, v)``), with
``g_k = de_k/dY_k`` and ``R = R_tgt_ref``:

    de/dxi_ref  = [ X x (R^T g),  R^T g ]
    de/dxi_tgt  = [ g x Y,        -g    ]
    de/dtheta   = (R^T g) . dX/dtheta
    de/d(a, b)  = w (-exp(-a) I_t, 1)

Image gradients are the exact derivatives of the bilinear interpolant, so
the analytic Jacobians match numerical differentiation (tested).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

import gtsam

from spgeo.camera import PinholeCamera
from spgeo.configs import config_class

from . import kernels

__all__ = [
    "PhotometricConfig", "ShapeModel", "ScaledShape", "PlanarShape",
    "PrimitivePhotometricFactor", "photometric_rows", "photometric_rows_numpy",
    "photometric_rows_numba", "residual_pass", "robust_weights",
]


@config_class
@dataclass(frozen=True)
class PhotometricConfig:
    """Options of :class:`PrimitivePhotometricFactor`.

    Attributes:
        robust: ``"huber"`` (default) or ``"none"`` (plain least squares).
        huber_delta: Huber threshold in intensity units (images in [0, 1]);
            default 0.04 (~10 grey levels): below it squared error, above it
            absolute error (the paper's L1 cost, smoothed near 0).
        min_depth: points closer than this to the target camera (metres along
            its optical axis, in the map's units) are invalid (default 1e-3).
        normalise: ``"valid"`` (default): the per-primitive mean runs over the
            pixels valid in the target; ``"all"``: over all of the
            primitive's pixels (then leaving the image lowers the cost);
            ``"none"``: no mean, every pixel weighted ``1 / pixel_sigma`` (a
            per-pixel noise model: covariances in physical units).
        pixel_sigma: per-pixel photometric noise std (intensity units) used by
            ``normalise="none"``.
        behind_penalty: photometric error (intensity units) charged to a pixel
            whose point lies behind the reference or target camera (default
            0.5, about the largest plausible photometric error).
        backend: implementation of the rows (:func:`photometric_rows`):
            ``"auto"`` (default: the compiled kernels of
            :mod:`spgeo.factors.kernels` when numba is importable, else
            numpy), ``"numba"`` or ``"numpy"`` (the reference).  The same
            cost either way.
    """

    robust: str = "huber"
    huber_delta: float = 0.04
    min_depth: float = 1e-3
    normalise: str = "valid"
    pixel_sigma: float = 0.02
    behind_penalty: float = 0.5
    backend: str = "auto"

    def __post_init__(self) -> None:
        if self.robust not in ("huber", "none"):
            raise ValueError(f"PhotometricConfig.robust must be 'huber' or 'none', got {self.robust!r}")
        if not self.huber_delta > 0:
            raise ValueError("PhotometricConfig.huber_delta must be > 0")
        if self.normalise not in ("valid", "all", "none"):
            raise ValueError(f"PhotometricConfig.normalise must be 'valid', 'all' or 'none', "
                             f"got {self.normalise!r}")
        if not self.pixel_sigma > 0:
            raise ValueError("PhotometricConfig.pixel_sigma must be > 0")
        if self.backend not in kernels.BACKENDS:
            raise ValueError(f"PhotometricConfig.backend must be one of {kernels.BACKENDS}, "
                             f"got {self.backend!r}")


def robust_weights(r: np.ndarray, config: PhotometricConfig) -> np.ndarray:
    """Square-root IRLS weights ``sqrt(psi(r) / r)`` of the per-pixel residuals."""
    if config.robust == "none":
        return np.ones_like(r)
    a = np.abs(r)
    return np.where(a <= config.huber_delta, 1.0,
                    np.sqrt(config.huber_delta / np.maximum(a, 1e-300)))


class ShapeModel:
    """Reference-frame points of one primitive's pixels as a function of its
    shape variable ``theta`` (a gtsam Vector of size :attr:`dim`)."""

    dim: int = 0

    def points(self, theta: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(X (K, 3), dX/dtheta (K, 3, dim), valid (K,))``; ``theta`` is one
        ``(dim,)`` vector or one per pixel, ``(K, dim)`` (batched primitives)."""
        raise NotImplementedError


class ScaledShape(ShapeModel):
    """The paper's model: 1-DoF log-scale ``s`` on the integrated shape,
    ``X_k = exp(l_k + s) r_k`` (``l_k`` unscaled log-depth, ``r_k`` ray with z = 1)."""

    dim = 1

    def __init__(self, rays: np.ndarray, log_depth: np.ndarray) -> None:
        self.rays = np.asarray(rays, dtype=np.float64)
        self.log_depth = np.asarray(log_depth, dtype=np.float64)
        if self.rays.ndim != 2 or self.rays.shape[1] != 3 or self.log_depth.shape != self.rays.shape[:1]:
            raise ValueError("ScaledShape: rays must be (K, 3) and log_depth (K,)")

    def points(self, theta):
        z = np.exp(self.log_depth + np.asarray(theta, dtype=np.float64)[..., 0])
        X = self.rays * z[:, None]
        return X, X[:, :, None], np.ones(z.size, dtype=bool)


class PlanarShape(ShapeModel):
    """3-DoF inverse-depth plane ``1/z = a x + b y + c`` in normalised image
    coordinates ``(x, y)`` (for when no normal network is available);
    ``X_k = r_k / (theta . r_k)``.  Pixels with ``theta . r <= 0`` (plane
    behind the camera along that ray) are invalid."""

    dim = 3

    def __init__(self, rays: np.ndarray, min_inverse_depth: float = 1e-6) -> None:
        self.rays = np.asarray(rays, dtype=np.float64)
        if self.rays.ndim != 2 or self.rays.shape[1] != 3:
            raise ValueError("PlanarShape: rays must be (K, 3)")
        self.min_inverse_depth = float(min_inverse_depth)

    def points(self, theta):
        rho = np.sum(self.rays * np.asarray(theta, dtype=np.float64), axis=-1)
        valid = rho > self.min_inverse_depth
        inv = np.where(valid, 1.0 / np.where(valid, rho, 1.0), 0.0)
        X = self.rays * inv[:, None]
        dX = -X[:, :, None] * (self.rays * inv[:, None])[:, None, :]
        return X, dX, valid

    @staticmethod
    def fronto_parallel(depth: float) -> np.ndarray:
        """Plane parameters of the fronto-parallel plane at ``depth`` metres."""
        return np.array([0.0, 0.0, 1.0 / float(depth)])


def _cross_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Row-wise cross product ``a x b`` of (K, 3) arrays written into ``out``."""
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _sample_with_gradient(img: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Bilinear value and its exact derivatives of a 2-D image at (u, v);
    outside ``[0, W-1] x [0, H-1]`` (or NaN) invalid with zeros.  A lean copy
    of :func:`spgeo.images.sample_bilinear` for the factor's hot path."""
    h, w = img.shape
    with np.errstate(invalid="ignore"):
        valid = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc = np.where(valid, u, 0.0)
    vc = np.where(valid, v, 0.0)
    u0 = np.minimum(uc.astype(np.int64), w - 2)
    v0 = np.minimum(vc.astype(np.int64), h - 2)
    au = uc - u0
    av = vc - v0
    flat = img.reshape(-1)
    i00 = v0 * w + u0
    p00 = flat[i00]
    p01 = flat[i00 + 1]
    p10 = flat[i00 + w]
    p11 = flat[i00 + w + 1]
    top = p00 + (p01 - p00) * au
    bot = p10 + (p11 - p10) * au
    val = np.where(valid, top + (bot - top) * av, 0.0)
    gu = np.where(valid, (p01 - p00) * (1 - av) + (p11 - p10) * av, 0.0)
    gv = np.where(valid, bot - top, 0.0)
    return val, valid, gu, gv


def _row_scale(config: PhotometricConfig, valid: np.ndarray, behind: np.ndarray,
               ids: Optional[np.ndarray], n_groups: int, group_pixels: np.ndarray):
    """Scale of each row (a scalar for one primitive) as ``config.normalise`` says:
    ``1 / sqrt(|rows valid or behind|)`` per primitive ("valid"), ``1 / pixel_sigma``
    ("none") or ``1 / sqrt(|Omega|)`` of the primitive ("all")."""
    if config.normalise == "valid":
        if ids is None:
            return 1.0 / np.sqrt(max(int(np.count_nonzero(valid | behind)), 1))
        cnt = np.bincount(ids, weights=(valid | behind), minlength=n_groups)
        return (1.0 / np.sqrt(np.maximum(cnt, 1.0)))[ids]
    if config.normalise == "none":
        return 1.0 / config.pixel_sigma
    per = 1.0 / np.sqrt(np.asarray(group_pixels, dtype=np.float64))
    return per[0] if ids is None else per[ids]


def photometric_rows_numpy(X: np.ndarray, dX: np.ndarray, shape_valid: np.ndarray,
                           T_world_ref: np.ndarray, T_world_tgt: np.ndarray,
                           target_image: np.ndarray, camera: PinholeCamera,
                           ref_intensity: np.ndarray, brightness: Optional[np.ndarray],
                           config: PhotometricConfig, ids: Optional[np.ndarray], n_groups: int,
                           group_pixels: np.ndarray, jacobians: bool = True) -> dict:
    """The factor's rows for the reference points ``X`` (K, 3) of one or many
    primitives (the module docstring's model).

    ``ids`` (K,) gives each row's primitive (``None``: all rows are one
    primitive) among ``n_groups``; ``group_pixels`` (n_groups,) is each
    primitive's ``|Omega|`` for ``normalise="all"``.  Rows of different
    primitives never mix: the result for one primitive is the same whether it
    is evaluated alone or in a batch (tested).  The numpy reference of
    :func:`photometric_rows_numba`.
    """
    R_wt, R_wr = T_world_tgt[:3, :3], T_world_ref[:3, :3]
    R = R_wt.T @ R_wr                                   # R_tgt_ref
    t = R_wt.T @ (T_world_ref[:3, 3] - T_world_tgt[:3, 3])
    Y = X @ R.T + t
    Yx, Yy, z = Y[:, 0], Y[:, 1], Y[:, 2]
    behind = ~shape_valid | (z <= config.min_depth)
    valid = ~behind
    inv_z = np.where(valid, 1.0 / np.where(valid, z, 1.0), 0.0)
    cam = camera
    u = np.where(valid, cam.fx * Yx * inv_z + cam.cx, -1.0)
    v = cam.fy * Yy * inv_z + cam.cy
    I_t, inside, gu, gv = _sample_with_gradient(target_image, u, v)
    valid &= inside
    if brightness is not None:
        a, b = float(brightness[0]), float(brightness[1])
    else:
        a, b = 0.0, 0.0
    ea = np.exp(-a)
    r = ea * I_t + b - ref_intensity
    scale = _row_scale(config, valid, behind, ids, n_groups, group_pixels)
    w = scale * robust_weights(r, config) * valid
    e = w * r
    if behind.any():
        pen = config.behind_penalty
        e = np.where(behind, scale * robust_weights(np.array([pen]), config)[0] * pen, e)
    out = {"e": e, "r": np.where(valid, r, 0.0), "valid": valid, "behind": behind, "weights": w}
    if not jacobians:
        return out
    wg = w * ea * inv_z
    du = wg * gu * cam.fx
    dv = wg * gv * cam.fy
    dz = -(du * Yx + dv * Yy) * inv_z
    g = np.empty((du.size, 3))                         # de/dY
    g[:, 0], g[:, 1], g[:, 2] = du, dv, dz
    gR = g @ R                                         # R^T g per row
    J_ref = np.empty((du.size, 6))
    _cross_into(X, gR, J_ref[:, :3])
    J_ref[:, 3:] = gR
    J_tgt = np.empty((du.size, 6))
    _cross_into(g, Y, J_tgt[:, :3])
    J_tgt[:, 3:] = -g
    out["J_ref"] = J_ref
    out["J_tgt"] = J_tgt
    out["J_shape"] = np.einsum("ki,kij->kj", gR, dX)
    if brightness is not None:
        J_b = np.empty((du.size, 2))
        J_b[:, 0] = -w * ea * I_t
        J_b[:, 1] = w
        out["J_brightness"] = J_b
    return out


def _relative_pose(T_world_ref: np.ndarray, T_world_tgt: np.ndarray):
    """``(R, t)`` of ``T_tgt_ref`` from the two camera-to-world poses."""
    R_wt = T_world_tgt[:3, :3]
    R = np.ascontiguousarray(R_wt.T @ T_world_ref[:3, :3])
    t = R_wt.T @ (T_world_ref[:3, 3] - T_world_tgt[:3, 3])
    return R, t


_EMPTY_IDS = np.zeros(0, dtype=np.int64)
_EMPTY_BOOL = np.zeros(0, dtype=bool)


def residual_pass(X: np.ndarray, shape_valid: Optional[np.ndarray], R: np.ndarray,
                  t: np.ndarray, target_image: np.ndarray, camera: PinholeCamera,
                  ref_intensity: np.ndarray, a: float, b: float, config: PhotometricConfig,
                  ids: Optional[np.ndarray], group_pixels: np.ndarray) -> dict:
    """Residual rows by the compiled kernel :func:`spgeo.factors.kernels.residual_pass`
    (shared by the factors and the tracker): ``e``, ``r``, ``valid``,
    ``behind``, ``weights`` (K,), ``sum_sq = |e|^2``, ``n_valid``, and the
    kernel's ``I_t`` (K,), ``Y``, ``g`` (K, 3), ``ea = exp(-a)`` for the Jacobians.  ``shape_valid`` / ``ids`` None: all valid /
    one primitive; ``group_pixels`` is per primitive (its size is the
    primitive count)."""
    k = X.shape[0]
    out = {"e": np.empty(k), "r": np.empty(k), "valid": np.empty(k, dtype=bool),
           "behind": np.empty(k, dtype=bool), "weights": np.empty(k), "I_t": np.empty(k),
           "Y": np.empty((k, 3)), "g": np.empty((k, 3))}
    cam = camera
    ea = float(np.exp(-a))
    sq, n_valid = kernels.residual_pass(
        X, _EMPTY_BOOL if shape_valid is None else shape_valid, R, t, target_image,
        float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), ref_intensity, ea, float(b),
        _EMPTY_IDS if ids is None else ids, np.asarray(group_pixels, dtype=np.float64),
        kernels.NORMALISE_CODES[config.normalise], float(config.pixel_sigma),
        config.robust == "huber", float(config.huber_delta), float(config.min_depth),
        float(config.behind_penalty), out["e"], out["r"], out["valid"], out["behind"],
        out["weights"], out["I_t"], out["Y"], out["g"])
    out.update(ea=ea, sum_sq=sq, n_valid=n_valid)
    return out


def photometric_rows_numba(X: np.ndarray, dX: np.ndarray, shape_valid: np.ndarray,
                           T_world_ref: np.ndarray, T_world_tgt: np.ndarray,
                           target_image: np.ndarray, camera: PinholeCamera,
                           ref_intensity: np.ndarray, brightness: Optional[np.ndarray],
                           config: PhotometricConfig, ids: Optional[np.ndarray], n_groups: int,
                           group_pixels: np.ndarray, jacobians: bool = True) -> dict:
    """:func:`photometric_rows_numpy` by the compiled kernels (same arguments
    and results; with ``jacobians`` also ``pose_rows_and_e`` (K, 13|15),
    ``[J_ref | J_tgt | J_brightness | e]``, of which ``J_ref``, ``J_tgt``
    and ``J_brightness`` are views)."""
    R, t = _relative_pose(T_world_ref, T_world_tgt)
    a, b = (float(brightness[0]), float(brightness[1])) if brightness is not None else (0.0, 0.0)
    gp = np.broadcast_to(np.asarray(group_pixels, dtype=np.float64).reshape(-1), (n_groups,))
    res = residual_pass(X, shape_valid, R, t, target_image, camera, ref_intensity, a, b, config,
                        ids, np.ascontiguousarray(gp))
    out = {key: res[key] for key in ("e", "r", "valid", "behind", "weights")}
    if not jacobians:
        return out
    k = X.shape[0]
    # pose and brightness columns side by side with e: [J_ref | J_tgt | J_b | e]
    # (the Gram input of PhotometricFactorGroup's square-root chunks)
    A = np.empty((k, 13 + (2 if brightness is not None else 0)))
    out["J_ref"], out["J_tgt"] = A[:, :6], A[:, 6:12]
    out["J_shape"] = np.empty((k, dX.shape[2]))
    J_b = A[:, 12:14] if brightness is not None else np.empty((0, 2))
    kernels.jacobian_rows(X, dX, R, res["Y"], res["g"], res["weights"], res["I_t"], res["ea"],
                          out["J_ref"], out["J_tgt"], out["J_shape"], J_b)
    A[:, -1] = res["e"]
    out["pose_rows_and_e"] = A
    if brightness is not None:
        out["J_brightness"] = J_b
    return out


def photometric_rows(X: np.ndarray, dX: np.ndarray, shape_valid: np.ndarray,
                     T_world_ref: np.ndarray, T_world_tgt: np.ndarray, target_image: np.ndarray,
                     camera: PinholeCamera, ref_intensity: np.ndarray,
                     brightness: Optional[np.ndarray], config: PhotometricConfig,
                     ids: Optional[np.ndarray], n_groups: int, group_pixels: np.ndarray,
                     jacobians: bool = True) -> dict:
    """The factor's rows (:func:`photometric_rows_numpy`'s contract) by the
    implementation ``config.backend`` selects."""
    fn = (photometric_rows_numba if kernels.resolve_backend(config.backend) == "numba"
          else photometric_rows_numpy)
    return fn(X, dX, shape_valid, T_world_ref, T_world_tgt, target_image, camera, ref_intensity,
              brightness, config, ids, n_groups, group_pixels, jacobians)


class PrimitivePhotometricFactor:
    """Builder of the gtsam.CustomFactor of one (primitive, target) pair.

    Args:
        ref_key, tgt_key: keys of ``T_world_ref`` / ``T_world_tgt`` (Pose3).
        shape_key: key of the primitive's shape variable (Vector of ``shape.dim``).
        shape: :class:`ScaledShape` or :class:`PlanarShape` over the pixels used.
        ref_intensity: (K,) reference intensities ``I_r(u_k)`` in [0, 1].
        target_image: (H, W) float target image (the pyramid level in use).
        target_camera: intrinsics of ``target_image`` (same level).
        brightness_key: optional key of the target's affine brightness ``(a, b)``.
        config: :class:`PhotometricConfig`.
        n_pixels: with ``normalise="all"``, the pixel count ``|Omega|`` of the
            ``1/sqrt(|Omega|)`` weight (default K).

    ``factor`` is the gtsam.CustomFactor; :meth:`evaluate` exposes the
    residuals, Jacobians and validity for tests and diagnostics.
    """

    def __init__(self, ref_key: int, tgt_key: int, shape_key: int, shape: ShapeModel,
                 ref_intensity: np.ndarray, target_image: np.ndarray,
                 target_camera: PinholeCamera, brightness_key: Optional[int] = None,
                 config: PhotometricConfig = PhotometricConfig(),
                 n_pixels: Optional[int] = None) -> None:
        self.ref_intensity = np.asarray(ref_intensity, dtype=np.float64).reshape(-1)
        k = self.ref_intensity.size
        if k == 0:
            raise ValueError("PrimitivePhotometricFactor: primitive has no pixel")
        if shape.rays.shape[0] != k:
            raise ValueError(f"PrimitivePhotometricFactor: shape has {shape.rays.shape[0]} pixels "
                             f"but {k} reference intensities")
        img = np.asarray(target_image)
        if img.ndim != 2 or img.shape != target_camera.shape:
            raise ValueError(f"target image must be (H, W) matching the camera "
                             f"{target_camera.shape}, got {img.shape}")
        if not np.all(np.isfinite(self.ref_intensity)):
            raise ValueError("reference intensities contain NaN or inf")
        if ref_key == tgt_key:
            raise ValueError("reference and target keys must differ")
        self.target_image = img
        self.camera = target_camera
        self.shape = shape
        self.config = config
        self.keys = [ref_key, tgt_key, shape_key] + ([brightness_key] if brightness_key is not None else [])
        self.has_brightness = brightness_key is not None
        self.n_pixels = float(n_pixels if n_pixels is not None else k)
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(k), self.keys, self._error)

    # --------------------------------------------------------------- core
    def evaluate(self, T_world_ref: np.ndarray, T_world_tgt: np.ndarray, theta: np.ndarray,
                 brightness: Optional[np.ndarray] = None, jacobians: bool = True) -> dict:
        """Residuals ``e`` (K,), validity, photometric errors ``r`` and, if asked,
        the Jacobians ``J_ref`` (K, 6), ``J_tgt`` (K, 6), ``J_shape`` (K, dim),
        ``J_brightness`` (K, 2)."""
        X, dX, shape_valid = self.shape.points(np.asarray(theta, dtype=np.float64))
        return photometric_rows(X, dX, shape_valid, T_world_ref, T_world_tgt, self.target_image,
                                self.camera, self.ref_intensity,
                                brightness if self.has_brightness else None, self.config,
                                None, 1, np.array([self.n_pixels]), jacobians)

    def _error(self, this: gtsam.CustomFactor, values: gtsam.Values,
               H: Optional[List[np.ndarray]]) -> np.ndarray:
        keys = this.keys()
        T_wr = values.atPose3(keys[0]).matrix()
        T_wt = values.atPose3(keys[1]).matrix()
        theta = values.atVector(keys[2])
        br = values.atVector(keys[3]) if self.has_brightness else None
        res = self.evaluate(T_wr, T_wt, theta, br, jacobians=H is not None)
        if H is not None:
            H[0] = res["J_ref"]
            H[1] = res["J_tgt"]
            H[2] = res["J_shape"]
            if self.has_brightness:
                H[3] = res["J_brightness"]
        return res["e"]
