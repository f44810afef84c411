"""The VO's map initialisation (docs/design.md §5.1, *Initialisation*): the
:class:`Initialiser` that :class:`spgeo.vo.Odometry` owns (one per VO).  It
holds its own state (the bounded buffer of frames waiting for keyframe 1, the
retry gaps, why the last try failed, the SfM reports), solves keyframes 0 and 1
with few-view SfM, and returns an :class:`InitDecision` for each frame of a
segment that has only its keyframe 0 (wait, a failed SfM, or start the map with
keyframe 0's solved primitives, keyframe 1's pose and the buffered frames
re-tracked); ``Odometry`` applies it.  Also here: the supporting views of that
SfM (:func:`init_views`), the check that its result may initialise a map
(:func:`init_rejection`) and :func:`twoview_start`.

A keyframe pair without parallax never initialises a map: the frames stay
``INIT`` (tracked against keyframe 0) or ``LOST`` and
:attr:`Odometry.init_failure` says why.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..geometry import invert_pose, ray_angles_deg, rotation_angle_deg
from ..primitive_models import apply_primitive_model
from ..primitives import PrimitiveSet
from ..sfm import SfMResult, few_view_sfm
from ..sfm.init import twoview_initialisation
from .config import OdometryConfig
from .map import MapKeyframe
from .tracking import Keyframe, TrackResult, constant_velocity_guess, track_frame

__all__ = ["Initialiser", "InitDecision", "RetrackedFrame", "init_views", "init_rejection",
           "append_bounded", "twoview_start", "sfm_parallax_deg"]

log = logging.getLogger(__name__)


def init_views(image: np.ndarray, idx: int, frame0: int, buffer: Sequence[tuple], n_extra: int,
               T_kf0_f: Optional[np.ndarray]) -> Tuple[List[np.ndarray], Optional[List[np.ndarray]]]:
    """Supporting views of the initialisation's SfM and their initial poses.

    Args:
        image: keyframe 1's image (frame ``idx``).
        idx, frame0: frame numbers of keyframes 1 and 0.
        buffer: ``(frame number, image)`` of the frames waiting between them.
        n_extra: ``OdometryConfig.init.extra_views``.
        T_kf0_f: keyframe 1's tracked pose in keyframe 0 (4x4), or None when it
            was not tracked.
    Returns:
        ``(views, init)``: keyframe 1's image first, then up to ``n_extra``
        buffered images evenly spaced between keyframes 0 and 1; ``init`` their
        initial ``T_kf0_view`` (the extra views at keyframe 1's motion
        interpolated in time), or None (the SfM's own two-view initialisation)
        without ``T_kf0_f``.
    """
    n = min(n_extra, len(buffer))
    picks = sorted({int(round(q * len(buffer) / (n + 1))) - 1 for q in range(1, n + 1)}) if n else []
    picks = [p for p in picks if 0 <= p < len(buffer)]
    views = [image] + [buffer[p][1] for p in picks]
    if T_kf0_f is None:
        return views, None
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(T_kf0_f))
    init = [T_kf0_f] + [gtsam.Pose3.Expmap((buffer[p][0] - frame0) / max(idx - frame0, 1) * xi)
                        .matrix() for p in picks]
    return views, init


def twoview_start(image0: np.ndarray, image1: np.ndarray, camera: PinholeCamera,
                  prims0: PrimitiveSet) -> Optional[Tuple[np.ndarray, PrimitiveSet]]:
    """Keyframe 1's pose and keyframe 0's log-scales from feature-based two-view
    geometry (:func:`spgeo.sfm.init.twoview_initialisation`: essential matrix,
    triangulated inliers, a robust median per primitive), for a monocular
    front-end whose primitives have no scale yet.

    Args:
        image0, image1: keyframes 0 and 1 at ``camera``'s resolution.
        camera: their intrinsics.
        prims0: keyframe 0's primitives (their log-scales are ignored).
    Returns:
        ``(T_kf0_kf1, prims)``: with a two-view estimate (``"ok"``) its pose
        and the triangulated scales, in the units where keyframe 0's median
        depth is 1 (the units of a front-end's unscaled primitives); when the
        matches show no parallax (``"low_parallax"``) the rotation-only
        estimate with zero translation and the unscaled primitives (the SfM
        finds the baseline from there: a pose tracked against unscaled
        primitives overestimates it); None without an estimate (too few
        matches or inliers, degenerate geometry).
    """
    report: dict = {}
    unscaled = prims0.with_log_scales(np.zeros(len(prims0)))
    poses, prims = twoview_initialisation(image0, [image1], camera, unscaled, report)
    status = report["twoview_status"][0]
    if status == "low_parallax":
        # the rotation-only estimate, zero translation: the SfM finds the baseline
        return np.asarray(poses[0], dtype=float).copy(), unscaled
    if status != "ok" or not report.get("primitives_with_points"):
        return None
    med = float(np.median(np.exp(prims.scaled_log_depth())))
    if not (np.isfinite(med) and med > 0):
        return None
    T = np.asarray(poses[0], dtype=float).copy()
    T[:3, 3] /= med
    return T, prims.with_log_scales(prims.log_scales - np.log(med))


def init_rejection(sfm: SfMResult, tracked: bool) -> Optional[str]:
    """Why the SfM of keyframes 0 and 1 must not initialise a map, or None.

    A keyframe pair initialises only with a baseline: the SfM's view of
    keyframe 1 (its first view) must not be ``"low_parallax"`` / ``"diverged"``
    and its pose must be finite.  When keyframe 1 was not tracked against
    keyframe 0 (large motion or a frame the tracker cannot use) the SfM alone
    decides, so its status must also be ``"ok"`` (before ``init.max_gap`` the
    caller also asks its baseline for ``init.min_parallax``).
    """
    if not sfm.T_ref_view or not np.all(np.isfinite(sfm.T_ref_view[0])):
        return "non-finite keyframe-1 pose"
    kf1 = sfm.view_status[0]
    if kf1 in ("low_parallax", "diverged"):
        p = (sfm.report.get("parallax") or [None])[0]
        return f"SfM view of keyframe 1 {kf1}" + ("" if p is None else f", parallax {p:.3g}")
    if not tracked and sfm.status != "ok":
        return f"keyframe 1 not tracked and SfM status {sfm.status}"
    return None


def sfm_parallax_deg(sfm: SfMResult, percentile: float) -> float:
    """The ``percentile``-th percentile (in [0, 100]) of the triangulation
    angles (degrees) of the SfM's reference primitives between the reference
    camera and the SfM's first view (keyframe 1), over the pixels of the
    constrained primitives: for each pixel's point ``X`` (reference camera
    frame, at its solved depth), the angle between the rays from the two camera centres, ``X`` and
    ``X - c`` with ``c = T_ref_view[0][:3, 3]``.  Scale-free; 0 for a pure
    rotation; NaN without a finite pose or a constrained primitive."""
    T = np.asarray(sfm.T_ref_view[0], dtype=float) if sfm.T_ref_view else None
    prims = sfm.primitives
    keep = np.ones(len(prims), bool)
    keep[np.asarray(sfm.unconstrained, dtype=np.int64)] = False
    if T is None or not np.all(np.isfinite(T)) or not keep.any():
        return float("nan")
    cam = prims.camera
    uv = np.stack([prims.pixels % cam.width, prims.pixels // cam.width], -1).astype(float)
    X = cam.unproject(uv, np.exp(prims.scaled_log_depth()))[keep[prims.primitive_ids]]
    angles = ray_angles_deg(X, np.zeros(3), T[:3, 3])
    angles = angles[np.isfinite(angles)]
    return float(np.percentile(angles, percentile)) if angles.size else float("nan")


def append_bounded(buffer: list, item, cap: int) -> None:
    """Append ``item`` to ``buffer``; beyond ``cap`` entries every other older
    entry is dropped (the newest is kept), so a long wait holds a bounded,
    evenly thinned set of frames."""
    buffer.append(item)
    if len(buffer) > cap:
        buffer[:] = buffer[:-1][::2] + buffer[-1:]


#: :attr:`InitDecision.action` values
WAIT, FAILED, START = "wait", "failed", "start"


@dataclass
class RetrackedFrame:
    """A buffered frame re-tracked against the solved keyframe 0.

    Attributes:
        frame: frame number.
        image: its image.
        ok: whether it tracked.
        T_world_frame: its re-tracked pose, or (not ``ok``) the last good pose
            before it in the buffer.
        T_kf0_frame: its pose in keyframe 0 (``ok`` only).
        brightness: its tracked ``(a, b)`` (``ok`` only).
    """

    frame: int
    image: np.ndarray
    ok: bool
    T_world_frame: np.ndarray
    T_kf0_frame: Optional[np.ndarray] = None
    brightness: Optional[np.ndarray] = None


@dataclass
class InitDecision:
    """What :meth:`Initialiser.step` decided for one frame.

    Attributes:
        action: ``"wait"`` (the frame stays ``INIT`` at its pose tracked against
            keyframe 0, or ``LOST``; it is buffered), ``"failed"`` (the SfM of
            keyframes 0-1 failed: the frame is ``LOST`` and buffered) or
            ``"start"`` (the frame becomes keyframe 1 of a new map).
        T_kf0_frame: the frame's tracked pose in keyframe 0.
        keyframe0: ``"start"``: keyframe 0 rebuilt with the SfM's primitives.
        T_world_kf1: ``"start"``: keyframe 1's pose.
        retracked: ``"start"``: the buffered frames re-tracked against
            ``keyframe0``, in frame order.
        T_world_last: ``"start"``: the last re-tracked good pose (keyframe 0's
            when none tracked): the previous pose of the velocity model.
    """

    action: str
    T_kf0_frame: np.ndarray
    keyframe0: Optional[Keyframe] = None
    T_world_kf1: Optional[np.ndarray] = None
    retracked: List[RetrackedFrame] = field(default_factory=list)
    T_world_last: Optional[np.ndarray] = None


class Initialiser:
    """The map initialisation of one :class:`spgeo.vo.Odometry` (module docstring).

    Args:
        config: the VO's :class:`OdometryConfig` (``init_*``, ``sfm``, ``keyframe_levels``,
            ``kf_*`` overlap thresholds, ``primitive_model``, ``tracker``).
        camera: the frames' intrinsics.
        uses_depth: whether the front-end uses depth (metric primitives).

    Attributes:
        failure: why the last keyframe-1 SfM was refused (None: none yet in
            this segment).
        wait_note: why the current wait goes on.
        reports: one dict per SfM tried (all segments).
    """

    def __init__(self, config: OdometryConfig, camera: PinholeCamera, uses_depth: bool) -> None:
        self.config = config
        self.camera = camera
        self.uses_depth = bool(uses_depth)
        self.reports: List[dict] = []
        self.reset()

    def reset(self) -> None:
        """A new segment: no buffered frame, no retry gap, no failure note."""
        self.buffer: List[tuple] = []    # (frame index, image) before keyframe 1
        self.retry_gap = 0    # a lost frame may end the wait from this gap on
        self.wait_until = 0   # past init.max_gap, after a pair without parallax
        self.failure: Optional[str] = None
        self.wait_note: Optional[str] = None

    def _buffer_frame(self, idx: int, image: np.ndarray) -> None:
        append_bounded(self.buffer, (idx, np.asarray(image)), 2 * self.config.init.max_gap)

    def step(self, image: np.ndarray, idx: int, kf0: MapKeyframe, tr: TrackResult,
             brightness: np.ndarray, segment: int,
             timings: Dict[str, float]) -> InitDecision:
        """Decide for frame ``idx`` (``image``) of a segment with only keyframe
        ``kf0``, given ``tr``, its tracking against keyframe 0, and
        ``brightness``, the VO's current brightness estimate (the re-tracking's
        start).  Adds ``timings["init"]`` when an SfM runs."""
        T_kf0_f = invert_pose(kf0.keyframe.T_world_kf) @ tr.T_world_frame
        parallax = (np.linalg.norm(T_kf0_f[:3, 3]) / kf0.keyframe.median_depth
                    if tr.ok else 0.0)
        gap = idx - kf0.frame
        early = not tr.ok and gap < self.config.init.max_gap
        if self._waits(tr, T_kf0_f, parallax, gap, early):
            self.wait_note = (
                f"waiting for keyframe 1: {gap} frames after keyframe 0, " + (
                    f"parallax {parallax:.3g} < init.min_parallax {self.config.init.min_parallax:g}"
                    if tr.ok else f"frame lost against keyframe 0 ({tr.reason})"))
            self._buffer_frame(idx, image)
            return InitDecision(WAIT, T_kf0_f)
        t = time.perf_counter()
        sfm, n_views = self._solve(image, idx, kf0, tr, T_kf0_f)
        timings["init"] = time.perf_counter() - t
        failed, rejected = self._judge(sfm, tr, idx, segment, parallax, early, n_views)
        if failed:
            self.retry_gap = gap + max(1, gap // 2)
            self.failure = f"frame {idx}: SfM of keyframes 0-1 {sfm.status}"
            self._buffer_frame(idx, image)
            return InitDecision(FAILED, T_kf0_f)
        if rejected is not None:
            # no baseline between keyframes 0 and 1: no map; wait for motion
            self.wait_until = max(gap, self.config.init.max_gap) + max(1, gap // 2)
            self.failure = f"frame {idx}: no map initialised from keyframes 0-1 ({rejected})"
            log.warning("%s; waiting for camera motion", self.failure)
            self._buffer_frame(idx, image)
            return InitDecision(WAIT, T_kf0_f)
        keyframe0, T_01 = self._solved_keyframe0(kf0, sfm, segment)
        retracked, last = self._retrack(keyframe0, kf0.frame, idx, T_01, brightness)
        self.buffer.clear()
        return InitDecision(START, T_kf0_f, keyframe0, kf0.keyframe.T_world_kf @ T_01, retracked,
                            last)

    def _waits(self, tr: TrackResult, T_kf0_f: np.ndarray, parallax: float, gap: int,
               early: bool) -> bool:
        """Whether the frame waits for keyframe 1 (no SfM yet)."""
        cfg = self.config
        # keyframe 1 must still overlap keyframe 0: the overlap criteria of
        # keyframes (valid fraction, rotation) end the wait too
        rot = rotation_angle_deg(T_kf0_f[:3, :3])
        overlap_ending = tr.ok and (tr.valid_fraction < cfg.keyframe.min_valid_fraction
                                    or rot > cfg.keyframe.max_rotation_deg)
        # a frame lost against keyframe 0's unscaled shapes (large motion) ends
        # the wait too (retries spaced out); its SfM must then pass its own checks
        wait = gap < cfg.init.max_gap and not overlap_ending and (
            (tr.ok and (parallax < cfg.init.min_parallax or gap < cfg.init.min_gap))
            or (early and gap < self.retry_gap))
        # past init.max_gap after a keyframe pair without parallax: retries spaced out,
        # unless the tracked parallax is reached or keyframe 0's view is ending
        return wait or (gap < self.wait_until and not overlap_ending
                        and not (tr.ok and parallax >= cfg.init.min_parallax))

    def _solve(self, image: np.ndarray, idx: int, kf0: MapKeyframe, tr: TrackResult,
               T_kf0_f: np.ndarray) -> Tuple[SfMResult, int]:
        """The SfM of keyframe 0 (reference), this frame and extra views; its view count."""
        cfg = self.config
        sfm_cfg = dataclasses.replace(cfg.sfm, reset_scales=not self.uses_depth)
        prims0 = kf0.keyframe.primitives
        T_init = T_kf0_f if tr.ok else None
        if tr.ok and cfg.init.method == "twoview" and not self.uses_depth:
            tv = twoview_start(kf0.image, image, self.camera, prims0)
            if tv is not None:
                T_init, prims0 = tv
                sfm_cfg = dataclasses.replace(sfm_cfg, reset_scales=False)
            else:
                log.info("frame %d: no two-view estimate for keyframe 1; the SfM starts from "
                         "the tracked pose", idx)
        views, init = init_views(image, idx, kf0.frame, self.buffer, cfg.init.extra_views, T_init)
        sfm = few_view_sfm(kf0.image, views, self.camera, prims0, sfm_cfg, init_T_ref_view=init)
        return sfm, len(views)

    def _judge(self, sfm: SfMResult, tr: TrackResult, idx: int, segment: int, parallax: float,
               early: bool, n_views: int) -> Tuple[bool, Optional[str]]:
        """``(failed, rejection)`` of the SfM (a failed one is retried later, a
        rejected one waits for motion); appends its report."""
        cfg = self.config
        finite = bool(np.all(np.isfinite(sfm.T_ref_view[0])))
        if not tr.ok and finite:  # the SfM's own baseline over its median depth
            parallax = float(np.linalg.norm(sfm.T_ref_view[0][:3, 3]) / np.median(
                np.exp(sfm.primitives.scaled_log_depth())))
        angle = (sfm_parallax_deg(sfm, cfg.init.parallax_percentile)
                 if finite and not tr.ok and cfg.init.min_parallax_deg is not None else None)
        enough = parallax >= cfg.init.min_parallax or (
            angle is not None and angle >= cfg.init.min_parallax_deg)
        failed = sfm.status == "diverged" or (early and (sfm.status != "ok" or not enough))
        rejected = None if failed else init_rejection(sfm, tr.ok)
        self.reports.append({
            "status": sfm.status, "frame": idx, "segment": segment, "parallax": parallax,
            "sfm_parallax": (sfm.report.get("parallax") or [None])[0], "n_views": n_views,
            "accepted": not (failed or not finite or rejected), "rejected": rejected,
            **({} if angle is None else {"parallax_deg": angle}),
            **{k: sfm.report.get(k) for k in ("n_primitives", "final_cost", "seconds_total")}})
        if failed or not finite:
            log.warning("two-view initialisation failed at frame %d (SfM status %s, parallax "
                        "%.3g); retrying later", idx, sfm.status, parallax)
            if angle is not None:
                log.info("frame %d: triangulation angle %.3g deg (init.min_parallax_deg %g)",
                         idx, angle, cfg.init.min_parallax_deg)
            return True, rejected
        return False, rejected

    def _solved_keyframe0(self, kf0: MapKeyframe, sfm: SfMResult,
                          segment: int) -> Tuple[Keyframe, np.ndarray]:
        """Keyframe 0 rebuilt with the SfM's primitives, and ``T_kf0_kf1``."""
        new_prims = sfm.primitives
        if self.config.primitive_model != "integrated":
            new_prims = apply_primitive_model(new_prims, self.config.primitive_model)
        if not self.uses_depth and segment > 0:
            # a re-initialised monocular segment keeps the previous map's depth scale
            # (keyframe 0's primitives were set to it by Odometry._reinitialise)
            med = np.median(np.exp(kf0.keyframe.primitives.scaled_log_depth()))
            med_new = np.median(np.exp(new_prims.scaled_log_depth()))
            c = float(np.log(med / med_new))
            new_prims = new_prims.with_log_scales(new_prims.log_scales + c)
            T_01 = np.asarray(sfm.T_ref_view[0], dtype=float).copy()
            T_01[:3, 3] *= np.exp(c)
        else:
            T_01 = np.asarray(sfm.T_ref_view[0], dtype=float)
        keyframe0 = Keyframe.build(kf0.image, new_prims, kf0.keyframe.T_world_kf,
                                   self.config.keyframe_levels, self.config.selection)
        return keyframe0, T_01

    def _retrack(self, keyframe0: Keyframe, frame0: int, idx: int, T_01: np.ndarray,
                 brightness: np.ndarray) -> Tuple[List[RetrackedFrame], np.ndarray]:
        """Re-track the buffered frames against the solved keyframe 0: from the
        constant-velocity guess, else from the pose interpolated between keyframes
        0 and 1 at the frame's place in the gap (a failed frame leaves no velocity).
        Returns the frames and the last good pose."""
        tracker = self.config.tracker
        T_w0 = keyframe0.T_world_kf
        prev = None
        last = T_w0.copy()
        xi01 = gtsam.Pose3.Logmap(gtsam.Pose3(T_01))
        out: List[RetrackedFrame] = []
        for j, img in self.buffer:
            tj = track_frame(keyframe0, img, constant_velocity_guess(last, prev), brightness,
                             tracker)
            if not tj.ok:
                frac = (j - frame0) / max(idx - frame0, 1)
                T_guess = T_w0 @ gtsam.Pose3.Expmap(frac * xi01).matrix()
                tj2 = track_frame(keyframe0, img, T_guess, brightness, tracker)
                if tj2.ok or tj2.photometric_cost < tj.photometric_cost:
                    tj = tj2
            if tj.ok:
                prev, last = last, tj.T_world_frame
                out.append(RetrackedFrame(j, img, True, tj.T_world_frame.copy(),
                                          invert_pose(T_w0) @ tj.T_world_frame,
                                          np.asarray(tj.brightness, float)))
            else:
                out.append(RetrackedFrame(j, img, False, last.copy()))
        return out, last
