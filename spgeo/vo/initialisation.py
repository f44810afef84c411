"""The VO's map initialisation (docs/design.md §5.1, *Initialisation*): the
stage of :class:`spgeo.vo.Odometry` that waits for keyframe 1 and solves
keyframes 0 and 1 with few-view SfM (:class:`InitialisationStage`), the
supporting views of that SfM, the check that its result may initialise a map
and the bounded buffer of frames waiting for keyframe 1.

A keyframe pair without parallax never initialises a map: the frames stay
``INIT`` (tracked against keyframe 0) or ``LOST`` and
:attr:`Odometry.init_failure` says why.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..frame import Frame
from ..geometry import invert_pose, rotation_angle_deg
from ..primitives import PrimitiveSet
from ..sfm import SfMResult, few_view_sfm
from ..sfm.init import twoview_initialisation
from .mapping import MapKeyframe, SupportCandidate, apply_primitive_model
from .result import FrameResult, FrameStatus
from .tracking import Keyframe, TrackResult, constant_velocity_guess, track_frame

__all__ = ["InitialisationStage", "init_views", "init_rejection", "append_bounded",
           "twoview_start"]

log = logging.getLogger(__name__)


def init_views(image: np.ndarray, idx: int, frame0: int, buffer: Sequence[tuple], n_extra: int,
               T_kf0_f: Optional[np.ndarray]) -> Tuple[List[np.ndarray], Optional[List[np.ndarray]]]:
    """Supporting views of the initialisation's SfM and their initial poses.

    Args:
        image: keyframe 1's image (frame ``idx``).
        idx, frame0: frame numbers of keyframes 1 and 0.
        buffer: ``(frame number, image)`` of the frames waiting between them.
        n_extra: ``OdometryConfig.init_extra_views``.
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
    decides, so its status must also be ``"ok"`` (before ``init_max_gap`` the
    caller also asks its baseline for ``init_min_parallax``).
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


def append_bounded(buffer: list, item, cap: int) -> None:
    """Append ``item`` to ``buffer``; beyond ``cap`` entries every other older
    entry is dropped (the newest is kept), so a long wait holds a bounded,
    evenly thinned set of frames."""
    buffer.append(item)
    if len(buffer) > cap:
        buffer[:] = buffer[:-1][::2] + buffer[-1:]


class InitialisationStage:
    """The initialisation stage of :class:`spgeo.vo.Odometry` (a base class of
    it, split out for length): :meth:`_initialise` handles one frame of a map
    segment that has only its keyframe 0, on ``Odometry``'s state (its
    keyframes, buffer, poses, configuration and front-end)."""

    def _init_pending(self, frame: Frame, idx: int, kf0: MapKeyframe, tr: TrackResult,
                      T_kf0_f: np.ndarray) -> FrameResult:
        """A frame waiting for keyframe 1: buffered; ``INIT`` at its pose tracked
        against keyframe 0, or ``LOST`` at the last good pose."""
        append_bounded(self._init_buffer, (idx, np.asarray(frame.image)),
                       2 * self.config.init_max_gap)
        if tr.ok:
            self._rel[idx] = (kf0.index, T_kf0_f, kf0.keyframe.median_depth)
        pose = tr.T_world_frame if tr.ok else self._last_good
        return FrameResult(idx, float(frame.timestamp), pose.copy(),
                           FrameStatus.INIT if tr.ok else FrameStatus.LOST, track=tr)

    def _initialise(self, frame: Frame, idx: int, timings: Dict[str, float]) -> FrameResult:
        kf0 = self._kfs[self._seg_kfs[0]]
        t = time.perf_counter()
        tr = self._track_against(kf0.keyframe, frame.image)
        timings["track"] = time.perf_counter() - t
        T_kf0_f = invert_pose(kf0.keyframe.T_world_kf) @ tr.T_world_frame
        if tr.ok:
            self._accept(tr)
            self._n_lost = 0
        else:
            self._n_lost += 1
        parallax = (np.linalg.norm(T_kf0_f[:3, 3]) / kf0.keyframe.median_depth
                    if tr.ok else 0.0)
        gap = idx - kf0.frame
        cfg = self.config
        # keyframe 1 must still overlap keyframe 0: the overlap criteria of
        # keyframes (valid fraction, rotation) end the wait too
        rot = rotation_angle_deg(T_kf0_f[:3, :3])
        overlap_ending = tr.ok and (tr.valid_fraction < cfg.kf_min_valid_fraction
                                    or rot > cfg.kf_max_rotation_deg)
        # a frame lost against keyframe 0's unscaled shapes (large motion) ends
        # the wait too (retries spaced out); its SfM must then pass its own checks
        early = not tr.ok and gap < cfg.init_max_gap
        wait = gap < cfg.init_max_gap and not overlap_ending and (
            (tr.ok and (parallax < cfg.init_min_parallax or gap < cfg.init_min_gap))
            or (early and gap < self._init_retry_gap))
        # past init_max_gap after a keyframe pair without parallax: retries spaced out,
        # unless the tracked parallax is reached or keyframe 0's view is ending
        wait = wait or (gap < self._init_wait_until and not overlap_ending
                        and not (tr.ok and parallax >= cfg.init_min_parallax))
        if wait:
            self._init_wait_note = (
                f"waiting for keyframe 1: {gap} frames after keyframe 0, " + (
                    f"parallax {parallax:.3g} < init_min_parallax {cfg.init_min_parallax:g}"
                    if tr.ok else f"frame lost against keyframe 0 ({tr.reason})"))
            return self._init_pending(frame, idx, kf0, tr, T_kf0_f)
        # ---- SfM: keyframe 0 of the segment (reference), this frame and extra views
        t = time.perf_counter()
        sfm_cfg = dataclasses.replace(self.config.sfm, reset_scales=not self.frontend.uses_depth)
        prims0 = kf0.keyframe.primitives
        T_init = T_kf0_f if tr.ok else None
        if tr.ok and cfg.init_method == "twoview" and not self.frontend.uses_depth:
            tv = twoview_start(kf0.image, frame.image, self.camera, prims0)
            if tv is not None:
                T_init, prims0 = tv
                sfm_cfg = dataclasses.replace(sfm_cfg, reset_scales=False)
            else:
                log.info("frame %d: no two-view estimate for keyframe 1; the SfM starts from "
                         "the tracked pose", idx)
        views, init = init_views(frame.image, idx, kf0.frame, self._init_buffer,
                                 cfg.init_extra_views, T_init)
        sfm = few_view_sfm(kf0.image, views, self.camera, prims0, sfm_cfg, init_T_ref_view=init)
        timings["init"] = time.perf_counter() - t
        finite = bool(np.all(np.isfinite(sfm.T_ref_view[0])))
        if not tr.ok and finite:  # the SfM's own baseline over its median depth
            parallax = float(np.linalg.norm(sfm.T_ref_view[0][:3, 3]) / np.median(
                np.exp(sfm.primitives.scaled_log_depth())))
        failed = sfm.status == "diverged" or (early and (sfm.status != "ok"
                                                         or parallax < cfg.init_min_parallax))
        rejected = None if failed else init_rejection(sfm, tr.ok)
        self._sfm_reports.append({
            "status": sfm.status, "frame": idx, "segment": self._segment, "parallax": parallax,
            "sfm_parallax": (sfm.report.get("parallax") or [None])[0], "n_views": len(views),
            "accepted": not (failed or not finite or rejected), "rejected": rejected,
            **{k: sfm.report.get(k) for k in ("n_primitives", "final_cost", "seconds_total")}})
        if failed or not finite:
            self._init_retry_gap = gap + max(1, gap // 2)
            self._init_failure = f"frame {idx}: SfM of keyframes 0-1 {sfm.status}"
            log.warning("two-view initialisation failed at frame %d (SfM status %s, parallax "
                        "%.3g); retrying later", idx, sfm.status, parallax)
            append_bounded(self._init_buffer, (idx, np.asarray(frame.image)), 2 * cfg.init_max_gap)
            self._n_lost += 1
            return FrameResult(idx, float(frame.timestamp), self._last_good.copy(), FrameStatus.LOST,
                               track=tr)
        if rejected is not None:
            # no baseline between keyframes 0 and 1: no map; wait for motion
            self._init_wait_until = max(gap, cfg.init_max_gap) + max(1, gap // 2)
            self._init_failure = f"frame {idx}: no map initialised from keyframes 0-1 ({rejected})"
            log.warning("%s; waiting for camera motion", self._init_failure)
            return self._init_pending(frame, idx, kf0, tr, T_kf0_f)
        new_prims = sfm.primitives
        if self.config.primitive_model != "integrated":
            new_prims = apply_primitive_model(new_prims, self.config.primitive_model)
        T_w0 = kf0.keyframe.T_world_kf
        if not self.frontend.uses_depth and self._segment > 0:
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
        kf0.keyframe = Keyframe.build(kf0.image, new_prims, T_w0, self.config.levels,
                                      self.config.selection)
        T1 = T_w0 @ T_01
        # re-track the buffered frames against the solved keyframe 0: from the
        # constant-velocity guess, else from the pose interpolated between keyframes
        # 0 and 1 at the frame's place in the gap (a failed frame leaves no velocity)
        prev = None
        last = T_w0.copy()
        xi01 = gtsam.Pose3.Logmap(gtsam.Pose3(T_01))
        for j, img in self._init_buffer:
            tj = track_frame(kf0.keyframe, img, constant_velocity_guess(last, prev),
                             self._brightness, self.config.tracker)
            if not tj.ok:
                frac = (j - kf0.frame) / max(idx - kf0.frame, 1)
                T_guess = T_w0 @ gtsam.Pose3.Expmap(frac * xi01).matrix()
                tj2 = track_frame(kf0.keyframe, img, T_guess, self._brightness,
                                  self.config.tracker)
                if tj2.ok or tj2.photometric_cost < tj.photometric_cost:
                    tj = tj2
            if tj.ok:
                prev, last = last, tj.T_world_frame
                self._frames[j].T_world_cam = tj.T_world_frame.copy()
                self._frames[j].status = FrameStatus.INIT
                self._rel[j] = (kf0.index, invert_pose(T_w0) @ tj.T_world_frame,
                                kf0.keyframe.median_depth)
                self._candidates.append(SupportCandidate(j, img, self._rel[j][1],
                                                   np.asarray(tj.brightness, float)))
            else:
                self._frames[j].status = FrameStatus.LOST
                self._frames[j].T_world_cam = last.copy()
                self._rel.pop(j, None)
        self._init_buffer.clear()
        self._last_good, self._prev_good = T1.copy(), last.copy()
        self._n_lost = 0
        return self._new_keyframe(frame, idx, T1, timings, track=tr)
