"""Features, matching and two-view / PnP geometry of the feature VO baseline.

:class:`FeatureGeometry` holds the detector (ORB or SIFT, bucketed on a grid),
the ratio-test matcher, triangulation with cheirality / parallax /
reprojection checks, PnP (``cv2.solvePnPRansac`` + Levenberg-Marquardt) and the
essential-matrix initialisation; :class:`FeatureVOConfig` holds the options of
the whole baseline (:mod:`.feature_vo`).  Poses here are world-to-camera
``T_cw`` (4x4); pixels are (u, v) float64.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

import cv2
import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.geometry import invert_pose

__all__ = ["FeatureVOConfig", "Features", "FeatureGeometry", "gray_u8", "fractional_velocity"]

logger = logging.getLogger(__name__)


@dataclass
class FeatureVOConfig:
    """Options of the feature VO baseline (:class:`~.feature_vo.FeatureVO`).

    Attributes:
        detector: ``"orb"`` (default) or ``"sift"``.
        n_features: features kept per frame (default 1000).
        grid: (columns, rows) of the bucketing grid (default (8, 6)).
        orb_patch_size: ORB patch/edge size; None (default) = 31 for images at
            least 240 px high, proportionally smaller (>= 11) below.
        orb_levels: ORB pyramid levels (default 6), scale factor 1.2.
        fast_threshold: ORB FAST threshold (default 7; the bucketing keeps the best).
        ratio: Lowe ratio test (default 0.8).
        init_min_flow: median feature displacement needed to try initialising,
            as a fraction of the image diagonal (default 0.02).
        init_min_parallax_deg: median triangulation angle to accept it, in
            degrees (default 3.0).
        init_min_cheirality: fraction of the essential-matrix inliers that must
            triangulate in front of both cameras (default 0.97).
        init_min_points: triangulated points needed (default 60).
        init_max_frames: frames tried against one reference before the
            reference is moved forward (default 40).
        ransac_threshold_px: RANSAC threshold of the essential matrix and PnP,
            in pixels at 640 px width (scaled with the image width; default 2.0).
        min_pnp_inliers: fewest PnP inliers for a tracked frame (default 25).
        local_keyframes: keyframes whose map points are matched (default 3).
        keyframe_fraction: new keyframe when the inliers fall below this
            fraction of the last keyframe's tracked points (default 0.6).
        keyframe_min_inliers: ... or below this number (default 80).
        min_triangulation_deg: smallest parallax of a new point (default 1.0).
        max_reprojection_px: largest reprojection error of a new point, at 640 px
            width (default 3.0).
        max_lost_frames: consecutive lost frames before re-initialising (default 5).
        show_progress: tqdm progress bar (default False).
    """

    detector: str = "orb"
    n_features: int = 1000
    grid: Tuple[int, int] = (8, 6)
    orb_patch_size: Optional[int] = None
    orb_levels: int = 6
    fast_threshold: int = 7
    ratio: float = 0.8
    init_min_flow: float = 0.02
    init_min_parallax_deg: float = 3.0
    init_min_cheirality: float = 0.97
    init_min_points: int = 60
    init_max_frames: int = 40
    ransac_threshold_px: float = 2.0
    min_pnp_inliers: int = 25
    local_keyframes: int = 3
    keyframe_fraction: float = 0.6
    keyframe_min_inliers: int = 80
    min_triangulation_deg: float = 1.0
    max_reprojection_px: float = 3.0
    max_lost_frames: int = 5
    show_progress: bool = False

    def __post_init__(self) -> None:
        if self.detector not in ("orb", "sift"):
            raise ValueError(f"FeatureVOConfig.detector must be 'orb' or 'sift', "
                             f"got {self.detector!r}")
        if self.n_features < 50:
            raise ValueError(f"FeatureVOConfig.n_features must be >= 50, got {self.n_features}")
        if not 0 < self.ratio <= 1:
            raise ValueError(f"FeatureVOConfig.ratio must be in (0, 1], got {self.ratio}")
        if not 0 < self.keyframe_fraction < 1:
            raise ValueError("FeatureVOConfig.keyframe_fraction must be in (0, 1)")
        if self.min_pnp_inliers < 6 or self.init_min_points < 8:
            raise ValueError("FeatureVOConfig: min_pnp_inliers >= 6 and init_min_points >= 8")
        if self.max_lost_frames < 1 or self.local_keyframes < 1:
            raise ValueError("FeatureVOConfig: max_lost_frames and local_keyframes must be >= 1")



@dataclass
class Features:
    """Features of one frame: ``uv`` (N, 2) float64 pixels, ``desc`` (N, D) or None."""

    uv: np.ndarray
    desc: Optional[np.ndarray]


class FeatureGeometry:
    """Detector, matcher and geometry of one camera; ``timings`` accumulates
    seconds per stage (``features``, ``matching``, ``pnp``, ``initialisation``,
    ``triangulation``)."""

    def __init__(self, camera: PinholeCamera, config: FeatureVOConfig) -> None:
        self.cam = camera
        self.cfg = config
        self.K = camera.K.astype(np.float64)
        self.px_scale = camera.width / 640.0
        self.timings = {k: 0.0 for k in ("features", "matching", "pnp", "initialisation",
                                         "triangulation")}
        h = camera.height
        if config.detector == "orb":
            patch = config.orb_patch_size or (31 if h >= 240 else max(11, int(31 * h / 240)))
            self.detector = cv2.ORB_create(nfeatures=config.n_features * 3, scaleFactor=1.2,
                                           nlevels=config.orb_levels, edgeThreshold=patch,
                                           patchSize=patch, fastThreshold=config.fast_threshold)
            self.norm = cv2.NORM_HAMMING
        else:
            self.detector = cv2.SIFT_create(nfeatures=config.n_features * 3)
            self.norm = cv2.NORM_L2
        self.matcher = cv2.BFMatcher(self.norm)

    # ---------------------------------------------------------- features
    def features(self, gray: np.ndarray) -> Features:
        t0 = time.perf_counter()
        kps = self.detector.detect(gray, None)
        kps = self._bucket(kps)
        desc = None
        if kps:
            kps, desc = self.detector.compute(gray, kps)
        self.timings["features"] += time.perf_counter() - t0
        if desc is None or not kps:
            return Features(np.zeros((0, 2)), None)
        return Features(np.array([k.pt for k in kps], dtype=np.float64), desc)

    def _bucket(self, kps):
        if len(kps) <= self.cfg.n_features:
            return list(kps)
        gx, gy = self.cfg.grid
        per_cell = max(1, int(math.ceil(self.cfg.n_features / (gx * gy))))
        cells: Dict[Tuple[int, int], list] = {}
        for k in kps:
            c = (min(gx - 1, int(k.pt[0] * gx / self.cam.width)),
                 min(gy - 1, int(k.pt[1] * gy / self.cam.height)))
            cells.setdefault(c, []).append(k)
        kept, rest = [], []
        for lst in cells.values():
            lst.sort(key=lambda k: -k.response)
            kept.extend(lst[:per_cell])
            rest.extend(lst[per_cell:])
        if len(kept) < self.cfg.n_features:
            rest.sort(key=lambda k: -k.response)
            kept.extend(rest[:self.cfg.n_features - len(kept)])
        return kept[:self.cfg.n_features]

    def match(self, d1: Optional[np.ndarray], d2: Optional[np.ndarray]) -> np.ndarray:
        """(M, 2) index pairs (i1, i2): ratio test + mutual uniqueness."""
        if d1 is None or d2 is None or len(d1) < 2 or len(d2) < 2:
            return np.zeros((0, 2), dtype=int)
        t0 = time.perf_counter()
        knn = self.matcher.knnMatch(d1, d2, k=2)
        pairs = {}
        for m in knn:
            if len(m) == 2 and m[0].distance < self.cfg.ratio * m[1].distance:
                if self.norm == cv2.NORM_HAMMING and m[0].distance > 64:
                    continue
                j = m[0].trainIdx
                # keep the best match per target index
                if j not in pairs or pairs[j][1] > m[0].distance:
                    pairs[j] = (m[0].queryIdx, m[0].distance)
        self.timings["matching"] += time.perf_counter() - t0
        if not pairs:
            return np.zeros((0, 2), dtype=int)
        return np.array([(q, j) for j, (q, _) in pairs.items()], dtype=int)

    # ---------------------------------------------------------- geometry
    def project(self, T_cw: np.ndarray, X: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        Xc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (Xc[:, :2] / z[:, None]) * [self.K[0, 0], self.K[1, 1]] + self.K[:2, 2]
        return uv, z

    def triangulate(self, T1: np.ndarray, T2: np.ndarray, uv1: np.ndarray,
                    uv2: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Points (M, 3) and a validity mask: cheirality, parallax, reprojection."""
        if len(uv1) == 0:
            return np.zeros((0, 3)), np.zeros(0, bool)
        P1, P2 = self.K @ T1[:3], self.K @ T2[:3]
        Xh = cv2.triangulatePoints(P1, P2, uv1.T.astype(np.float64), uv2.T.astype(np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            X = (Xh[:3] / Xh[3]).T
        ok = np.all(np.isfinite(X), axis=1)
        X = np.where(ok[:, None], X, 0.0)
        r1, z1 = self.project(T1, X)
        r2, z2 = self.project(T2, X)
        max_err = self.cfg.max_reprojection_px * self.px_scale
        ok &= (z1 > 0) & (z2 > 0)
        with np.errstate(invalid="ignore"):
            ok &= np.linalg.norm(r1 - uv1, axis=1) < max_err
            ok &= np.linalg.norm(r2 - uv2, axis=1) < max_err
        c1, c2 = invert_pose(T1)[:3, 3], invert_pose(T2)[:3, 3]
        a, b = X - c1, X - c2
        with np.errstate(invalid="ignore", divide="ignore"):
            cosang = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        ang = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
        ok &= ang > self.cfg.min_triangulation_deg
        return X, ok & np.isfinite(ang)

    def pnp(self, X: np.ndarray, uv: np.ndarray,
            T_guess: Optional[np.ndarray]) -> Tuple[Optional[np.ndarray], np.ndarray]:
        """World-to-camera pose and inlier mask, or (None, empty) on failure."""
        n = len(X)
        if n < self.cfg.min_pnp_inliers:
            return None, np.zeros(n, bool)
        t0 = time.perf_counter()
        thr = self.cfg.ransac_threshold_px * self.px_scale * 1.5
        try:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(
                X.astype(np.float64), uv.astype(np.float64), self.K, None,
                iterationsCount=200, reprojectionError=thr, confidence=0.999,
                flags=cv2.SOLVEPNP_EPNP)
            if ok and inl is not None and T_guess is not None and len(inl) < 2 * len(X) // 3:
                # constant-velocity guess as a second hypothesis (rarely needed)
                rvec0, _ = cv2.Rodrigues(T_guess[:3, :3])
                tvec0 = T_guess[:3, 3].reshape(3, 1).copy()
                r0, z0 = self.project(T_guess, X)
                with np.errstate(invalid="ignore"):
                    inl0 = np.flatnonzero((z0 > 0) & (np.linalg.norm(r0 - uv, axis=1) < thr))
                if len(inl0) > len(inl):
                    rvec, tvec, inl = rvec0, tvec0, inl0
            if not ok or inl is None or len(inl) < self.cfg.min_pnp_inliers:
                return None, np.zeros(n, bool)
            inl = inl.reshape(-1)
            rvec, tvec = cv2.solvePnPRefineLM(X[inl].astype(np.float64),
                                              uv[inl].astype(np.float64), self.K, None,
                                              rvec, tvec)
            T = np.eye(4)
            T[:3, :3] = cv2.Rodrigues(rvec)[0]
            T[:3, 3] = tvec.reshape(3)
            # final inlier set under the refined pose
            r, z = self.project(T, X)
            with np.errstate(invalid="ignore"):
                mask = (z > 0) & (np.linalg.norm(r - uv, axis=1) < thr)
            if mask.sum() < self.cfg.min_pnp_inliers or not np.all(np.isfinite(T)):
                return None, np.zeros(n, bool)
            return T, mask
        except cv2.error as exc:
            logger.debug("PnP failed: %s", exc)
            return None, np.zeros(n, bool)
        finally:
            self.timings["pnp"] += time.perf_counter() - t0

    # ------------------------------------------------------ initialisation
    def try_initialise(self, ref: Features, cur: Features
                       ) -> Optional[Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """(T_cw of cur, points (M,3), ref indices, cur indices) with the map in the
        reference camera frame and median depth 1, or None."""
        cfg = self.cfg
        t0 = time.perf_counter()
        try:
            m = self.match(ref.desc, cur.desc)
            if len(m) < cfg.init_min_points:
                return None
            u1, u2 = ref.uv[m[:, 0]], cur.uv[m[:, 1]]
            diag = math.hypot(self.cam.width, self.cam.height)
            if np.median(np.linalg.norm(u2 - u1, axis=1)) < cfg.init_min_flow * diag:
                return None
            thr = cfg.ransac_threshold_px * self.px_scale
            E, mask = cv2.findEssentialMat(u1, u2, self.K, method=cv2.USAC_MAGSAC, prob=0.999,
                                           threshold=thr)
            if E is None or E.shape != (3, 3) or mask is None:
                return None
            ransac_inl = mask.reshape(-1) > 0
            _, R, t, mask2 = cv2.recoverPose(E, u1, u2, self.K, mask=mask.copy())
            inl = mask2.reshape(-1) > 0
            # a wrong (e.g. bas-relief) solution leaves many RANSAC inliers behind a camera
            if (inl.sum() < cfg.init_min_points
                    or inl.sum() < cfg.init_min_cheirality * ransac_inl.sum()):
                return None
            R, t = _refine_two_view(self.K, u1[inl], u2[inl], R, t.reshape(3))
            T2 = np.eye(4)
            T2[:3, :3], T2[:3, 3] = R, t
            X, ok = self.triangulate(np.eye(4), T2, u1[inl], u2[inl])
            if ok.sum() < cfg.init_min_points:
                return None
            X = X[ok]
            c2 = invert_pose(T2)[:3, 3]
            a, b = X, X - c2
            ang = np.degrees(np.arccos(np.clip(np.sum(a * b, 1) / (
                np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)), -1, 1)))
            if np.median(ang) < cfg.init_min_parallax_deg:
                return None
            scale = 1.0 / float(np.median(X[:, 2]))
            X = X * scale
            T2[:3, 3] *= scale
            idx = np.flatnonzero(inl)[ok]
            return T2, X, m[idx, 0], m[idx, 1]
        except cv2.error as exc:
            logger.debug("initialisation attempt failed: %s", exc)
            return None
        finally:
            self.timings["initialisation"] += time.perf_counter() - t0



def gray_u8(image: np.ndarray) -> np.ndarray:
    """(H, W) C-contiguous uint8 grey image from grey / RGB uint8 or float [0, 1] input."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[..., 0]
        else:
            img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]).astype(np.float32),
                               cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img.astype(np.float32)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)



def _sampson(R: np.ndarray, t: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distances (normalised image units) of ``x2^T [t]x R x1 = 0``."""
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    Ex1, Etx2 = x1 @ E.T, x2 @ E
    num = np.sum(x2 * Ex1, 1)
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return num / np.sqrt(np.maximum(den, 1e-18))


def _refine_two_view(K: np.ndarray, u1: np.ndarray, u2: np.ndarray, R0: np.ndarray,
                     t0: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt-style (TRF, Huber) refinement of ``x2 = R x1 + t`` (unit
    t) on the Sampson error in pixels.  Returns the input when it does not improve."""
    from scipy.optimize import least_squares

    from spgeo.geometry import so3_exp

    f = 0.5 * (K[0, 0] + K[1, 1])
    x1 = np.c_[(u1 - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(len(u1))]
    x2 = np.c_[(u2 - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(len(u2))]
    t0 = t0 / np.linalg.norm(t0)
    a = np.array([1.0, 0, 0]) if abs(t0[0]) < 0.9 else np.array([0, 1.0, 0])
    b1 = np.cross(t0, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(t0, b1)

    def unpack(p):
        t = t0 + p[3] * b1 + p[4] * b2
        return so3_exp(p[:3]) @ R0, t / np.linalg.norm(t)

    def fun(p):
        return f * _sampson(*unpack(p), x1, x2)

    try:
        res = least_squares(fun, np.zeros(5), loss="huber", f_scale=1.0, max_nfev=50)
    except (ValueError, np.linalg.LinAlgError):
        return R0, t0
    if not res.success or not np.all(np.isfinite(res.x)):
        return R0, t0
    return unpack(res.x)


def fractional_velocity(T: np.ndarray, steps: int) -> np.ndarray:
    """Per-frame motion of a ``steps``-frame relative motion (rotation by
    axis-angle fraction, translation divided)."""
    if steps <= 1:
        return T
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec / steps)[0]
    out[:3, 3] = T[:3, 3] / steps
    return out

