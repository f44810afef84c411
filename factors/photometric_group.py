"""The per-primitive photometric factors of one frame pair, evaluated as one group.

Same cost, residuals and Jacobians as the per-primitive
:class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` (docs/design.md §4).
:mod:`spgeo.factors.photometric` re-exports :class:`PhotometricFactorGroup`.
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

import gtsam

from spgeo.camera import PinholeCamera

from . import kernels
from .photometric import PhotometricConfig, ShapeModel, photometric_rows

__all__ = ["PhotometricFactorGroup", "release_groups"]


class PhotometricFactorGroup:
    """The per-primitive factors of one (reference frame, target frame) pair,
    evaluated together.

    Factor ``i`` is exactly the :class:`PrimitivePhotometricFactor` of
    primitive ``i`` (same keys, residuals and Jacobians: tested); the group
    only shares the work.  When gtsam linearises (or evaluates) the graph it
    calls every factor with the same ``Values``: the first call evaluates all
    primitives in one vectorised pass and caches the result, the others read
    their rows.  A cached result is reused only if the poses, the brightness
    and the calling factor's own shape variable are bit-identical to the ones
    it was computed with (a primitive's rows depend on nothing else), so a
    stale cache can never be served.

    Args:
        ref_key, tgt_key: keys of ``T_world_ref`` / ``T_world_tgt`` (Pose3).
        shape_keys: (N,) key of each primitive's shape variable.
        shape: one :class:`ScaledShape` / :class:`PlanarShape` over the
            concatenated pixels of all N primitives.
        offsets: (N + 1,) primitive ``i`` owns rows ``offsets[i]:offsets[i+1]``
            (each non-empty).
        ref_intensity: (K,) reference intensities in [0, 1], concatenated.
        target_image, target_camera, brightness_key, config: as for
            :class:`PrimitivePhotometricFactor` (one brightness for the pair).
        n_pixels: (N,) ``|Omega|`` per primitive for ``normalise="all"``
            (default: the row counts).

        chunk: primitives per gtsam factor (default 1: one factor per
            primitive, exactly :class:`PrimitivePhotometricFactor`).  With
            ``chunk = c > 1`` factor ``j`` covers primitives ``j c .. j c + c -
            1`` (keys: the two poses, their ``c`` shape variables, the
            brightness) in *square-root form*: instead of its pixel rows it
            returns ``c * dim + m + 1`` rows ``[R | z]`` (``m`` = 12 pose + 2
            brightness columns) with ``R^T R = J^T J``, ``R^T z = J^T e`` and
            ``|z| = |e|`` (:meth:`_compressed`), so the cost, the Gauss-Newton
            system and every gtsam optimiser step are those of the per-primitive
            factors (tested), while gtsam makes one Python callback per chunk
            instead of per primitive (each callback copies the whole
            ``Values``) and its dense blocks do not grow with the pixel count.
            A cost-only call returns ``(|e|, 0, ..., 0)``; a chunk factor's
            error vector is therefore not differentiable row by row: check
            Jacobians on ``chunk=1`` (the factor tests do) and the chunks
            against them.

    ``factors`` lists the gtsam.CustomFactor objects (add them all).
    """

    def __init__(self, ref_key: int, tgt_key: int, shape_keys, shape: ShapeModel,
                 offsets: np.ndarray, ref_intensity: np.ndarray, target_image: np.ndarray,
                 target_camera: PinholeCamera, brightness_key: Optional[int] = None,
                 config: PhotometricConfig = PhotometricConfig(),
                 n_pixels: Optional[np.ndarray] = None, chunk: int = 1) -> None:
        self.shape_keys = [int(k) for k in shape_keys]
        self.offsets = np.asarray(offsets, dtype=np.int64).reshape(-1)
        n = len(self.shape_keys)
        sizes = np.diff(self.offsets)
        if n == 0 or self.offsets.size != n + 1 or self.offsets[0] != 0 or np.any(sizes < 1):
            raise ValueError("PhotometricFactorGroup: offsets must be (N+1,) from 0 with every "
                             "primitive non-empty, N = len(shape_keys) >= 1")
        self.ref_intensity = np.asarray(ref_intensity, dtype=np.float64).reshape(-1)
        k = int(self.offsets[-1])
        if self.ref_intensity.size != k or shape.rays.shape[0] != k:
            raise ValueError(f"PhotometricFactorGroup: {k} rows in offsets, "
                             f"{self.ref_intensity.size} intensities, {shape.rays.shape[0]} rays")
        if not np.all(np.isfinite(self.ref_intensity)):
            raise ValueError("reference intensities contain NaN or inf")
        img = np.asarray(target_image)
        if img.ndim != 2 or img.shape != target_camera.shape:
            raise ValueError(f"target image must be (H, W) matching the camera "
                             f"{target_camera.shape}, got {img.shape}")
        if ref_key == tgt_key:
            raise ValueError("reference and target keys must differ")
        self.ref_key, self.tgt_key = int(ref_key), int(tgt_key)
        self.brightness_key = brightness_key
        self.shape = shape
        self.target_image = img
        self.camera = target_camera
        self.config = config
        self.ids = np.repeat(np.arange(n), sizes)
        self.n_pixels = (sizes.astype(np.float64) if n_pixels is None
                         else np.asarray(n_pixels, dtype=np.float64).reshape(n))
        self._cache: Optional[dict] = None
        self.n_batch_evaluations = 0
        if int(chunk) < 1:
            raise ValueError("PhotometricFactorGroup: chunk must be >= 1")
        self.chunks = [np.arange(a, min(a + int(chunk), n)) for a in range(0, n, int(chunk))]
        # columns shared by every row: both poses and the brightness
        self._n_pose_cols = 12 + (2 if brightness_key is not None else 0)
        self._chunk_rows = np.array([self.offsets[c[0]] for c in self.chunks] + [k])
        self._chunk_keys = [[self.shape_keys[i] for i in prims] for prims in self.chunks]
        self.factors = []
        for j, prims in enumerate(self.chunks):
            keys = [self.ref_key, self.tgt_key] + self._chunk_keys[j]
            if brightness_key is not None:
                keys.append(int(brightness_key))
            rows = (int(sizes[prims].sum()) if prims.size == 1
                    else prims.size * shape.dim + self._n_pose_cols + 1)
            noise = gtsam.noiseModel.Unit.Create(rows)
            self.factors.append(gtsam.CustomFactor(
                noise, keys, lambda this, v, H, j=j: self._error(j, v, H)))

    def __len__(self) -> int:
        return len(self.shape_keys)

    def release(self) -> None:
        """Forget the gtsam factors and the cached evaluation, for an owner
        that no longer needs the group (its factors left the graph).

        Each factor's callback holds the group, and ``factors`` holds the
        factors: a reference cycle through gtsam that Python's collector cannot
        see, so a group is otherwise never freed.  After :meth:`release` the
        factors still evaluate (they keep the group alive while gtsam holds
        them) and the group is freed with the last of them; ``factors`` is
        empty."""
        self.factors = []
        self.forget_cache()

    def forget_cache(self) -> None:
        """Drop the cached evaluation (repeated calls at equal values are served from
        it): the next call evaluates again (a benchmark times every call)."""
        self._cache = None

    def evaluate(self, T_world_ref: np.ndarray, T_world_tgt: np.ndarray, thetas: np.ndarray,
                 brightness: Optional[np.ndarray] = None, jacobians: bool = True) -> dict:
        """All rows at once; ``thetas`` is (N, dim).  Same keys as
        :meth:`PrimitivePhotometricFactor.evaluate`, concatenated in primitive order."""
        thetas = np.asarray(thetas, dtype=np.float64).reshape(len(self), -1)
        X, dX, shape_valid = self.shape.points(thetas[self.ids])
        br = brightness if self.brightness_key is not None else None
        return photometric_rows(X, dX, shape_valid, T_world_ref, T_world_tgt, self.target_image,
                                self.camera, self.ref_intensity, br, self.config, self.ids,
                                len(self), self.n_pixels, jacobians)

    def evaluate_at(self, values: gtsam.Values, jacobians: bool = False) -> dict:
        """:meth:`evaluate` at the poses, shape variables and brightness in
        ``values`` (all of the group's keys must be there)."""
        thetas = np.array([values.atVector(k) for k in self.shape_keys])
        br = values.atVector(self.brightness_key) if self.brightness_key is not None else None
        return self.evaluate(values.atPose3(self.ref_key).matrix(),
                             values.atPose3(self.tgt_key).matrix(), thetas, br, jacobians)

    def _read_thetas(self, values: gtsam.Values, prims: np.ndarray,
                     own: np.ndarray) -> np.ndarray:
        """All shape variables from ``values`` (a key gtsam left out keeps a
        stale entry: its rows are never served, the cache checks each
        caller's own variables)."""
        thetas = np.zeros((len(self), own.shape[1]))
        for i, key in enumerate(self.shape_keys):
            if values.exists(key):
                thetas[i] = values.atVector(key)
        thetas[prims] = own
        return thetas

    def _compressed(self, res: dict) -> List[np.ndarray]:
        """Per multi-primitive chunk, a square-root form ``[R | z]`` of its
        rows' ``[J | e]``: ``c * dim + m + 1`` rows (``m`` pose and brightness
        columns) with ``[R z]^T [R z] = [J e]^T [J e]``, so the same Gauss-Newton
        Hessian ``J^T J``, gradient ``J^T e`` and cost ``e^T e``.  Columns:
        ``m`` pose / brightness, then ``dim`` per primitive, then ``z``.

        Each primitive's rows depend on its own shape variable only, so the
        shape columns are block-diagonal; the primitive's ``dim`` rows of ``R``
        come from its ``dim x dim`` Gram block in closed form, and the pose /
        brightness remainder (Schur complement) from a ``(m+1)``-square
        eigen-decomposition.  Built once per linearisation, cached in ``res``.
        """
        if "compressed" in res:
            return res["compressed"]
        J_s = res["J_shape"]
        d = J_s.shape[1]
        parts = [res["J_ref"], res["J_tgt"]]
        if self.brightness_key is not None:
            parts.append(res["J_brightness"])
        m1 = self._n_pose_cols + 1
        if "pose_rows_and_e" in res:
            # compiled rows: the Gram blocks in one compiled pass over them
            G_ss = np.empty((len(self), d, d))
            G_sa = np.empty((len(self), d, m1))
            AtA = np.empty((len(self.chunks), m1, m1))
            kernels.chunk_grams(res["pose_rows_and_e"], J_s, self.offsets, self._chunk_rows,
                                G_ss, G_sa, AtA)
        else:
            Ae = np.column_stack(parts + [res["e"]])            # (K, m + 1)
            starts = self.offsets[:-1]
            if d == 1:
                s = J_s[:, 0]
                G_ss = np.add.reduceat(s * s, starts)[:, None, None]                # (N, 1, 1)
                G_sa = np.add.reduceat(s[:, None] * Ae, starts)[:, None, :]         # (N, 1, m+1)
            else:
                G_ss = np.add.reduceat(J_s[:, :, None] * J_s[:, None, :], starts)  # (N, d, d)
                G_sa = np.add.reduceat(J_s[:, :, None] * Ae[:, None, :], starts)   # (N, d, m+1)
            AtA = [None if p.size == 1 else
                   Ae[self._chunk_rows[j]:self._chunk_rows[j + 1]].T
                   @ Ae[self._chunk_rows[j]:self._chunk_rows[j + 1]]
                   for j, p in enumerate(self.chunks)]
        lam, V = np.linalg.eigh(G_ss)
        tol = 1e-12 * max(float(lam.max()), 1e-300)
        ok = lam > tol
        root = np.sqrt(np.where(ok, lam, 0.0))
        inv_root = np.where(ok, 1.0 / np.where(ok, root, 1.0), 0.0)
        Vt = np.swapaxes(V, 1, 2)
        U_ss = root[:, :, None] * Vt                                                 # (N, d, d)
        U_sa = inv_root[:, :, None] * (Vt @ G_sa)                                    # (N, d, m+1)
        out = []
        for j, prims in enumerate(self.chunks):
            if prims.size == 1:
                out.append(None)
                continue
            c = prims.size
            rows_s = U_sa[prims].reshape(c * d, m1)
            M = AtA[j] - rows_s.T @ rows_s            # pose / brightness Schur complement
            mu, W = np.linalg.eigh(0.5 * (M + M.T))
            W_rows = np.sqrt(np.maximum(mu, 0.0))[:, None] * W.T                    # (m+1, m+1)
            C = np.zeros((c * d + m1, c * d + m1))       # rows x (m pose, c*d shape, z)
            C[:c * d, :m1 - 1] = rows_s[:, :-1]
            C[:c * d, -1] = rows_s[:, -1]
            ii = np.arange(c)[:, None, None] * d
            C[ii + np.arange(d)[None, :, None],
              m1 - 1 + ii + np.arange(d)[None, None, :]] = U_ss[prims]
            C[c * d:, :m1 - 1] = W_rows[:, :-1]
            C[c * d:, -1] = W_rows[:, -1]
            out.append(C)
        res["compressed"] = out
        return out

    def _chunk_norms(self, res: dict) -> np.ndarray:
        """|e| of each chunk's rows, cached in ``res``."""
        if "chunk_norm" not in res:
            res["chunk_norm"] = np.sqrt(np.add.reduceat(res["e"] ** 2, self._chunk_rows[:-1]))
        return res["chunk_norm"]

    def _error(self, j: int, values: gtsam.Values, H: Optional[List[np.ndarray]]) -> np.ndarray:
        prims = self.chunks[j]
        T_wr = values.atPose3(self.ref_key).matrix()
        T_wt = values.atPose3(self.tgt_key).matrix()
        own = np.array([values.atVector(k) for k in self._chunk_keys[j]], dtype=np.float64)
        br = (np.asarray(values.atVector(self.brightness_key), dtype=np.float64)
              if self.brightness_key is not None else None)
        c = self._cache
        hit = (c is not None and (H is None or c["jacobians"])
               and bool((c["thetas"][prims] == own).all())
               and bool((c["T_wr"] == T_wr).all()) and bool((c["T_wt"] == T_wt).all())
               and (br is None or bool((c["br"] == br).all())))
        if not hit:
            thetas = own if prims.size == len(self) else self._read_thetas(values, prims, own)
            res = self.evaluate(T_wr, T_wt, thetas, br, jacobians=H is not None)
            self.n_batch_evaluations += 1
            c = self._cache = {"T_wr": T_wr, "T_wt": T_wt, "br": br, "thetas": thetas,
                               "jacobians": H is not None, "res": res}
        res = c["res"]
        if prims.size == 1:
            a, b = self.offsets[prims[0]], self.offsets[prims[0] + 1]
            if H is not None:
                H[0] = res["J_ref"][a:b]
                H[1] = res["J_tgt"][a:b]
                H[2] = res["J_shape"][a:b]
                if self.brightness_key is not None:
                    H[3] = res["J_brightness"][a:b]
            return res["e"][a:b]
        if H is None:
            # the cost only: any vector of the factor's dimension with the rows' norm
            z = np.zeros(prims.size * self.shape.dim + self._n_pose_cols + 1)
            z[0] = self._chunk_norms(res)[j]
            return z
        C = self._compressed(res)[j]
        d = self.shape.dim
        H[0] = C[:, 0:6]
        H[1] = C[:, 6:12]
        base = self._n_pose_cols
        for m in range(prims.size):
            H[2 + m] = C[:, base + m * d:base + (m + 1) * d]
        if self.brightness_key is not None:
            H[2 + prims.size] = C[:, 12:14]
        return C[:, -1]


def release_groups(groups) -> None:
    """:meth:`PhotometricFactorGroup.release` of every group in ``groups`` (an
    owner done with them: their factors left, or are about to leave, the graph)."""
    for g in groups:
        g.release()
