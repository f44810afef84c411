"""Feature-based monocular visual odometry baseline (OpenCV).

A deliberately classical reference for the ATE tables beside spgeo
(issue 4 §2): same inputs (RGB frames + intrinsics, never depth), same
output format (TUM trajectory, camera-to-world, first posed frame = identity,
arbitrary scale).

Pipeline (one thread, keyframe based, no bundle adjustment):

1. **Features**: ORB (default; ``detector="sift"`` for SIFT) detected on a
   bucketed grid so that features cover the image.
2. **Initialisation**: the first usable frame is the reference keyframe;
   each following frame is matched to it until the median feature
   displacement exceeds ``init_min_flow`` (fraction of the image diagonal)
   and the essential matrix (``cv2.findEssentialMat``, MAGSAC) with
   ``cv2.recoverPose`` puts almost all inliers in front of both cameras, and,
   after a Sampson-error refinement, enough points triangulate with a median
   parallax above ``init_min_parallax_deg``.  The map is scaled so that the
   median depth in the reference is 1.  Frames between the reference and the
   initialising frame are posed afterwards by PnP.
3. **Tracking**: descriptors of each frame are matched (ratio test) to the
   map points seen by the last ``local_keyframes`` keyframes; the pose comes
   from ``cv2.solvePnPRansac`` (seeded by a constant-velocity guess), refined
   on the inliers with Levenberg-Marquardt.
4. **Keyframes**: when the tracked inliers fall below
   ``keyframe_fraction`` of the last keyframe's map points (or below
   ``keyframe_min_inliers``), the frame becomes a keyframe and new points are
   triangulated against the previous keyframe (parallax, cheirality and
   reprojection checks).
5. **Failure handling**: a frame with too few features, matches or PnP
   inliers is flagged ``lost`` (no pose) and the next frames try to
   re-localise against the same map; after ``max_lost_frames`` consecutive
   failures the system re-initialises a new map (``reinitialised``) whose
   origin is the last tracked pose and whose scale is matched to the last
   known speed (a heuristic: the segments' scales remain only loosely tied).
   No input ever raises inside the loop; unexpected OpenCV errors flag the
   frame.

Statuses (:data:`STATUSES`): ``initialising`` (no map yet, no pose),
``tracked``, ``lost`` (no pose), ``reinitialised`` (first posed frames of a
new map after a failure).  Use :meth:`FeatureVOResult.save_tum` to write
``trajectory.txt`` (posed frames only) plus ``trajectory.status.txt``
(every frame) and ``keyframes.txt``.

Command line::

    python -m spgeo.evaluation.feature_vo --dataset 7scenes PATH --frames 0:300 \
        --resolution 160x120 --out DIR
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.cli_args import (add_dataset_arguments, add_verbose_argument, parse_resolution,
                             setup_logging)
from spgeo.frame import Frame
from spgeo.geometry import invert_pose
from spgeo.jsonio import json_default

from .trajectory import (AteResult, ate_per_frame_and_keyframes, status_path_for, write_status,
                         write_tum)

__all__ = ["FeatureVOConfig", "FeatureVOResult", "run_feature_vo", "STATUSES", "main"]

logger = logging.getLogger(__name__)

STATUS_INITIALISING = "initialising"
STATUS_TRACKED = "tracked"
STATUS_LOST = "lost"
STATUS_REINIT = "reinitialised"
#: Every per-frame status :func:`run_feature_vo` reports.
STATUSES = (STATUS_INITIALISING, STATUS_TRACKED, STATUS_LOST, STATUS_REINIT)


@dataclass
class FeatureVOConfig:
    """Options of :func:`run_feature_vo` (defaults chosen on synthetic data).

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
        init_min_parallax_deg: median triangulation angle to accept it (default 3.0;
            wrong, bas-relief-like two-view solutions on synthetic data had
            1.2-3.1 degrees, correct ones more).
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
class FeatureVOResult:
    """Output of :func:`run_feature_vo`.

    Attributes:
        timestamps: (n,) frame timestamps (frame numbers for data sets without time).
        poses: (n, 4, 4) camera-to-world, NaN for frames without a pose; the first
            posed frame is the identity; the scale is arbitrary (median depth of the
            initial map = 1).
        status: per-frame status (:data:`STATUSES`).
        is_keyframe: (n,) bool.
        segment: (n,) int map id (0 for the first map, +1 per re-initialisation,
            -1 for frames without a pose).
        n_inliers: (n,) PnP inliers (or initial-map points) per frame.
        frame_time_s: (n,) processing time per frame.
        timings: total seconds per stage (``features``, ``matching``, ``pnp``,
            ``initialisation``, ``triangulation``, ``total``).
        names: frame names.
        config: the configuration used.
    """

    timestamps: np.ndarray
    poses: np.ndarray
    status: List[str]
    is_keyframe: np.ndarray
    segment: np.ndarray
    n_inliers: np.ndarray
    frame_time_s: np.ndarray
    timings: Dict[str, float]
    names: List[str]
    config: FeatureVOConfig = field(default_factory=FeatureVOConfig)

    @property
    def valid(self) -> np.ndarray:
        """(n,) bool: frames with a pose."""
        return np.all(np.isfinite(self.poses.reshape(len(self.poses), -1)), axis=1)

    @property
    def n_segments(self) -> int:
        return int(self.segment.max()) + 1 if np.any(self.segment >= 0) else 0

    @property
    def fps(self) -> float:
        total = self.timings.get("total", 0.0)
        return len(self.timestamps) / total if total > 0 else float("nan")

    def status_counts(self) -> Dict[str, int]:
        return {s: int(sum(1 for x in self.status if x == s)) for s in STATUSES}

    def save_tum(self, path: Union[str, Path], keyframes_only: bool = False) -> Path:
        """Write the posed frames (or keyframes) as a TUM file and every frame's
        status into ``<stem>.status.txt`` beside it.  Returns ``path``."""
        path = Path(path)
        mask = self.valid & (self.is_keyframe if keyframes_only else True)
        header = [f"spgeo feature VO baseline ({self.config.detector.upper()} + essential "
                  f"matrix + PnP); {'keyframes' if keyframes_only else 'every posed frame'}; "
                  "monocular: scale arbitrary",
                  f"frames {len(self.timestamps)}, posed {int(self.valid.sum())}, "
                  f"segments {self.n_segments}; statuses in {status_path_for(path).name}"]
        write_tum(path, self.timestamps[mask], self.poses[mask], header=header)
        write_status(status_path_for(path), self.timestamps, self.status,
                     extra={"keyframe": self.is_keyframe.astype(int).tolist(),
                            "segment": self.segment.tolist(),
                            "inliers": self.n_inliers.tolist()})
        return path

    def ate(self, gt_timestamps: Sequence[float], gt_poses: Sequence[np.ndarray],
            max_time_diff: float = 0.02) -> Dict[str, Optional[AteResult]]:
        """Sim(3) ATE, per-frame and keyframe-only (see :mod:`.trajectory`)."""
        return ate_per_frame_and_keyframes((self.timestamps, self.poses),
                                           (gt_timestamps, gt_poses), self.is_keyframe,
                                           max_time_diff=max_time_diff)

    def summary(self) -> Dict[str, object]:
        return {"n_frames": len(self.timestamps), "n_posed": int(self.valid.sum()),
                "n_keyframes": int(self.is_keyframe.sum()), "n_segments": self.n_segments,
                "status_counts": self.status_counts(), "fps": self.fps,
                "timings_s": dict(self.timings), "config": asdict(self.config)}


# ================================================================ internals
@dataclass
class _Features:
    uv: np.ndarray          # (N, 2) float64 pixels
    desc: Optional[np.ndarray]  # (N, D) or None


@dataclass
class _Keyframe:
    index: int
    T_cw: np.ndarray        # world-to-camera 4x4
    feats: _Features
    point_ids: np.ndarray   # (N,) int, -1 = no map point


class _Map:
    def __init__(self) -> None:
        self.points = np.zeros((0, 3))
        self.keyframes: List[_Keyframe] = []

    def add_points(self, X: np.ndarray) -> np.ndarray:
        start = len(self.points)
        self.points = np.vstack([self.points, X.reshape(-1, 3)])
        return np.arange(start, start + len(X))


class _FeatureVO:
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
    def features(self, gray: np.ndarray) -> _Features:
        t0 = time.perf_counter()
        kps = self.detector.detect(gray, None)
        kps = self._bucket(kps)
        desc = None
        if kps:
            kps, desc = self.detector.compute(gray, kps)
        self.timings["features"] += time.perf_counter() - t0
        if desc is None or not kps:
            return _Features(np.zeros((0, 2)), None)
        return _Features(np.array([k.pt for k in kps], dtype=np.float64), desc)

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
    def try_initialise(self, ref: _Features, cur: _Features
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


def _gray_u8(image: np.ndarray) -> np.ndarray:
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


def run_feature_vo(frames: Sequence[Union[Frame, np.ndarray]],
                   camera: Optional[PinholeCamera] = None,
                   config: Optional[FeatureVOConfig] = None,
                   timestamps: Optional[Sequence[float]] = None) -> FeatureVOResult:
    """Run the feature-based VO baseline over a sequence.

    Args:
        frames: :class:`~spgeo.frame.Frame` objects (only ``image``,
            ``timestamp``, ``name`` are used: never depth or ground truth) or
            images (H, W[, 3]) float in [0, 1] or uint8.
        camera: intrinsics (default: the first Frame's camera; required for raw
            images).  Images must be undistorted.
        config: :class:`FeatureVOConfig` (default options if None).
        timestamps: for raw images (default: the index).

    Returns a :class:`FeatureVOResult`; tracking failures are flagged per frame,
    never raised.  Raises ``ValueError`` only for invalid arguments (no frames,
    no camera, an image of the wrong size).
    """
    cfg = config or FeatureVOConfig()
    frames = list(frames)
    if not frames:
        raise ValueError("run_feature_vo: no frames")
    if camera is None:
        if not isinstance(frames[0], Frame):
            raise ValueError("run_feature_vo: camera is required for raw images")
        camera = frames[0].camera
    if camera.distortion is not None and np.any(np.asarray(camera.distortion) != 0):
        logger.warning("run_feature_vo: camera has distortion coefficients; images are assumed "
                       "undistorted and the distortion is ignored")
    n = len(frames)
    if timestamps is None:
        timestamps = [f.timestamp if isinstance(f, Frame) else float(i)
                      for i, f in enumerate(frames)]
    timestamps = np.asarray(timestamps, dtype=np.float64)
    if timestamps.shape != (n,):
        raise ValueError(f"run_feature_vo: {timestamps.size} timestamps for {n} frames")
    names = [f.name if isinstance(f, Frame) and f.name else f"{i:06d}"
             for i, f in enumerate(frames)]

    vo = _FeatureVO(camera, cfg)
    poses = np.full((n, 4, 4), np.nan)           # camera-to-world
    status = [STATUS_INITIALISING] * n
    is_kf = np.zeros(n, bool)
    segment = np.full(n, -1)
    n_inl = np.zeros(n, int)
    ftime = np.zeros(n)

    # state
    world_map: Optional[_Map] = None
    seg = -1
    ref: Optional[Tuple[int, _Features]] = None     # initialisation reference
    pending: List[Tuple[int, _Features]] = []       # frames awaiting a pose after init
    last_good: Optional[int] = None                 # last posed frame index
    T_cw_prev: Optional[np.ndarray] = None
    velocity = np.eye(4)                            # T_cw(k) @ inv(T_cw(k-1)), per frame
    n_lost = 0
    anchor = np.eye(4)                              # world pose of a new map's origin
    anchor_scale = 1.0
    speed_hist: List[float] = []
    kf_tracked = 0

    def world_T_cw(T_cw_map: np.ndarray) -> np.ndarray:
        """Map-frame world-to-camera -> global camera-to-world."""
        T_wc_map = invert_pose(T_cw_map)
        T_wc_map[:3, 3] *= anchor_scale
        return anchor @ T_wc_map

    def local_points(m: _Map) -> Tuple[np.ndarray, np.ndarray]:
        ids_seen, descs = [], []
        seen = set()
        for kf in reversed(m.keyframes[-cfg.local_keyframes:]):
            for j in np.flatnonzero(kf.point_ids >= 0):
                pid = int(kf.point_ids[j])
                if pid not in seen:
                    seen.add(pid)
                    ids_seen.append(pid)
                    descs.append(kf.feats.desc[j])
        if not ids_seen:
            return np.zeros(0, int), None
        return np.array(ids_seen), np.array(descs)

    def track(i: int, feats: _Features, guess: Optional[np.ndarray]):
        ids, descs = local_points(world_map)
        m = vo.match(descs, feats.desc)
        if len(m) < cfg.min_pnp_inliers:
            return None, m, np.zeros(len(m), bool), ids
        T, inl = vo.pnp(world_map.points[ids[m[:, 0]]], feats.uv[m[:, 1]], guess)
        return T, m, inl, ids

    def make_keyframe(i: int, feats: _Features, T_cw: np.ndarray, m: np.ndarray,
                      inl: np.ndarray, ids: np.ndarray) -> int:
        point_ids = np.full(len(feats.uv), -1)
        point_ids[m[inl, 1]] = ids[m[inl, 0]]
        t0 = time.perf_counter()
        # triangulate still-unmapped features against the local keyframes (newest first)
        for kf in reversed(world_map.keyframes[-cfg.local_keyframes:]):
            mm = vo.match(kf.feats.desc, feats.desc)
            if len(mm):
                free = (kf.point_ids[mm[:, 0]] < 0) & (point_ids[mm[:, 1]] < 0)
                mm = mm[free]
            if len(mm) == 0:
                continue
            X, ok = vo.triangulate(kf.T_cw, T_cw, kf.feats.uv[mm[:, 0]], feats.uv[mm[:, 1]])
            if ok.any():
                new_ids = world_map.add_points(X[ok])
                kf.point_ids[mm[ok, 0]] = new_ids
                point_ids[mm[ok, 1]] = new_ids
        vo.timings["triangulation"] += time.perf_counter() - t0
        world_map.keyframes.append(_Keyframe(i, T_cw, feats, point_ids))
        is_kf[i] = True
        return int((point_ids >= 0).sum())

    try:
        from tqdm import tqdm
        iterator = tqdm(range(n), desc="feature VO", unit="frame", disable=not cfg.show_progress)
    except ImportError:  # pragma: no cover
        iterator = range(n)

    t_total = time.perf_counter()
    for i in iterator:
        t_frame = time.perf_counter()
        try:
            f = frames[i]
            img = f.image if isinstance(f, Frame) else f
            camera.check_image(img, f"frame {names[i]}")
            gray = _gray_u8(img)
            feats = vo.features(gray)
            n_feat = len(feats.uv)

            if world_map is None:
                # ------------------------------------------------ initialising
                if n_feat < cfg.init_min_points:
                    status[i] = STATUS_INITIALISING if seg < 0 else STATUS_LOST
                    continue
                if ref is None or i - ref[0] > cfg.init_max_frames:
                    ref, pending = (i, feats), []
                    status[i] = STATUS_INITIALISING if seg < 0 else STATUS_LOST
                    continue
                res = vo.try_initialise(ref[1], feats)
                if res is None:
                    pending.append((i, feats))
                    status[i] = STATUS_INITIALISING if seg < 0 else STATUS_LOST
                    continue
                T2, X, i_ref, i_cur = res
                seg += 1
                world_map = _Map()
                ids = world_map.add_points(X)
                pid_ref = np.full(len(ref[1].uv), -1)
                pid_ref[i_ref] = ids
                pid_cur = np.full(n_feat, -1)
                pid_cur[i_cur] = ids
                if seg > 0:
                    # re-initialisation: continue from the last tracked pose, speed-matched
                    anchor = poses[last_good].copy()
                    est_speed = float(np.median(speed_hist[-10:])) if speed_hist else 0.0
                    step = np.linalg.norm(T2[:3, 3])
                    anchor_scale = (est_speed * (i - ref[0]) / step
                                    if est_speed > 0 and step > 0 else 1.0)
                else:
                    anchor, anchor_scale = np.eye(4), 1.0
                world_map.keyframes.append(_Keyframe(ref[0], np.eye(4), ref[1], pid_ref))
                world_map.keyframes.append(_Keyframe(i, T2, feats, pid_cur))
                st = STATUS_TRACKED if seg == 0 else STATUS_REINIT
                for k, T in ((ref[0], np.eye(4)), (i, T2)):
                    poses[k] = world_T_cw(T)
                    status[k], segment[k], is_kf[k] = st, seg, True
                n_inl[ref[0]] = n_inl[i] = len(X)
                kf_tracked = len(X)
                # pose the frames between reference and initialisation
                for k, fk in pending:
                    Tk, mk, inlk, _ = track(k, fk, None)
                    if Tk is not None:
                        poses[k] = world_T_cw(Tk)
                        status[k], segment[k], n_inl[k] = st, seg, int(inlk.sum())
                pending, ref = [], None
                velocity = _fractional_velocity(T2, max(1, i - world_map.keyframes[0].index))
                T_cw_prev, last_good, n_lost = T2, i, 0
                continue

            # ------------------------------------------------------- tracking
            gap = i - last_good
            guess = T_cw_prev
            for _ in range(gap):
                guess = velocity @ guess
            T, m, inl, ids = track(i, feats, guess) if n_feat >= cfg.min_pnp_inliers \
                else (None, None, None, None)
            if T is None:
                status[i] = STATUS_LOST
                n_lost += 1
                if n_lost >= cfg.max_lost_frames:
                    logger.info("feature VO: %d frames lost at frame %s; re-initialising",
                                n_lost, names[i])
                    world_map, ref, pending = None, (i, feats), []
                    if n_feat < cfg.init_min_points:
                        ref = None
                continue
            n_inl[i] = int(inl.sum())
            poses[i] = world_T_cw(T)
            segment[i] = seg
            status[i] = STATUS_REINIT if (seg > 0 and status[world_map.keyframes[0].index]
                                          == STATUS_REINIT and len(world_map.keyframes) <= 2) \
                else STATUS_TRACKED
            step_vel = T @ invert_pose(T_cw_prev)
            velocity = _fractional_velocity(step_vel, gap)
            moved = float(np.linalg.norm(poses[i][:3, 3] - poses[last_good][:3, 3]))
            speed_hist.append(moved / gap)
            T_cw_prev, last_good, n_lost = T, i, 0
            if n_inl[i] < max(cfg.keyframe_min_inliers, cfg.keyframe_fraction * kf_tracked) \
                    or n_inl[i] < cfg.keyframe_min_inliers:
                kf_tracked = make_keyframe(i, feats, T, m, inl, ids)
        except (cv2.error, np.linalg.LinAlgError, FloatingPointError) as exc:
            logger.warning("feature VO: frame %s failed (%s); flagged lost", names[i], exc)
            status[i] = STATUS_LOST
            poses[i] = np.nan
            segment[i] = -1
        finally:
            ftime[i] = time.perf_counter() - t_frame

    timings = dict(vo.timings)
    timings["total"] = time.perf_counter() - t_total
    return FeatureVOResult(timestamps=timestamps, poses=poses, status=status, is_keyframe=is_kf,
                           segment=segment, n_inliers=n_inl, frame_time_s=ftime,
                           timings=timings, names=names, config=cfg)


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


def _fractional_velocity(T: np.ndarray, steps: int) -> np.ndarray:
    """Per-frame motion of a ``steps``-frame relative motion (rotation by
    axis-angle fraction, translation divided)."""
    if steps <= 1:
        return T
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec / steps)[0]
    out[:3, 3] = T[:3, 3] / steps
    return out


# ======================================================================= CLI
def resize_frames(frames: Sequence[Frame], width: int, height: int) -> List[Frame]:
    """Frames resized to ``width`` x ``height`` (area interpolation; camera via
    :meth:`PinholeCamera.resized`).  Depth is dropped (the baseline never reads it)."""
    out = []
    for f in frames:
        cam = f.camera.resized(width, height)
        img = cv2.resize(np.asarray(f.image, np.float32), (width, height),
                         interpolation=cv2.INTER_AREA)
        out.append(Frame(image=img, camera=cam, timestamp=f.timestamp, depth=None,
                         T_world_cam=f.T_world_cam, name=f.name, meta=dict(f.meta)))
    return out


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.feature_vo``: run the baseline on a data set,
    write ``trajectory.txt`` (+ ``trajectory.status.txt``), ``keyframes.txt`` and
    ``report.json`` to ``--out``, and print the Sim(3) ATE when the data set has
    ground truth.  Returns 0, or 2 for bad arguments / unreadable data."""
    parser = argparse.ArgumentParser(
        prog="python -m spgeo.evaluation.feature_vo",
        description="Feature-based monocular VO baseline (ORB + essential matrix + PnP).")
    add_dataset_arguments(parser)
    parser.add_argument("--resolution", default=None,
                        help="resize images to WIDTHxHEIGHT first (e.g. 160x120)")
    parser.add_argument("--detector", choices=("orb", "sift"), default="orb")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--max-time-diff", type=float, default=None,
                        help="ATE association tolerance (default 0.02 s, 0.1 for frame-number "
                             "timestamps)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_verbose_argument(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    from spgeo.datasets import open_dataset

    kind, path = args.dataset
    try:
        res_wh = parse_resolution(args.resolution, min_size=1) if args.resolution else None
        seq = open_dataset(kind, path, frames=args.frames, load_depth=False)
        frames = list(seq)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if len(frames) < 2:
        print("error: need at least 2 frames", file=sys.stderr)
        return 2
    if res_wh is not None:
        frames = resize_frames(frames, *res_wh)
    config = FeatureVOConfig(detector=args.detector, show_progress=not args.no_progress)
    result = run_feature_vo(frames, frames[0].camera, config)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result.save_tum(out / "trajectory.txt")
    result.save_tum(out / "keyframes.txt", keyframes_only=True)
    report: Dict[str, object] = {"dataset": kind, "path": str(path), "frames": args.frames,
                                 "resolution": args.resolution, **result.summary()}
    counts = result.status_counts()
    print(f"feature VO: {len(frames)} frames, {int(result.valid.sum())} posed, "
          f"{int(result.is_keyframe.sum())} keyframes, {result.n_segments} segment(s), "
          f"statuses {counts}, {result.fps:.1f} FPS")
    gt = [(f.timestamp, f.T_world_cam) for f in frames if f.T_world_cam is not None]
    if len(gt) >= 3:
        tol = args.max_time_diff
        if tol is None:
            stamps = np.array([f.timestamp for f in frames])
            integral = np.allclose(stamps, np.round(stamps))
            tol = 0.1 if integral else 0.02
        try:
            ates = result.ate([g[0] for g in gt], [g[1] for g in gt], max_time_diff=tol)
            report["ate"] = {k: (v.summary() if v is not None else None) for k, v in ates.items()}
            for v in ates.values():
                if v is not None:
                    print(v)
        except ValueError as exc:
            print(f"ATE not available: {exc}")
            report["ate"] = {"error": str(exc)}
    else:
        print("no ground-truth poses: ATE not computed")
    with open(out / "report.json", "w", encoding="utf-8") as fh:
        json.dump(report, fh, indent=2, default=json_default)
    print(f"wrote {out / 'trajectory.txt'}")
    return 0




if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
