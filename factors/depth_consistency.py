"""Mean depth consistency between two keyframes' primitives (VO scale chaining).

Photometric factors fix a keyframe's depth scale relative to its neighbour
only through parallax: after a pure rotation the new keyframe's scales are
unobservable, and the map's scale drifts with whatever weak prior holds them.
This factor chains the scale geometrically instead.  For ``K`` fixed
correspondences ``i`` -- a pixel of the reference keyframe with reference-frame
point ``X_i(theta_a(i))`` (its primitive's shape model) and the target
keyframe's pixel it projected to when the factor was built, whose target-frame
depth along that pixel's ray is ``Z_i(phi_b(i))`` (the target primitive's shape
model) -- the single residual (log units) is

    r = (1/K) sum_i [ log z_i - log Z_i ],     z_i = e3 . (R X_i + t),
    (R, t) = T_tgt_ref = inv(T_world_tgt) T_world_ref,

the mean log-ratio of where the reference surface is and where the target's
primitives say it is.  It constrains the two keyframes' common depth scale
given their relative pose (with or without parallax) and leaves every
relative scale to the photometric factors.  Correspondences are fixed at
construction (the target pixel does not follow the pose), which makes the
residual smooth; the error this leaves is the depth change across the pixel
shift of an update, second order near convergence.  Terms whose point falls
behind the target camera (``z_i <= min_depth``) or whose shape is invalid
(a plane behind its camera) contribute nothing and get no Jacobian.

Jacobians (gtsam Pose3 retraction ``T Exp(xi)``, ``xi = (omega, v)``), with
``g_i = (1/K) e3 / z_i = dr/dY_i`` and ``Y_i = R X_i + t``:

    dr/dxi_ref   = sum_i [ X_i x (R^T g_i),  R^T g_i ]
    dr/dxi_tgt   = sum_i [ g_i x Y_i,        -g_i    ]
    dr/dtheta_a  = sum_{i: a(i)=a} (R^T g_i) . dX_i/dtheta
    dr/dphi_b    = -(1/K) sum_{i: b(i)=b} (dZ_i/dphi) / Z_i

(tested against central differences).
"""
from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

import gtsam

from .photometric import ShapeModel, _cross_into

__all__ = ["DepthConsistencyFactor"]


class DepthConsistencyFactor:
    """Builder / holder of one mean depth-consistency ``gtsam.CustomFactor``.

    Args:
        ref_pose_key, tgt_pose_key: keys of ``T_world_ref`` / ``T_world_tgt``
            (Pose3, camera-to-world).
        ref_shape_keys: keys of the reference primitives' shape variables.
        ref_shape: shape model over the K reference pixels (rays with z = 1).
        ref_ids: (K,) index into ``ref_shape_keys`` of each reference pixel.
        tgt_shape_keys: keys of the target primitives' shape variables.
        tgt_shape: shape model over the K corresponding target pixels.
        tgt_ids: (K,) index into ``tgt_shape_keys`` of each target pixel.
        sigma: noise of the mean log-ratio (> 0; 0.02 is about 2 % in scale).
        min_depth: a point closer than this to the target camera (metres, along
            its optical axis) is left out (default 1e-3).

    Keys that own no correspondence are left out of the factor.

    Attributes:
        factor: the ``gtsam.CustomFactor`` (add it to a graph).
        keys: its keys: the two poses, then the used reference and target
            shape keys.
    """

    def __init__(self, ref_pose_key: int, tgt_pose_key: int, ref_shape_keys: Sequence[int],
                 ref_shape: ShapeModel, ref_ids: np.ndarray, tgt_shape_keys: Sequence[int],
                 tgt_shape: ShapeModel, tgt_ids: np.ndarray, sigma: float,
                 min_depth: float = 1e-3) -> None:
        ref_ids = np.asarray(ref_ids, dtype=np.int64).reshape(-1)
        tgt_ids = np.asarray(tgt_ids, dtype=np.int64).reshape(-1)
        k = ref_ids.size
        if k == 0:
            raise ValueError("DepthConsistencyFactor: no correspondence")
        if tgt_ids.size != k or ref_shape.rays.shape[0] != k or tgt_shape.rays.shape[0] != k:
            raise ValueError(f"DepthConsistencyFactor: {k} reference ids, {tgt_ids.size} target "
                             f"ids, {ref_shape.rays.shape[0]} / {tgt_shape.rays.shape[0]} rays")
        if (ref_ids.min() < 0 or ref_ids.max() >= len(ref_shape_keys) or tgt_ids.min() < 0
                or tgt_ids.max() >= len(tgt_shape_keys)):
            raise ValueError("DepthConsistencyFactor: ids out of range of the shape keys")
        sigma = float(sigma)
        if not np.isfinite(sigma) or sigma <= 0:
            raise ValueError(f"DepthConsistencyFactor: sigma must be finite and > 0, got {sigma}")
        if int(ref_pose_key) == int(tgt_pose_key):
            raise ValueError("DepthConsistencyFactor: reference and target keys must differ")
        # compact the keys to the used ones
        ref_used, self.ref_ids = np.unique(ref_ids, return_inverse=True)
        tgt_used, self.tgt_ids = np.unique(tgt_ids, return_inverse=True)
        self.ref_shape_keys = [int(ref_shape_keys[i]) for i in ref_used]
        self.tgt_shape_keys = [int(tgt_shape_keys[i]) for i in tgt_used]
        self.ref_pose_key, self.tgt_pose_key = int(ref_pose_key), int(tgt_pose_key)
        self.keys: List[int] = ([self.ref_pose_key, self.tgt_pose_key] + self.ref_shape_keys
                                + self.tgt_shape_keys)
        if len(set(self.keys)) != len(self.keys):
            raise ValueError("DepthConsistencyFactor: a key appears twice")
        self.ref_shape, self.tgt_shape = ref_shape, tgt_shape
        self.sigma = sigma
        self.min_depth = float(min_depth)
        self.n = k
        self.factor = gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, sigma), self.keys,
                                         self._error)

    def evaluate(self, T_world_ref: np.ndarray, T_world_tgt: np.ndarray, ref_thetas: np.ndarray,
                 tgt_thetas: np.ndarray, jacobians: bool = True) -> dict:
        """The residual ``r`` (float), the per-correspondence log-ratios
        ``d`` (K,) with their validity, and, if asked, the Jacobians
        ``J_ref`` (6,), ``J_tgt`` (6,), ``J_ref_shape`` (N_ref, dim),
        ``J_tgt_shape`` (N_tgt, dim), in the order of the used keys."""
        ref_thetas = np.asarray(ref_thetas, dtype=np.float64).reshape(len(self.ref_shape_keys), -1)
        tgt_thetas = np.asarray(tgt_thetas, dtype=np.float64).reshape(len(self.tgt_shape_keys), -1)
        X, dX, ok_ref = self.ref_shape.points(ref_thetas[self.ref_ids])
        Xt, dXt, ok_tgt = self.tgt_shape.points(tgt_thetas[self.tgt_ids])
        R_wt, R_wr = T_world_tgt[:3, :3], T_world_ref[:3, :3]
        R = R_wt.T @ R_wr
        t = R_wt.T @ (T_world_ref[:3, 3] - T_world_tgt[:3, 3])
        Y = X @ R.T + t
        z, Z = Y[:, 2], Xt[:, 2]
        valid = ok_ref & ok_tgt & (z > self.min_depth) & (Z > 0)
        zs, Zs = np.where(valid, z, 1.0), np.where(valid, Z, 1.0)
        d = np.where(valid, np.log(zs) - np.log(Zs), 0.0)
        out = {"r": float(d.sum()) / self.n, "d": d, "valid": valid}
        if not jacobians:
            return out
        g = np.zeros((self.n, 3))
        g[:, 2] = np.where(valid, 1.0 / (self.n * zs), 0.0)
        gR = g @ R
        J = np.empty((self.n, 6))
        _cross_into(X, gR, J[:, :3])
        J[:, 3:] = gR
        out["J_ref"] = J.sum(0)
        _cross_into(g, Y, J[:, :3])
        J[:, 3:] = -g
        out["J_tgt"] = J.sum(0)
        per_ref = np.einsum("ki,kij->kj", gR, dX)
        per_tgt = -np.where(valid, 1.0 / (self.n * Zs), 0.0)[:, None] * dXt[:, 2, :]
        out["J_ref_shape"] = np.stack(
            [np.bincount(self.ref_ids, weights=per_ref[:, j], minlength=len(self.ref_shape_keys))
             for j in range(per_ref.shape[1])], 1)
        out["J_tgt_shape"] = np.stack(
            [np.bincount(self.tgt_ids, weights=per_tgt[:, j], minlength=len(self.tgt_shape_keys))
             for j in range(per_tgt.shape[1])], 1)
        return out

    def _error(self, this: gtsam.CustomFactor, values: gtsam.Values,
               H: Optional[List[np.ndarray]]) -> np.ndarray:
        T_wr = values.atPose3(self.ref_pose_key).matrix()
        T_wt = values.atPose3(self.tgt_pose_key).matrix()
        th_r = np.array([values.atVector(k) for k in self.ref_shape_keys])
        th_t = np.array([values.atVector(k) for k in self.tgt_shape_keys])
        res = self.evaluate(T_wr, T_wt, th_r, th_t, jacobians=H is not None)
        if H is not None:
            H[0] = res["J_ref"].reshape(1, 6)
            H[1] = res["J_tgt"].reshape(1, 6)
            n_r = len(self.ref_shape_keys)
            for i in range(n_r):
                H[2 + i] = res["J_ref_shape"][i:i + 1]
            for i in range(len(self.tgt_shape_keys)):
                H[2 + n_r + i] = res["J_tgt_shape"][i:i + 1]
        return np.array([res["r"]])
