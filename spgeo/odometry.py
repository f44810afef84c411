"""Keyframe-based monocular visual odometry on SuperPrimitives (DESIGN.md §5).

One thread, one call per frame (:meth:`Odometry.track`):

* **Initialisation.**  The first frame is keyframe 0 (pose identity: the
  gauge).  Following frames are tracked against it (status ``"init"``) until
  one has enough parallax (translation / median depth >=
  ``OdometryConfig.init_min_parallax``) or ``init_max_gap`` frames have
  passed; that frame becomes keyframe 1 and two-view SfM
  (:func:`spgeo.sfm.few_view_sfm`, keyframe 0 as reference) gives keyframe
  0's log-scales and ``T_0_1``.  The frames in between are then re-tracked
  against the solved keyframe 0.  With a depth-using front-end (RGB-D /
  oracle, ``frontend.uses_depth``) keyframe 0's scales start from that depth
  (so the trajectory is metric); with a monocular front-end they start at 0
  and SfM starts from the feature-based two-view pose.
* **Tracking.**  :func:`spgeo.tracking.track_frame` against the latest
  keyframe from a constant-velocity guess; if that is lost, once more from
  the last good pose; if still lost the frame is flagged ``"lost"`` and keeps
  the last good pose (the next frame starts from it; a frame tracked after a
  loss is flagged ``"relocalised"``).
* **Keyframes.**  A tracked frame becomes a keyframe when its valid fraction
  drops below ``kf_min_valid_fraction`` or its translation from the latest
  keyframe over that keyframe's median depth exceeds ``kf_max_translation``.
  Its primitives get log-scales from the z-buffered rendering of the window's
  keyframes (:func:`spgeo.rendering.render_primitives`,
  :func:`spgeo.rendering.init_scales_from_render`).
* **Mapping.**  A gtsam ``BatchFixedLagSmoother`` (Levenberg-Marquardt) over
  keyframe poses, per-keyframe primitive log-scales and an affine brightness
  per directed keyframe pair.  Each new keyframe is linked to the previous one
  by :class:`~spgeo.factors.photometric.PrimitivePhotometricFactor` in both
  directions (previous -> new and new -> previous), built at pyramid level
  ``map_level`` on the ``2^level * map_stride`` pixel lattice.  Keyframe 0's
  pose has a tight gauge prior; every log-scale a weak prior (weight
  ``scale_prior_weight``) to its initial value.  Smoother timestamps are the
  keyframe indices and the lag keeps ``window`` keyframes: older keys are
  *marginalised* (their information stays as a linear prior), not dropped.
  After each update the window's :class:`~spgeo.tracking.Keyframe` objects
  are rebuilt from the smoother's estimate.

Left out of this first version: supporting non-keyframes in the mapping
graph (the paper links 4 per keyframe), re-initialisation after a long loss,
relocalisation against older keyframes than the latest, keyframe point
clouds and a batch runner.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Union

import numpy as np

import gtsam

from .camera import PinholeCamera
from .factors.photometric import PhotometricConfig, PrimitivePhotometricFactor, ScaledShape
from .factors.priors import brightness_prior, log_scale_prior, pose_gauge_prior
from .frame import Frame
from .frontend import PrimitiveFrontEnd
from .geometry import invert_pose, rotation_angle_deg
from .primitives import PrimitiveSet
from .rendering import init_scales_from_render, render_primitives
from .sfm import SfMConfig, _level_pixels, few_view_sfm
from .tracking import Keyframe, TrackerConfig, TrackResult, constant_velocity_guess, track_frame

__all__ = ["OdometryConfig", "FrameResult", "OdometryResult", "Odometry",
           "kf_pose_key", "kf_scale_key", "kf_brightness_key"]

log = logging.getLogger(__name__)

STATUSES = ("init", "ok", "keyframe", "lost", "relocalised")
_MAX_PRIMS = 1_000_000


def kf_pose_key(k: int) -> int:
    """Smoother key of keyframe ``k``'s pose ``T_world_kf``."""
    return gtsam.symbol("x", int(k))


def kf_scale_key(k: int, i: int) -> int:
    """Smoother key of primitive ``i``'s log-scale in keyframe ``k``."""
    return gtsam.symbol("s", int(k) * _MAX_PRIMS + int(i))


def kf_brightness_key(ref: int, tgt: int) -> int:
    """Smoother key of the affine brightness of keyframe ``tgt`` seen from ``ref``
    (``ref`` and ``tgt`` are consecutive keyframes)."""
    return gtsam.symbol("b" if tgt > ref else "c", int(max(ref, tgt)))


@dataclass(frozen=True)
class OdometryConfig:
    """Options of :class:`Odometry` (defaults: DESIGN.md §5, measured on the
    synthetic 160x120 sequences of ``tests/test_odometry.py``).

    Attributes:
        tracker: :class:`TrackerConfig` of frame-to-keyframe tracking.
        kf_min_valid_fraction: new keyframe when fewer of the latest
            keyframe's primitive pixels project into the frame (default 0.6).
        kf_max_translation: new keyframe when the translation from the latest
            keyframe over its median depth exceeds this (default 0.2).
        kf_max_relative_cost: new keyframe when the tracked frame's relative
            photometric cost (``TrackResult.relative_cost``) exceeds this
            (default 0.2; the tracker declares ``"lost"`` at 0.35, and slow
            hand-held motion reaches that before the translation threshold).
        kf_max_rotation_deg: new keyframe when the rotation from the latest
            keyframe exceeds this (default 15 degrees).
        window: keyframes kept in the smoother (default 5); older ones are
            marginalised.
        levels: pyramid levels of the keyframes (default 3).
        map_level: pyramid level of the mapping factors (default 1).
        map_stride: extra pixel stride of the mapping factors on that level's
            lattice (default 1).
        map_iterations: LM iterations per smoother update (default 10).
        photometric: per-pixel cost of the mapping factors.
        scale_prior_weight: weight of each log-scale's prior to its initial
            value (paper: 1e-5).
        brightness_prior_sigma: sigmas of the brightness ``(a, b)`` priors.
        gauge_sigma: sigma of keyframe 0's pose prior.
        min_level_pixels: primitives with fewer pixels at ``map_level`` get no
            mapping factor.
        render_splat: splat size when rendering the window into a new keyframe.
        init_min_parallax: keyframe 1 is the first frame whose tracked
            translation over keyframe 0's median depth reaches this
            (default 0.08) ...
        init_max_gap: ... or the frame this many frames after keyframe 0
            (default 10).
        sfm: :class:`SfMConfig` of the two-view initialisation (its
            ``reset_scales`` is overridden: False with a depth-using
            front-end, True otherwise).
    """

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    kf_min_valid_fraction: float = 0.6
    kf_max_translation: float = 0.2
    kf_max_relative_cost: float = 0.2
    kf_max_rotation_deg: float = 15.0
    window: int = 5
    levels: int = 3
    map_level: int = 1
    map_stride: int = 1
    map_iterations: int = 10
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    scale_prior_weight: float = 1e-5
    brightness_prior_sigma: tuple = (0.3, 0.3)
    gauge_sigma: float = 1e-6
    min_level_pixels: int = 4
    render_splat: int = 2
    init_min_parallax: float = 0.08
    init_max_gap: int = 10
    sfm: SfMConfig = field(default_factory=lambda: SfMConfig(levels=3, marginals=False))

    def __post_init__(self) -> None:
        if self.window < 2:
            raise ValueError(f"OdometryConfig.window must be >= 2, got {self.window}")
        if not 0 <= self.map_level < self.levels:
            raise ValueError("OdometryConfig.map_level must be in [0, levels)")
        if self.map_stride < 1 or self.map_iterations < 1 or self.init_max_gap < 1:
            raise ValueError("OdometryConfig: map_stride, map_iterations and init_max_gap "
                             "must be >= 1")
        if not self.scale_prior_weight > 0:
            raise ValueError("OdometryConfig.scale_prior_weight must be > 0")
        if not 0 <= self.kf_min_valid_fraction <= 1 or not self.kf_max_translation > 0:
            raise ValueError("OdometryConfig: kf_min_valid_fraction in [0, 1] and "
                             "kf_max_translation > 0 required")


@dataclass
class FrameResult:
    """Outcome of :meth:`Odometry.track` for one frame.

    Attributes:
        index: frame number (0-based, in call order).
        timestamp: the frame's timestamp.
        T_world_cam: 4x4 camera-to-world pose (world = keyframe 0's camera);
            the last good pose for a ``"lost"`` frame.
        status: ``"init"`` (before keyframe 1; the pose is provisional and is
            refined in :meth:`Odometry.result`), ``"ok"``, ``"keyframe"``,
            ``"lost"`` or ``"relocalised"`` (first tracked frame after a loss).
        keyframe_index: the keyframe's index if this frame became one.
        track: the :class:`TrackResult` of the final tracking attempt (None
            for frame 0).
        timings: seconds per stage (``track``, ``frontend``, ``mapping``,
            ``total``).
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: str
    keyframe_index: Optional[int] = None
    track: Optional[TrackResult] = None
    timings: Dict[str, float] = field(default_factory=dict)


@dataclass
class OdometryResult:
    """The trajectory so far (:meth:`Odometry.result`).

    Attributes:
        timestamps: (n,) frame timestamps.
        poses: (n, 4, 4) camera-to-world poses (keyframes at their smoothed
            estimate, other frames as tracked).
        statuses: per-frame status strings.
        is_keyframe: (n,) bool.
        keyframe_timestamps, keyframe_poses: keyframes only.
    """

    timestamps: np.ndarray
    poses: np.ndarray
    statuses: List[str]
    is_keyframe: np.ndarray

    @property
    def keyframe_timestamps(self) -> np.ndarray:
        return self.timestamps[self.is_keyframe]

    @property
    def keyframe_poses(self) -> np.ndarray:
        return self.poses[self.is_keyframe]


@dataclass
class _KF:
    index: int          # keyframe number
    frame: int          # frame number
    image: np.ndarray
    keyframe: Keyframe


class Odometry:
    """Streaming monocular VO (module docstring).

    Args:
        camera: intrinsics of the input frames.
        config: :class:`OdometryConfig`.
        frontend: the :class:`PrimitiveFrontEnd` that primifies keyframes
            (give it a small ``working_size``, e.g. 160x120).
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig = OdometryConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None) -> None:
        if frontend is None:
            raise ValueError("Odometry needs a front-end (spgeo.frontend.make_frontend)")
        self.camera = camera
        self.config = config
        self.frontend = frontend
        self._frames: List[FrameResult] = []
        self._kfs: Dict[int, _KF] = {}
        self._kf_order: List[int] = []
        self._init_buffer: List[tuple] = []   # (frame index, image) before keyframe 1
        self._last_good: Optional[np.ndarray] = None
        self._prev_good: Optional[np.ndarray] = None
        self._brightness = np.zeros(2)
        self._lost = False
        lag = float(config.window) - 0.5
        self.smoother = gtsam.BatchFixedLagSmoother(lag, self._lm_params())
        self._map_reports: List[dict] = []
        self._sfm_report: Optional[dict] = None

    # ------------------------------------------------------------ public API
    def track(self, frame: Frame) -> FrameResult:
        """Process the next frame (a :class:`~spgeo.frame.Frame`; its depth is
        read only by a depth-using front-end)."""
        t0 = time.perf_counter()
        image = np.asarray(frame.image)
        if image.ndim not in (2, 3) or tuple(image.shape[:2]) != self.camera.shape:
            raise ValueError(f"Odometry.track: image of shape {image.shape} does not match the "
                             f"camera {self.camera.shape}")
        if not np.all(np.isfinite(image)):
            raise ValueError("Odometry.track: image contains NaN or inf")
        idx = len(self._frames)
        timings: Dict[str, float] = {}
        if idx == 0:
            res = self._start(frame, timings)
        elif len(self._kf_order) < 2:
            res = self._initialise(frame, idx, timings)
        else:
            res = self._track(frame, idx, timings)
        timings["total"] = time.perf_counter() - t0
        res.timings = timings
        self._frames.append(res)
        return res

    def result(self) -> OdometryResult:
        """Per-frame trajectory (keyframes at their latest smoothed poses)."""
        n = len(self._frames)
        poses = np.array([f.T_world_cam for f in self._frames]).reshape(n, 4, 4)
        is_kf = np.array([f.keyframe_index is not None for f in self._frames], dtype=bool)
        for kf in self._kfs.values():
            poses[kf.frame] = kf.keyframe.T_world_kf
        return OdometryResult(np.array([f.timestamp for f in self._frames], dtype=float),
                              poses, [f.status for f in self._frames], is_kf)

    def smoother_estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window)."""
        return self.smoother.calculateEstimate()

    @property
    def keyframes(self) -> List[Keyframe]:
        """All keyframes in creation order (the window's at their smoothed state)."""
        return [self._kfs[k].keyframe for k in self._kf_order]

    def save(self, directory: Union[str, Path]) -> Dict[str, Path]:
        """Write ``trajectory.txt`` (every frame with a pose), ``keyframes.txt``
        (TUM, camera-to-world), ``trajectory.status.txt`` (per-frame status and
        keyframe flag) and ``report.json``; returns their paths."""
        from spgeo.evaluation.trajectory import status_path_for, write_status, write_tum

        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        res = self.result()
        traj = out / "trajectory.txt"
        kfs = out / "keyframes.txt"
        write_tum(traj, res.timestamps, list(res.poses), header=["spgeo.odometry per-frame"])
        write_tum(kfs, res.keyframe_timestamps, list(res.keyframe_poses),
                  header=["spgeo.odometry keyframes"])
        status = status_path_for(traj)
        write_status(status, res.timestamps, res.statuses,
                     {"keyframe": [int(k) for k in res.is_keyframe]})
        counts = {s: int(sum(1 for x in res.statuses if x == s)) for s in STATUSES}
        tot = [f.timings.get("total", 0.0) for f in self._frames]
        report = {
            "n_frames": len(self._frames), "n_keyframes": len(self._kf_order),
            "status_counts": counts,
            "seconds_total": float(np.sum(tot)),
            "fps": float(len(tot) / max(np.sum(tot), 1e-9)),
            "seconds_per_stage": {k: float(sum(f.timings.get(k, 0.0) for f in self._frames))
                                  for k in ("track", "frontend", "mapping", "init")},
            "config": _jsonable(dataclasses.asdict(self.config)),
            "frontend": getattr(self.frontend, "name", str(self.frontend)),
            "sfm": _jsonable(self._sfm_report),
            "mapping": _jsonable(self._map_reports),
            "frames": [{"index": f.index, "timestamp": f.timestamp, "status": f.status,
                        "keyframe": f.keyframe_index, "timings": f.timings}
                       for f in self._frames],
        }
        rep = out / "report.json"
        rep.write_text(json.dumps(report, indent=1), encoding="utf-8")
        return {"trajectory": traj, "keyframes": kfs, "status": status, "report": rep}

    # ------------------------------------------------------------ stages
    def _lm_params(self) -> gtsam.LevenbergMarquardtParams:
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(int(self.config.map_iterations))
        p.setRelativeErrorTol(1e-4)
        p.setAbsoluteErrorTol(1e-9)
        return p

    def _primify(self, frame: Frame) -> PrimitiveSet:
        depth = frame.depth if self.frontend.uses_depth else None
        prims = self.frontend.primify(frame.image, self.camera, depth)
        if len(prims) == 0:
            raise ValueError("the front-end produced no primitive")
        return prims

    def _start(self, frame: Frame, timings: Dict[str, float]) -> FrameResult:
        t = time.perf_counter()
        prims = self._primify(frame)
        if not self.frontend.uses_depth:
            prims = prims.with_log_scales(np.zeros(len(prims)))
        timings["frontend"] = time.perf_counter() - t
        kf = Keyframe.build(frame.image, prims, np.eye(4), self.config.levels)
        self._kfs[0] = _KF(0, 0, np.asarray(frame.image), kf)
        self._kf_order.append(0)
        self._last_good, self._prev_good = np.eye(4), None
        return FrameResult(0, float(frame.timestamp), np.eye(4), "keyframe", keyframe_index=0)

    def _track_against(self, kf: Keyframe, image: np.ndarray):
        """Constant-velocity guess, then the last good pose; returns the TrackResult."""
        guess = constant_velocity_guess(self._last_good, self._prev_good)
        tr = track_frame(kf, image, guess, self._brightness, self.config.tracker)
        if not tr.ok and self._prev_good is not None:
            tr2 = track_frame(kf, image, self._last_good, self._brightness, self.config.tracker)
            if tr2.ok or tr2.photometric_cost < tr.photometric_cost:
                tr = tr2
        return tr

    def _accept(self, tr: TrackResult) -> None:
        self._prev_good, self._last_good = self._last_good, tr.T_world_frame.copy()
        self._brightness = np.asarray(tr.brightness, dtype=float).copy()

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        kf0 = self._kfs[0]
        t = time.perf_counter()
        tr = self._track_against(kf0.keyframe, frame.image)
        timings["track"] = time.perf_counter() - t
        if tr.ok:
            self._accept(tr)
        parallax = (np.linalg.norm(tr.T_world_frame[:3, 3]) / kf0.keyframe.median_depth
                    if tr.ok else 0.0)
        gap = idx - kf0.frame
        if parallax < self.config.init_min_parallax and gap < self.config.init_max_gap:
            self._init_buffer.append((idx, np.asarray(frame.image)))
            pose = tr.T_world_frame if tr.ok else self._last_good
            return FrameResult(idx, float(frame.timestamp), pose.copy(),
                               "init" if tr.ok else "lost", track=tr)
        # ---- two-view SfM: keyframe 0 (reference) and this frame
        t = time.perf_counter()
        sfm_cfg = dataclasses.replace(self.config.sfm, reset_scales=not self.frontend.uses_depth)
        init = [tr.T_world_frame] if tr.ok else None
        sfm = few_view_sfm(kf0.image, [frame.image], self.camera, kf0.keyframe.primitives,
                           sfm_cfg, init_T_ref_view=init)
        timings["init"] = time.perf_counter() - t
        self._sfm_report = {"status": sfm.status, "frame": idx, "parallax": parallax,
                            **{k: sfm.report.get(k) for k in ("n_primitives", "final_cost",
                                                               "seconds_total")}}
        if sfm.status == "diverged" or not np.all(np.isfinite(sfm.T_ref_view[0])):
            log.warning("two-view initialisation failed (%s) at frame %d; retrying later",
                        sfm.status, idx)
            self._init_buffer.append((idx, np.asarray(frame.image)))
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), "lost",
                               track=tr)
        kf0.keyframe = Keyframe.build(kf0.image, sfm.primitives, np.eye(4), self.config.levels)
        T1 = np.asarray(sfm.T_ref_view[0], dtype=float)
        # re-track the buffered frames against the solved keyframe 0
        prev = None
        last = np.eye(4)
        for j, img in self._init_buffer:
            tj = track_frame(kf0.keyframe, img, constant_velocity_guess(last, prev),
                             self._brightness, self.config.tracker)
            if tj.ok:
                prev, last = last, tj.T_world_frame
                self._frames[j].T_world_cam = tj.T_world_frame.copy()
                self._frames[j].status = "init"
            else:
                self._frames[j].status = "lost"
                self._frames[j].T_world_cam = last.copy()
        self._init_buffer.clear()
        self._last_good, self._prev_good = T1.copy(), last.copy()
        res = self._new_keyframe(frame, idx, T1, timings, track=tr)
        return res

    def _track(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        latest = self._kfs[self._kf_order[-1]]
        t = time.perf_counter()
        tr = self._track_against(latest.keyframe, frame.image)
        timings["track"] = time.perf_counter() - t
        if not tr.ok:
            self._lost = True
            log.info("frame %d lost (%s)", idx, tr.reason)
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), "lost",
                               track=tr)
        was_lost, self._lost = self._lost, False
        self._accept(tr)
        T_kf_f = invert_pose(latest.keyframe.T_world_kf) @ tr.T_world_frame
        rel_t = float(np.linalg.norm(T_kf_f[:3, 3])) / max(latest.keyframe.median_depth, 1e-9)
        rot = rotation_angle_deg(T_kf_f[:3, :3])
        if (tr.valid_fraction < self.config.kf_min_valid_fraction
                or rel_t > self.config.kf_max_translation
                or tr.relative_cost > self.config.kf_max_relative_cost
                or rot > self.config.kf_max_rotation_deg):
            res = self._new_keyframe(frame, idx, tr.T_world_frame, timings, track=tr)
            if res is not None:
                return res
        return FrameResult(idx, float(frame.timestamp), tr.T_world_frame.copy(),
                           "relocalised" if was_lost else "ok", track=tr)

    def _new_keyframe(self, frame: Frame, idx: int, T_world: np.ndarray,
                      timings: Dict[str, float], track: Optional[TrackResult]):
        cfg = self.config
        t = time.perf_counter()
        prims = self._primify(frame)
        window = [self._kfs[k] for k in self._kf_order[-cfg.window:]]
        depth = render_primitives([(w.keyframe.primitives, w.keyframe.T_world_kf) for w in window],
                                  prims.camera, T_world, splat=cfg.render_splat)
        try:
            prims = init_scales_from_render(prims, depth).primitives
        except ValueError as exc:
            log.warning("frame %d: no keyframe (%s)", idx, exc)
            timings["frontend"] = time.perf_counter() - t
            return None
        timings["frontend"] = time.perf_counter() - t
        k = len(self._kf_order)
        kf = _KF(k, idx, np.asarray(frame.image),
                 Keyframe.build(frame.image, prims, T_world, cfg.levels))
        self._kfs[k] = kf
        self._kf_order.append(k)
        t = time.perf_counter()
        self._map(k)
        timings["mapping"] = time.perf_counter() - t
        T_new = self._kfs[k].keyframe.T_world_kf
        # the smoothed pose of the new keyframe replaces the tracked one
        # (the same world-frame correction moves the previous pose of the velocity model)
        if self._prev_good is not None:
            self._prev_good = T_new @ invert_pose(self._last_good) @ self._prev_good
        self._last_good = T_new.copy()
        self._brightness = np.zeros(2)
        return FrameResult(idx, float(frame.timestamp), T_new.copy(), "keyframe",
                           keyframe_index=k, track=track)

    # ------------------------------------------------------------ mapping
    def _pair_factors(self, ref: _KF, tgt: _KF, graph: gtsam.NonlinearFactorGraph) -> int:
        """Photometric factors of ref's primitives observed in tgt (map level)."""
        cfg = self.config
        lvl = cfg.map_level
        prims = ref.keyframe.primitives
        cam = prims.camera
        w = cam.width
        stride = 2 ** lvl
        rays_all = cam.rays().reshape(-1, 3)[prims.pixels]
        ref_img = ref.keyframe.pyramid.images[lvl]
        tgt_img = tgt.keyframe.pyramid.images[lvl]
        tgt_cam = tgt.keyframe.pyramid.cameras[lvl]
        bkey = kf_brightness_key(ref.index, tgt.index)
        n = 0
        for i, ent in enumerate(_level_pixels(prims, stride * cfg.map_stride)):
            if ent.size < cfg.min_level_pixels:
                continue
            pix = prims.pixels[ent]
            ref_int = ref_img[(pix // w) // stride, (pix % w) // stride].astype(np.float64)
            f = PrimitivePhotometricFactor(
                kf_pose_key(ref.index), kf_pose_key(tgt.index), kf_scale_key(ref.index, i),
                ScaledShape(rays_all[ent], prims.log_depth[ent]), ref_int, tgt_img, tgt_cam,
                bkey, cfg.photometric, n_pixels=ent.size)
            graph.add(f.factor)
            n += 1
        graph.add(brightness_prior(bkey, cfg.brightness_prior_sigma))
        return n

    def _map(self, k: int) -> None:
        """Add keyframe ``k`` (k >= 1) to the smoother and update the window."""
        cfg = self.config
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()

        def add_kf(kf: _KF) -> None:
            values.insert(kf_pose_key(kf.index), gtsam.Pose3(kf.keyframe.T_world_kf))
            stamps.insert((kf_pose_key(kf.index), float(kf.index)))
            s = kf.keyframe.primitives.log_scales
            for i in range(len(s)):
                key = kf_scale_key(kf.index, i)
                values.insert(key, np.array([s[i]]))
                stamps.insert((key, float(kf.index)))
                graph.add(log_scale_prior(key, float(s[i]), cfg.scale_prior_weight))

        new, prev = self._kfs[k], self._kfs[self._kf_order[-2]]
        if k == 1:
            add_kf(prev)
            graph.add(pose_gauge_prior(kf_pose_key(prev.index), prev.keyframe.T_world_kf,
                                       cfg.gauge_sigma))
        add_kf(new)
        n_fwd = self._pair_factors(prev, new, graph)
        n_bwd = self._pair_factors(new, prev, graph)
        for ref, tgt in ((prev, new), (new, prev)):
            key = kf_brightness_key(ref.index, tgt.index)
            values.insert(key, np.zeros(2))
            stamps.insert((key, float(k)))
        t = time.perf_counter()
        self.smoother.update(graph, values, stamps)
        est = self.smoother.calculateEstimate()
        secs = time.perf_counter() - t
        # refresh the window's keyframes from the estimate
        for j in self._kf_order:
            kf = self._kfs[j]
            if not est.exists(kf_pose_key(j)):
                continue
            T = est.atPose3(kf_pose_key(j)).matrix()
            n_s = len(kf.keyframe.primitives)
            s = np.array([est.atVector(kf_scale_key(j, i))[0] for i in range(n_s)])
            if not (np.all(np.isfinite(T)) and np.all(np.isfinite(s))):
                log.warning("mapping produced non-finite values for keyframe %d; kept", j)
                continue
            kf.keyframe = Keyframe.build(kf.image, kf.keyframe.primitives.with_log_scales(s), T,
                                         cfg.levels)
        self._map_reports.append({"keyframe": k, "factors_forward": n_fwd,
                                  "factors_backward": n_bwd, "seconds": secs,
                                  "keys_in_window": int(est.size())})
        log.debug("mapping kf %d: %d+%d factors, %.2f s", k, n_fwd, n_bwd, secs)


def _jsonable(obj):
    """Convert dataclass dicts / numpy values for json."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if obj is None or isinstance(obj, (int, float, str, bool)):
        return obj
    return str(obj)
