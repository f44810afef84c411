"""Feature-based monocular visual odometry baseline (OpenCV).

A classical reference for the ATE tables beside spgeo: same inputs (RGB
frames + intrinsics, never depth), same output (a
:class:`~spgeo.trajectory.Trajectory`, camera-to-world, first posed frame =
identity, arbitrary scale).

Pipeline (one thread, keyframe based, no bundle adjustment; features and
geometry in :mod:`.feature_vo_frontend`):

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
   inliers is ``lost`` (no pose) and the next frames try to re-localise
   against the same map; after ``max_lost_frames`` consecutive failures the
   system re-initialises a new map (``reinit``) whose origin is the last
   tracked pose and whose scale is matched to the last known speed (a
   heuristic: the segments' scales remain only loosely tied).  No input ever
   raises inside the loop; unexpected OpenCV errors flag the frame.

Statuses (:data:`STATUSES`, values of :class:`~spgeo.trajectory.FrameStatus`):
``init`` (no map yet, no pose), ``ok``, ``lost`` (no pose), ``reinit`` (first
posed frames of a new map after a failure); keyframes are flagged by
``is_keyframe``.  :meth:`FeatureVOResult.save_tum` writes ``trajectory.txt``
(posed frames only) plus ``trajectory.status.txt`` (every frame, with
``keyframe``, ``segment`` and ``inliers`` columns).

Command line::

    python -m spgeo.evaluation.references.feature_vo --dataset 7scenes PATH --frames 0:300 \
        --resolution 160x120 --out DIR
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.apps.args import add_verbose_argument, parse_resolution
from spgeo.frame import Frame, resize_frame
from spgeo.geometry import invert_pose
from spgeo.trajectory import FrameStatus, Trajectory

from spgeo.evaluation.trajectory import default_max_time_diff
from spgeo.evaluation.runner import open_sequence, protocol_parser, run_protocol, write_json

from .feature_vo_frontend import (FeatureGeometry, Features, FeatureVOConfig,
                                  fractional_velocity, gray_u8)
from .feature_vo_result import STATUSES, FeatureVOFrame, FeatureVOResult

__all__ = ["FeatureVOConfig", "FeatureVO", "FeatureVOFrame", "FeatureVOResult",
           "run_feature_vo", "resize_frames", "STATUSES", "build_parser", "run", "main"]

logger = logging.getLogger(__name__)

# ================================================================== tracker
@dataclass
class _Keyframe:
    index: int
    T_cw: np.ndarray        # world-to-camera 4x4
    feats: Features
    point_ids: np.ndarray   # (N,) int, -1 = no map point


class _Map:
    def __init__(self) -> None:
        self.points = np.zeros((0, 3))
        self.keyframes: List[_Keyframe] = []

    def add_points(self, X: np.ndarray) -> np.ndarray:
        start = len(self.points)
        self.points = np.vstack([self.points, X.reshape(-1, 3)])
        return np.arange(start, start + len(X))


class FeatureVO:
    """Streaming feature VO (module docstring), mirroring
    :class:`spgeo.odometry.Odometry`: :meth:`track` each frame in time order,
    then :meth:`result`.

    Args:
        camera: intrinsics of the (undistorted) input images.
        config: :class:`FeatureVOConfig` (default options if None).
    """

    def __init__(self, camera: PinholeCamera, config: Optional[FeatureVOConfig] = None) -> None:
        self.camera = camera
        self.config = config or FeatureVOConfig()
        if camera.distortion is not None and np.any(np.asarray(camera.distortion) != 0):
            logger.warning("feature VO: camera has distortion coefficients; images are assumed "
                           "undistorted and the distortion is ignored")
        self.geometry = FeatureGeometry(camera, self.config)
        # per frame
        self._stamps: List[float] = []
        self._names: List[str] = []
        self._poses: List[np.ndarray] = []          # camera-to-world, NaN without a pose
        self._status: List[FrameStatus] = []
        self._is_kf: List[bool] = []
        self._segment: List[int] = []
        self._inliers: List[int] = []
        self._time: List[float] = []
        # state
        self._map: Optional[_Map] = None
        self._seg = -1
        self._ref: Optional[Tuple[int, Features]] = None     # initialisation reference
        self._pending: List[Tuple[int, Features]] = []       # frames awaiting a pose after init
        self._last_good: Optional[int] = None                # last posed frame index
        self._T_cw_prev: Optional[np.ndarray] = None
        self._velocity = np.eye(4)                 # T_cw(k) @ inv(T_cw(k-1)), per frame
        self._n_lost = 0
        self._anchor = np.eye(4)                   # world pose of a new map's origin
        self._anchor_scale = 1.0
        self._speed_hist: List[float] = []
        self._kf_tracked = 0

    # ------------------------------------------------------------ public API
    def track(self, frame: Union[Frame, np.ndarray], timestamp: Optional[float] = None,
              name: Optional[str] = None) -> FeatureVOFrame:
        """Process the next frame: a :class:`~spgeo.frame.Frame` (only ``image``,
        ``timestamp`` and ``name`` are read) or an image (H, W[, 3]) float in
        [0, 1] or uint8.  ``timestamp`` / ``name`` override the frame's
        (default for images: the frame number).  Tracking failures are flagged,
        never raised; raises ``ValueError`` for an image of the wrong size."""
        i = len(self._stamps)
        is_frame = isinstance(frame, Frame)
        if name is None:
            name = frame.name if is_frame and frame.name else f"{i:06d}"
        if timestamp is None:
            timestamp = frame.timestamp if is_frame else float(i)
        image = frame.image if is_frame else frame
        self.camera.check_image(image, f"frame {name}")
        self._stamps.append(float(timestamp))
        self._names.append(name)
        self._poses.append(np.full((4, 4), np.nan))
        self._status.append(FrameStatus.INIT)
        self._is_kf.append(False)
        self._segment.append(-1)
        self._inliers.append(0)
        self._time.append(0.0)
        t_frame = time.perf_counter()
        try:
            feats = self.geometry.features(gray_u8(image))
            if self._map is None:
                self._initialise(i, feats)
            else:
                self._track(i, feats)
        except (cv2.error, np.linalg.LinAlgError, FloatingPointError) as exc:
            logger.warning("feature VO: frame %s failed (%s); flagged lost", name, exc)
            self._status[i] = FrameStatus.LOST
            self._poses[i] = np.full((4, 4), np.nan)
            self._segment[i] = -1
        finally:
            self._time[i] = time.perf_counter() - t_frame
        return FeatureVOFrame(i, self._stamps[i], self._poses[i].copy(), self._status[i],
                              self._is_kf[i], self._segment[i], self._inliers[i], self._time[i])

    def result(self) -> Trajectory:
        """Every frame so far as a :class:`~spgeo.trajectory.Trajectory`
        (camera-to-world, NaN without a pose; extra column ``inliers``)."""
        n = len(self._stamps)
        return Trajectory(np.asarray(self._stamps, dtype=np.float64),
                          np.array(self._poses, dtype=np.float64).reshape(n, 4, 4),
                          list(self._status), np.array(self._is_kf, dtype=bool),
                          np.array(self._segment, dtype=int),
                          {"inliers": [int(v) for v in self._inliers]})

    @property
    def names(self) -> List[str]:
        """Frame names so far."""
        return list(self._names)

    @property
    def frame_time_s(self) -> np.ndarray:
        """(n,) processing seconds per frame so far."""
        return np.asarray(self._time, dtype=np.float64)

    @property
    def timings(self) -> Dict[str, float]:
        """Seconds per stage so far (:class:`~.feature_vo_frontend.FeatureGeometry`)."""
        return dict(self.geometry.timings)

    # -------------------------------------------------------------- internals
    def _world_pose(self, T_cw_map: np.ndarray) -> np.ndarray:
        """Map-frame world-to-camera -> global camera-to-world."""
        T_wc_map = invert_pose(T_cw_map)
        T_wc_map[:3, 3] *= self._anchor_scale
        return self._anchor @ T_wc_map

    def _local_points(self) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        ids_seen, descs = [], []
        seen = set()
        for kf in reversed(self._map.keyframes[-self.config.local_keyframes:]):
            for j in np.flatnonzero(kf.point_ids >= 0):
                pid = int(kf.point_ids[j])
                if pid not in seen:
                    seen.add(pid)
                    ids_seen.append(pid)
                    descs.append(kf.feats.desc[j])
        if not ids_seen:
            return np.zeros(0, int), None
        return np.array(ids_seen), np.array(descs)

    def _track_map(self, feats: Features, guess: Optional[np.ndarray]):
        """(T_cw or None, matches, inlier mask, map point ids) against the local map."""
        ids, descs = self._local_points()
        m = self.geometry.match(descs, feats.desc)
        if len(m) < self.config.min_pnp_inliers:
            return None, m, np.zeros(len(m), bool), ids
        T, inl = self.geometry.pnp(self._map.points[ids[m[:, 0]]], feats.uv[m[:, 1]], guess)
        return T, m, inl, ids

    def _make_keyframe(self, i: int, feats: Features, T_cw: np.ndarray, m: np.ndarray,
                       inl: np.ndarray, ids: np.ndarray) -> int:
        geo, world_map = self.geometry, self._map
        point_ids = np.full(len(feats.uv), -1)
        point_ids[m[inl, 1]] = ids[m[inl, 0]]
        t0 = time.perf_counter()
        # triangulate still-unmapped features against the local keyframes (newest first)
        for kf in reversed(world_map.keyframes[-self.config.local_keyframes:]):
            mm = geo.match(kf.feats.desc, feats.desc)
            if len(mm):
                free = (kf.point_ids[mm[:, 0]] < 0) & (point_ids[mm[:, 1]] < 0)
                mm = mm[free]
            if len(mm) == 0:
                continue
            X, ok = geo.triangulate(kf.T_cw, T_cw, kf.feats.uv[mm[:, 0]], feats.uv[mm[:, 1]])
            if ok.any():
                new_ids = world_map.add_points(X[ok])
                kf.point_ids[mm[ok, 0]] = new_ids
                point_ids[mm[ok, 1]] = new_ids
        geo.timings["triangulation"] += time.perf_counter() - t0
        world_map.keyframes.append(_Keyframe(i, T_cw, feats, point_ids))
        self._is_kf[i] = True
        return int((point_ids >= 0).sum())

    def _initialise(self, i: int, feats: Features) -> None:
        """No map: wait for a reference, try the two-view initialisation."""
        cfg = self.config
        n_feat = len(feats.uv)
        waiting = FrameStatus.INIT if self._seg < 0 else FrameStatus.LOST
        if n_feat < cfg.init_min_points:
            self._status[i] = waiting
            return
        if self._ref is None or i - self._ref[0] > cfg.init_max_frames:
            self._ref, self._pending = (i, feats), []
            self._status[i] = waiting
            return
        res = self.geometry.try_initialise(self._ref[1], feats)
        if res is None:
            self._pending.append((i, feats))
            self._status[i] = waiting
            return
        T2, X, i_ref, i_cur = res
        ref_i, ref_feats = self._ref
        self._seg += 1
        seg = self._seg
        world_map = self._map = _Map()
        ids = world_map.add_points(X)
        pid_ref = np.full(len(ref_feats.uv), -1)
        pid_ref[i_ref] = ids
        pid_cur = np.full(n_feat, -1)
        pid_cur[i_cur] = ids
        if seg > 0:
            # re-initialisation: continue from the last tracked pose, speed-matched
            self._anchor = self._poses[self._last_good].copy()
            est_speed = float(np.median(self._speed_hist[-10:])) if self._speed_hist else 0.0
            step = np.linalg.norm(T2[:3, 3])
            self._anchor_scale = (est_speed * (i - ref_i) / step
                                  if est_speed > 0 and step > 0 else 1.0)
        else:
            self._anchor, self._anchor_scale = np.eye(4), 1.0
        world_map.keyframes.append(_Keyframe(ref_i, np.eye(4), ref_feats, pid_ref))
        world_map.keyframes.append(_Keyframe(i, T2, feats, pid_cur))
        st = FrameStatus.OK if seg == 0 else FrameStatus.REINIT
        for k, T in ((ref_i, np.eye(4)), (i, T2)):
            self._poses[k] = self._world_pose(T)
            self._status[k], self._segment[k], self._is_kf[k] = st, seg, True
        self._inliers[ref_i] = self._inliers[i] = len(X)
        self._kf_tracked = len(X)
        # pose the frames between reference and initialisation
        for k, fk in self._pending:
            Tk, _, inlk, _ = self._track_map(fk, None)
            if Tk is not None:
                self._poses[k] = self._world_pose(Tk)
                self._status[k], self._segment[k], self._inliers[k] = st, seg, int(inlk.sum())
        self._pending, self._ref = [], None
        self._velocity = fractional_velocity(T2, max(1, i - world_map.keyframes[0].index))
        self._T_cw_prev, self._last_good, self._n_lost = T2, i, 0

    def _track(self, i: int, feats: Features) -> None:
        """PnP against the local map; a keyframe when the inliers drop."""
        cfg = self.config
        n_feat = len(feats.uv)
        gap = i - self._last_good
        guess = self._T_cw_prev
        for _ in range(gap):
            guess = self._velocity @ guess
        T, m, inl, ids = (self._track_map(feats, guess) if n_feat >= cfg.min_pnp_inliers
                          else (None, None, None, None))
        if T is None:
            self._status[i] = FrameStatus.LOST
            self._n_lost += 1
            if self._n_lost >= cfg.max_lost_frames:
                logger.info("feature VO: %d frames lost at frame %s; re-initialising",
                            self._n_lost, self._names[i])
                self._map, self._ref, self._pending = None, (i, feats), []
                if n_feat < cfg.init_min_points:
                    self._ref = None
            return
        n_inl = self._inliers[i] = int(inl.sum())
        self._poses[i] = self._world_pose(T)
        self._segment[i] = self._seg
        first = self._map.keyframes[0].index
        self._status[i] = (FrameStatus.REINIT if (self._seg > 0 and self._status[first]
                                                  == FrameStatus.REINIT
                                                  and len(self._map.keyframes) <= 2)
                           else FrameStatus.OK)
        self._velocity = fractional_velocity(T @ invert_pose(self._T_cw_prev), gap)
        moved = float(np.linalg.norm(self._poses[i][:3, 3] - self._poses[self._last_good][:3, 3]))
        self._speed_hist.append(moved / gap)
        self._T_cw_prev, self._last_good, self._n_lost = T, i, 0
        if n_inl < max(cfg.keyframe_min_inliers, cfg.keyframe_fraction * self._kf_tracked) \
                or n_inl < cfg.keyframe_min_inliers:
            self._kf_tracked = self._make_keyframe(i, feats, T, m, inl, ids)


def run_feature_vo(frames: Sequence[Union[Frame, np.ndarray]],
                   camera: Optional[PinholeCamera] = None,
                   config: Optional[FeatureVOConfig] = None,
                   timestamps: Optional[Sequence[float]] = None) -> FeatureVOResult:
    """Run :class:`FeatureVO` over a sequence.

    Args:
        frames: :class:`~spgeo.frame.Frame` objects (only ``image``,
            ``timestamp``, ``name`` are used: never depth or ground truth) or
            images (H, W[, 3]) float in [0, 1] or uint8.
        camera: intrinsics (default: the first Frame's camera; required for raw
            images).  Images must be undistorted.
        config: :class:`FeatureVOConfig` (default options if None).
        timestamps: per frame, overriding the frames' (default for images: the index).

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
    n = len(frames)
    if timestamps is not None:
        timestamps = np.asarray(timestamps, dtype=np.float64)
        if timestamps.shape != (n,):
            raise ValueError(f"run_feature_vo: {timestamps.size} timestamps for {n} frames")
    vo = FeatureVO(camera, cfg)
    try:
        from tqdm import tqdm
        iterator = tqdm(range(n), desc="feature VO", unit="frame", disable=not cfg.show_progress)
    except ImportError:  # pragma: no cover
        iterator = range(n)
    t_total = time.perf_counter()
    for i in iterator:
        vo.track(frames[i], None if timestamps is None else float(timestamps[i]))
    timings = vo.timings
    timings["total"] = time.perf_counter() - t_total
    return FeatureVOResult(vo.result(), vo.frame_time_s, timings, vo.names, cfg)


# ======================================================================= CLI
NAME = "feature_vo"


def resize_frames(frames: Sequence[Frame], width: int, height: int) -> List[Frame]:
    """:func:`spgeo.frame.resize_frame` of each frame to ``width`` x ``height`` pixels."""
    return [resize_frame(f, (width, height)) for f in frames]


def _ate_report(result: FeatureVOResult, frames: Sequence[Frame],
                max_time_diff: Optional[float]) -> Optional[Dict[str, object]]:
    """Print the per-frame and keyframe Sim(3) ATE of ``result`` against the frames'
    ground truth and return its ``report["ate"]`` entry (None: fewer than 3 poses)."""
    gt = [(f.timestamp, f.T_world_cam) for f in frames if f.T_world_cam is not None]
    if len(gt) < 3:
        print("no ground-truth poses: ATE not computed")
        return None
    tol = max_time_diff
    if tol is None:
        tol = default_max_time_diff([f.timestamp for f in frames])
    try:
        ates = result.ate([g[0] for g in gt], [g[1] for g in gt], max_time_diff=tol)
        entry = {k: (v.summary() if v is not None else None) for k, v in ates.items()}
        for v in ates.values():
            if v is not None:
                print(v)
    except ValueError as exc:
        print(f"ATE not available: {exc}")
        entry = {"error": str(exc)}
    return entry


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = protocol_parser(
        "python -m spgeo.evaluation.references.feature_vo",
        "Feature-based monocular VO baseline (ORB + essential matrix + PnP).", verbose=False)
    parser.add_argument("--resolution", default=None,
                        help="resize images to WIDTHxHEIGHT first (e.g. 160x120)")
    parser.add_argument("--detector", choices=("orb", "sift"), default="orb")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--max-time-diff", type=float, default=None,
                        help="ATE association tolerance (default 0.02 s, 0.1 for frame-number "
                             "timestamps)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_verbose_argument(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the baseline on ``--dataset`` / ``--frames``, write ``--out``, print the ATE."""
    kind, path = args.dataset
    res_wh = parse_resolution(args.resolution, min_size=1) if args.resolution else None
    frames = list(open_sequence(args))
    if len(frames) < 2:
        raise ValueError("need at least 2 frames")
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
    print(result.table())
    ate = _ate_report(result, frames, args.max_time_diff)
    if ate is not None:
        report["ate"] = ate
    write_json(out / "report.json", report)
    print(f"wrote {out / 'trajectory.txt'}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.references.feature_vo``: run the baseline on a data set,
    write ``trajectory.txt`` (+ ``trajectory.status.txt``), ``keyframes.txt`` and
    ``report.json`` to ``--out``, and print the Sim(3) ATE when the data set has
    ground truth.  Returns 0, or 2 for bad arguments / unreadable data."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
