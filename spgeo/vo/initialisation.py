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
from ..geometry import invert_pose, ray_angles_deg
from ..primitive_models import apply_primitive_model
from ..primitives import PrimitiveSet
from ..sfm import SfMResult, few_view_sfm
from ..sfm.init import twoview_initialisation
from .config import OdometryConfig
from .frame_tracker import FrameTracker, RetrackedFrame
from .keyframe_policy import KeyframePolicy
from .map import MapKeyframe
from .result import add_seconds
from .motion import MotionModel
from .tracking import Keyframe, TrackResult

__all__ = ["Initialiser", "InitDecision", "InitJob", "InitSolution", "Solving",
           "init_views", "init_rejection", "append_bounded", "twoview_start", "sfm_parallax_deg",
           "solve_keyframe1", "solved_keyframe0", "retrack"]

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
class InitJob:
    """What the keyframe-1 solve reads, picklable: :meth:`run` is a pure function
    of it, run where the mapping port says (this process, or the mapping worker
    while the tracker goes on: :meth:`spgeo.vo.mapping_port.MappingPort.solve_init`).

    Attributes:
        image, idx: keyframe 1's candidate frame and its number.
        kf0_image, kf0_frame, kf0_keyframe: keyframe 0's image, frame number and
            :class:`Keyframe` (unsolved primitives, pose).
        buffer: ``(frame number, image)`` of the frames waiting between them.
        T_kf0_f: the candidate's pose tracked against keyframe 0 (4x4).
        tracked: whether that tracking was ``ok``.
        brightness: the VO's brightness estimate (the re-tracking's start).
        segment: the map segment.
        camera, config: as :class:`Initialiser`'s.
        ahead: also solve keyframe 0 and re-track the buffer (:meth:`run`), for
            a solve away from the tracker, whose result is only judged there.
    """

    image: np.ndarray
    idx: int
    kf0_image: np.ndarray
    kf0_frame: int
    kf0_keyframe: Keyframe
    buffer: List[tuple]
    T_kf0_f: np.ndarray
    tracked: bool
    brightness: np.ndarray
    segment: int
    camera: PinholeCamera
    config: OdometryConfig
    ahead: bool = False

    def run(self) -> "InitSolution":
        """The SfM of keyframe 0, the candidate and extra views; with
        :attr:`ahead` and a finite, not diverged solve also keyframe 0 rebuilt
        with its primitives and the buffer re-tracked (images left out: the
        caller has them)."""
        t = time.perf_counter()
        sfm, n_views = solve_keyframe1(self)
        sol = InitSolution(sfm, n_views)
        if self.ahead and sfm.status != "diverged" and np.all(np.isfinite(sfm.T_ref_view[0])):
            sol.keyframe0, sol.T_01 = solved_keyframe0(self, sfm)
            retracked, sol.T_world_last = retrack(sol.keyframe0, self, sol.T_01)
            sol.retracked = [dataclasses.replace(r, image=None) for r in retracked]
        sol.seconds = time.perf_counter() - t
        return sol


@dataclass
class InitSolution:
    """:meth:`InitJob.run`'s result: the SfM, its view count and (``ahead``)
    keyframe 0 solved, ``T_kf0_kf1``, the re-tracked buffer (without images) and
    the last good re-tracked pose; ``seconds`` it took."""

    sfm: SfMResult
    n_views: int
    keyframe0: Optional[Keyframe] = None
    T_01: Optional[np.ndarray] = None
    retracked: Optional[List["RetrackedFrame"]] = None
    T_world_last: Optional[np.ndarray] = None
    seconds: float = 0.0


def solve_keyframe1(job: InitJob) -> Tuple[SfMResult, int]:
    """The SfM of keyframe 0 (reference), ``job``'s candidate and extra views;
    its view count."""
    cfg = job.config
    sfm_cfg = dataclasses.replace(cfg.sfm, reset_scales=True)
    prims0 = job.kf0_keyframe.primitives
    T_init = job.T_kf0_f if job.tracked else None
    if job.tracked and cfg.init.method == "twoview":
        tv = twoview_start(job.kf0_image, job.image, job.camera, prims0)
        if tv is not None:
            T_init, prims0 = tv
            sfm_cfg = dataclasses.replace(sfm_cfg, reset_scales=False)
        else:
            log.info("frame %d: no two-view estimate for keyframe 1; the SfM starts from "
                     "the tracked pose", job.idx)
    views, init = init_views(job.image, job.idx, job.kf0_frame, job.buffer,
                             cfg.init.extra_views, T_init)
    sfm = few_view_sfm(job.kf0_image, views, job.camera, prims0, sfm_cfg, init_T_ref_view=init)
    return sfm, len(views)


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
        keyframe1: ``"start"``: the frame number of keyframe 1: the frame
            decided for, or an earlier one whose solve ran beside the tracker.
        image1, track1: ``"start"``: keyframe 1's image and its tracking
            against keyframe 0.
        since: ``"start"`` for an earlier keyframe 1: ``(frame number, image)``
            of the buffered frames after it (tracked during its solve).
    """

    action: str
    T_kf0_frame: np.ndarray
    keyframe0: Optional[Keyframe] = None
    T_world_kf1: Optional[np.ndarray] = None
    retracked: List[RetrackedFrame] = field(default_factory=list)
    T_world_last: Optional[np.ndarray] = None
    keyframe1: Optional[int] = None
    image1: Optional[np.ndarray] = None
    track1: Optional[TrackResult] = None
    since: List[tuple] = field(default_factory=list)


class Initialiser:
    """The map initialisation of one :class:`spgeo.vo.Odometry` (module docstring).

    Args:
        config: the VO's :class:`OdometryConfig` (``init``, ``sfm``, ``keyframe_levels``,
            ``keyframe`` overlap thresholds, ``primitive_model``, ``tracker``).
        camera: the frames' intrinsics.
        solver: where the keyframe-1 solve runs: an object with
            ``solve_init(job) -> InitSolution or None`` (None: solved elsewhere,
            the tracker goes on) and ``init_result() -> InitSolution or None``
            (None while in flight), e.g. the VO's
            :class:`~spgeo.vo.mapping_port.MappingPort`; default None: solved here,
            at once.
        policy: the VO's :class:`~spgeo.vo.keyframe_policy.KeyframePolicy`, whose
            view-overlap test ends the wait for keyframe 1 (default None: one of
            ``config.keyframe`` on ``solver``).

    Attributes:
        failure: why the last keyframe-1 SfM was refused (None: none yet in
            this segment).
        wait_note: why the current wait goes on.
        reports: one dict per SfM tried (all segments).
        solving: the :class:`InitJob` solved elsewhere now, with the candidate's
            tracking (:class:`Solving`), or None.
    """

    def __init__(self, config: OdometryConfig, camera: PinholeCamera, solver=None, policy: Optional[KeyframePolicy] = None) -> None:
        self.config = config
        self.policy = policy if policy is not None else KeyframePolicy(config.keyframe, solver)
        self.camera = camera
        self.solver = solver
        self.reports: List[dict] = []
        self.reset()

    def reset(self) -> None:
        """A new segment: no buffered frame, no retry gap, no failure note, no
        solve in flight."""
        self.buffer: List[tuple] = []    # (frame index, image) before keyframe 1
        self.retry_gap = 0    # a lost frame may end the wait from this gap on
        self.wait_until = 0   # past init.max_gap, after a pair without parallax
        self.failure: Optional[str] = None
        self.wait_note: Optional[str] = None
        self.solving: Optional[Solving] = None
        self._tracks: Dict[int, tuple] = {}   # frames buffered in flight: (track, T_kf0_f)

    def _buffer_frame(self, idx: int, image: np.ndarray) -> None:
        """Buffer frame ``idx``, after every buffered frame (frames come in order:
        a refused candidate is buffered again before the frames decided after it)."""
        append_bounded(self.buffer, (idx, np.asarray(image)), 2 * self.config.init.max_gap)

    def step(self, image: np.ndarray, idx: int, kf0: MapKeyframe, tr: TrackResult,
             brightness: np.ndarray, segment: int,
             timings: Dict[str, float]) -> InitDecision:
        """Decide for frame ``idx`` (``image``) of a segment with only keyframe
        ``kf0``, given ``tr``, its tracking against keyframe 0, and
        ``brightness``, the VO's current brightness estimate (the re-tracking's
        start).  Adds ``timings["init"]`` (the seconds this thread spent) when
        an SfM runs or is concluded.  While a solve is in flight elsewhere the
        frame waits (buffered with its tracking); the frame that finds it solved
        concludes it: a ``"start"`` decision then names an earlier keyframe 1
        (:attr:`InitDecision.keyframe1`), and a refused one has the frames
        buffered meanwhile decided again, in order, before this one: the
        attempts are those of a solve that landed at once, whenever it lands."""
        T_kf0_f = invert_pose(kf0.keyframe.T_world_kf) @ tr.T_world_frame
        if self.solving is None:
            return self._decide(image, idx, kf0, tr, T_kf0_f, brightness, segment, timings)
        t = time.perf_counter()
        sol = self.solver.init_result()
        if sol is None:
            return self._wait_for_solve(image, idx, tr, T_kf0_f)
        # the frames buffered during the solve, and those before the candidate as sent
        since, self.buffer = self.buffer, list(self.solving.job.buffer)
        tracks, self._tracks = self._tracks, {}
        dec = self._conclude(self.solving, sol, since)
        add_seconds(timings, {"init": time.perf_counter() - t})
        if dec.action == START:
            return dataclasses.replace(dec, T_kf0_frame=T_kf0_f)
        for i, img in since:      # decided again; a solve sent meanwhile is polled from here on
            tr_i, T_i = tracks[i]
            if self.solving is None:
                self._decide(img, i, kf0, tr_i, T_i, brightness, segment, timings)
            else:
                self._wait_for_solve(img, i, tr_i, T_i)
        return self.step(image, idx, kf0, tr, brightness, segment, timings)

    def _wait_for_solve(self, image: np.ndarray, idx: int, tr: TrackResult,
                        T_kf0_f: np.ndarray) -> InitDecision:
        """Frame ``idx`` buffered with its tracking while a solve is in flight."""
        self._buffer_frame(idx, image)
        self._tracks[idx] = (tr, T_kf0_f)
        return InitDecision(WAIT, T_kf0_f)

    def _decide(self, image: np.ndarray, idx: int, kf0: MapKeyframe, tr: TrackResult,
                T_kf0_f: np.ndarray, brightness: np.ndarray, segment: int,
                timings: Dict[str, float]) -> InitDecision:
        """:meth:`step` with no solve in flight: wait, or solve frame ``idx`` as
        keyframe 1 (here, or sent to the solver: the frames after it are then
        buffered apart from those before, which the job holds)."""
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
        job = InitJob(np.asarray(image), idx, kf0.image, kf0.frame, kf0.keyframe,
                      list(self.buffer), T_kf0_f, bool(tr.ok), np.asarray(brightness, float),
                      segment, self.camera, self.config)
        solving = Solving(job, tr, T_kf0_f, float(parallax), bool(early))
        sol = job.run() if self.solver is None else self.solver.solve_init(job)
        if sol is None:
            self.solving, self.buffer = solving, []
            self.wait_note = f"solving keyframes 0-1 (frame {idx}) beside the tracker"
            return InitDecision(WAIT, T_kf0_f)
        dec = self._conclude(solving, sol)
        add_seconds(timings, {"init": time.perf_counter() - t})
        return dec

    def _conclude(self, solving: "Solving", sol: InitSolution,
                  since: Sequence[tuple] = ()) -> InitDecision:
        """The decision of a solved :class:`InitJob` (judged here; keyframe 0
        rebuilt and the buffer re-tracked here unless the solve did it); ``since``:
        the frames buffered while it was solved beside the tracker (not thinned
        with the frames before it: a late keyframe 1 catches them all up; a
        refused solve leaves them to :meth:`step`)."""
        job, tr = solving.job, solving.track
        self.solving = None
        gap = job.idx - job.kf0_frame
        failed, rejected = self._judge(sol.sfm, tr, job.idx, job.segment, solving.parallax,
                                       solving.early, sol.n_views)
        if failed:
            self.retry_gap = gap + max(1, gap // 2)
            self.failure = f"frame {job.idx}: SfM of keyframes 0-1 {sol.sfm.status}"
            self._buffer_frame(job.idx, job.image)
            return InitDecision(FAILED, solving.T_kf0_f)
        if rejected is not None:
            # no baseline between keyframes 0 and 1: no map; wait for motion
            self.wait_until = max(gap, self.config.init.max_gap) + max(1, gap // 2)
            self.failure = (f"frame {job.idx}: no map initialised from keyframes 0-1 "
                            f"({rejected})")
            log.warning("%s; waiting for camera motion", self.failure)
            self._buffer_frame(job.idx, job.image)
            return InitDecision(WAIT, solving.T_kf0_f)
        if sol.keyframe0 is None:
            keyframe0, T_01 = solved_keyframe0(job, sol.sfm)
            retracked, last = retrack(keyframe0, job, T_01)
        else:
            keyframe0, T_01, last = sol.keyframe0, sol.T_01, sol.T_world_last
            images = dict(job.buffer)
            retracked = [dataclasses.replace(r, image=images[r.frame]) for r in sol.retracked]
        since = list(since)
        self.buffer.clear()
        return InitDecision(START, solving.T_kf0_f, keyframe0,
                            job.kf0_keyframe.T_world_kf @ T_01, retracked, last,
                            keyframe1=job.idx, image1=job.image, track1=tr, since=since)

    def _waits(self, tr: TrackResult, T_kf0_f: np.ndarray, parallax: float, gap: int,
               early: bool) -> bool:
        """Whether the frame waits for keyframe 1 (no SfM yet)."""
        cfg = self.config
        # keyframe 1 must still overlap keyframe 0: the overlap criteria of
        # keyframes (valid fraction, rotation) end the wait too
        overlap_ending = tr.ok and self.policy.leaves_view(tr, T_kf0_f)
        # a frame lost against keyframe 0's unscaled shapes (large motion) ends
        # the wait too (retries spaced out); its SfM must then pass its own checks
        wait = gap < cfg.init.max_gap and not overlap_ending and (
            (tr.ok and (parallax < cfg.init.min_parallax or gap < cfg.init.min_gap))
            or (early and gap < self.retry_gap))
        # past init.max_gap after a keyframe pair without parallax: retries spaced out,
        # unless the tracked parallax is reached or keyframe 0's view is ending
        return wait or (gap < self.wait_until and not overlap_ending
                        and not (tr.ok and parallax >= cfg.init.min_parallax))

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


@dataclass
class Solving:
    """A keyframe-1 solve in flight: its :class:`InitJob`, the candidate's
    tracking against keyframe 0 (``track``, ``T_kf0_f``) and the parallax and
    ``early`` flag the judgement reads."""

    job: InitJob
    track: TrackResult
    T_kf0_f: np.ndarray
    parallax: float
    early: bool


def solved_keyframe0(job: InitJob, sfm: SfMResult) -> Tuple[Keyframe, np.ndarray]:
    """Keyframe 0 rebuilt with the SfM's primitives, and ``T_kf0_kf1``."""
    config, kf0 = job.config, job.kf0_keyframe
    new_prims = sfm.primitives
    if config.primitive_model != "integrated":
        new_prims = apply_primitive_model(new_prims, config.primitive_model)
    if job.segment > 0:
        # a re-initialised segment keeps the previous map's depth scale
        # (keyframe 0's primitives were set to it by Odometry._start at re-initialisation)
        med = np.median(np.exp(kf0.primitives.scaled_log_depth()))
        med_new = np.median(np.exp(new_prims.scaled_log_depth()))
        c = float(np.log(med / med_new))
        new_prims = new_prims.with_log_scales(new_prims.log_scales + c)
        T_01 = np.asarray(sfm.T_ref_view[0], dtype=float).copy()
        T_01[:3, 3] *= np.exp(c)
    else:
        T_01 = np.asarray(sfm.T_ref_view[0], dtype=float)
    keyframe0 = Keyframe.build(job.kf0_image, new_prims, kf0.T_world_kf,
                               config.keyframe_levels, config.selection)
    return keyframe0, T_01


def retrack(keyframe0: Keyframe, job: InitJob, T_01: np.ndarray
            ) -> Tuple[List[RetrackedFrame], np.ndarray]:
    """Re-track ``job``'s buffered frames against the solved keyframe 0
    (:meth:`FrameTracker.retrack <spgeo.vo.frame_tracker.FrameTracker.retrack>`):
    from a motion model started at keyframe 0 with the job's brightness (one
    constant-velocity step per buffered frame), then from the pose interpolated
    between keyframes 0 and 1 at the frame's place in the gap.  Returns the frames
    and the last good pose (keyframe 0's when none tracked)."""
    T_w0 = keyframe0.T_world_kf
    xi01 = gtsam.Pose3.Logmap(gtsam.Pose3(T_01))
    span = max(job.idx - job.kf0_frame, 1)
    motion = MotionModel()
    motion.reset(T_w0)
    motion.brightness = np.asarray(job.brightness, float).copy()
    kf0 = MapKeyframe(0, job.kf0_frame, job.kf0_image, keyframe0, job.segment)
    out = FrameTracker(job.camera, job.config).retrack(
        kf0, [(j, img, None) for j, img in job.buffer], motion,
        lambda j: T_w0 @ gtsam.Pose3.Expmap((j - job.kf0_frame) / span * xi01).matrix())
    return out, motion.last_good
