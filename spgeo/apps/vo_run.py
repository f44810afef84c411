"""Batch runner of the monocular VO (:class:`spgeo.vo.Odometry`) over a
frame sequence or a data set, with Sim(3) ATE against the ground truth
(an application: the ATE comes from :mod:`spgeo.metrics.ate`).

* :func:`run_odometry`: frames (any iterable of :class:`~spgeo.frame.Frame`)
  -> :class:`VORun`.  Every image is resized to the VO's processing size
  (:meth:`spgeo.vo.OdometryConfig.processing_size_for` of the first frame's
  size: ``odometry.resolution`` when set, else about ``odometry.target_pixels``
  pixels with the input's aspect ratio, :mod:`spgeo.vo.processing`, as
  :class:`spgeo.vo.Odometry` does with full-size frames); the
  depth map is resized (``cv2.INTER_NEAREST``) and passed on **only** when the
  front-end uses depth (``frontend.uses_depth``): with a monocular front-end
  the runner never touches ``Frame.depth``.  A frame of a random-access
  sequence (a data-set reader) whose file cannot be read
  (:class:`~spgeo.validation.FrameReadError`) never reaches the VO: it is
  skipped with a warning naming the file (``VORun.skipped``; status ``skipped``
  in the status file, no pose, not in the ATE), or with ``VORunConfig.strict``
  the error propagates.  Any other error propagates.
* :func:`run_dataset`: the same on a data set opened with
  :func:`spgeo.datasets.open_dataset`, with ``load_depth=False`` for a
  monocular front-end (the depth files are not even opened).
* :func:`run_vo`: :func:`run_odometry` returning ``(odometry, ground truth,
  FPS)`` (the former ``spgeo.evaluation.vo_run.run_vo``).
* :class:`~spgeo.apps.vo_outcome.VORun` (:mod:`spgeo.apps.vo_outcome`) holds the result:
  :meth:`VORun.ate`: per-frame and keyframe-only Sim(3)-aligned ATE (evo,
  ``evo_ape -as`` equivalent) over the frames not flagged ``"lost"``.
* :meth:`VORun.save`: ``trajectory.txt`` (every processed frame, TUM format,
  camera-to-world ``T_world_cam``), ``keyframes.txt``,
  ``trajectory.status.txt``, ``report.json`` (with ``"run"`` and, when there
  is ground truth, ``"ate"``) and keyframe point clouds in ``clouds/``.

Frames: ``T_world_cam`` is the 4x4 camera-to-world pose; the VO's world is
keyframe 0's camera (arbitrary scale for a monocular front-end), the
ground truth's world is the data set's.  Translations are in metres for the
ground truth, in the VO's unit for the estimate; ATE is in ground-truth metres
after the Sim(3) alignment.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, List, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame, frame_label
from ..frontend import (FRONTENDS, MONOCULAR_FRONTENDS, MetricDepthEstimator,
                        PrimitiveFrontEnd, build_frontend, check_model_options)
from ..vo import Odometry, OdometryConfig
from ..vo.processing import resize_for_vo
from ..vo.saved_map import SavedMap
from ..io.fusion import FusionConfig
from ..vo.metric_scale import MetricScale, estimate_metric_scale
from ..validation import FrameReadError
from .memory import RssCheckpoints
from .vo_outcome import SkippedFrame, VORun

__all__ = ["VORunConfig", "run_odometry", "run_dataset", "run_live", "run_vo", "make_vo_frontend",
           "blas_threads", "load_metric_model", "run_metric_scale"]

log = logging.getLogger(__name__)

#: :func:`run_odometry` records the current RSS after every this many frames
#: (``report.json``'s ``run.memory``)
RSS_EVERY = 100

#: Per-frame hook of :func:`run_odometry`: ``(frame, frame_result, odometry) -> None``.
FrameHook = Callable[[Frame, Any, Any], None]



@config_class
@dataclass(frozen=True)
class VORunConfig:
    """Options of :func:`run_odometry` / :func:`run_dataset`.

    Attributes:
        strict: abort on a frame whose file cannot be read
            (:class:`~spgeo.validation.FrameReadError` propagates); default False:
            such a frame is skipped with a warning naming the file, marked
            ``skipped`` in the status file and listed in ``report.json``.
        frontend: front-end name for :func:`spgeo.frontend.make_frontend`:
            ``"classical"`` (default; monocular, reads no depth), ``"manhattan"``
            (monocular, vanishing-point normals), ``"depth"`` (normals and initial
            scales from the sensor depth: RGB-D / oracle), ``"onnx"`` (SAM + normal
            network) or ``"onnx-depth"`` (SAM + normals from a depth network; models
            from ``spgeo models fetch``).  Ignored when a built front-end is given.
        odometry: :class:`~spgeo.vo.OdometryConfig` of the VO.
        progress: show a tqdm progress bar with live FPS (default True).
        sam_family: ``onnx`` / ``onnx-depth``: SAM registry family (default
            None: the registry default, ``efficientsam-vitt``; ``onnx-depth``
            then uses classical segments).
        normal_model: ``onnx``: normal-network registry name or ``.onnx`` path
            (default None: ``metric3d-vit-small-fp16``).  Refused with
            ``onnx-depth`` (``ValueError`` pointing to ``depth_model``).
        depth_model: ``onnx-depth``: depth-network registry name (built-in or
            registered with ``spgeo models register``) or ``.onnx`` path
            (default None: ``depth-anything-v2-small``).  Refused with any
            other ``frontend``: :func:`run_odometry` / :func:`run_dataset` raise
            ``ValueError`` naming it before the first frame
            (:func:`spgeo.frontend.check_model_options`; checked when the run
            starts, not here, so that ``--set`` / ``--config`` may give
            ``depth_model`` and ``frontend`` in any order).
        ate_max_time_diff: timestamp tolerance (seconds, or frames for data
            sets timed by frame number) of the ATE association (default 1e-3:
            estimate and ground truth share the frames' timestamps).
        blas_threads: BLAS threads while the run lasts (threadpoolctl; default
            1: the VO's matrices are small, and idle BLAS workers spinning on
            the other core slow the main thread); None leaves BLAS as it is.
        metric_scale: a metric-depth network (registry name, built-in or
            registered with ``spgeo models register NAME PATH --preset
            fastdepth``, or an ``.onnx`` path read with the ``fastdepth``
            preset; :func:`spgeo.frontend.metric_depth_from_cache`) whose depth
            gives the run's OUTPUT scale after the last frame
            (:func:`spgeo.vo.metric_scale.estimate_metric_scale` over the
            keyframes with depth): the run's trajectory, clouds, mesh and
            exports are then in metres (:attr:`VORun.metric_scale
            <spgeo.apps.vo_outcome.VORun>`, ``report.json``'s ``"metric_scale"``),
            the VO itself never sees it.  The model is loaded before the first
            frame: ``FileNotFoundError`` / ``ValueError`` naming it when it is
            missing, breaks its preset's contract or is not metric.  Default
            None: outputs in the VO's unit.
        capture_ring: live input (:func:`run_live`, a camera): frames the
            capture thread holds while the VO is busy
            (:class:`~spgeo.datasets.capture.CaptureRing`; the oldest is dropped
            when it is full).  Default 8; docs/results.md, "Real time with a
            camera", says why.
        fusion: :class:`~spgeo.io.fusion.FusionConfig` of the TSDF fusion
            (``spgeo vo --mesh``, :meth:`VORun.fuse <spgeo.apps.vo_outcome.VORun>`):
            voxel size, truncation, depth cut-off (world units, or fractions of
            the first keyframe's median depth when None), e.g.
            ``--set fusion.voxel_size=0.01``; ``report.json``'s ``"fusion"``
            holds the values used.
    """

    #: keys of a config file or ``--set`` that are not run fields are odometry
    #: fields (:func:`spgeo.configs.apply_overrides`)
    config_route = "odometry"

    strict: bool = False
    frontend: str = "classical"
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    progress: bool = True
    sam_family: Optional[str] = None
    normal_model: Optional[str] = None
    depth_model: Optional[str] = None
    ate_max_time_diff: float = 1e-3
    blas_threads: Optional[int] = 1
    metric_scale: Optional[str] = None
    capture_ring: int = 8
    fusion: FusionConfig = field(default_factory=FusionConfig)

    def __post_init__(self) -> None:
        if self.frontend not in FRONTENDS:
            raise ValueError(f"VORunConfig.frontend must be one of {FRONTENDS}, "
                             f"got {self.frontend!r}")
        check_model_options(self.frontend, self.normal_model)
        if not self.ate_max_time_diff > 0:
            raise ValueError("VORunConfig.ate_max_time_diff must be > 0")
        if self.capture_ring < 1:       # an integer: config_class checked the types
            raise ValueError(f"VORunConfig.capture_ring must be >= 1, "
                             f"got {self.capture_ring!r}")
        if self.metric_scale is not None and not (isinstance(self.metric_scale, str)
                                                  and self.metric_scale.strip()):
            raise ValueError("VORunConfig.metric_scale must be None or a model name / .onnx "
                             f"path, got {self.metric_scale!r}")


def make_vo_frontend(config: VORunConfig = VORunConfig(),
                     size: Optional[Tuple[int, int]] = None) -> PrimitiveFrontEnd:
    """The front-end named by ``config.frontend`` with working size ``size``
    (default ``config.odometry.resolution``; None when both are None: the
    frames' size), built by :func:`spgeo.frontend.build_frontend` from
    ``sam_family``, ``normal_model`` and ``depth_model``.

    ``onnx`` and ``onnx-depth`` raise ``FileNotFoundError`` when their models are
    not in the cache, ``ValueError`` when a model breaks its preset's contract.
    """
    size = config.odometry.resolution if size is None else tuple(size)
    return build_frontend(config.frontend, size, sam_family=config.sam_family,
                          normal_model=config.normal_model, depth_model=config.depth_model)


def run_odometry(frames: Iterable[Frame], config: VORunConfig = VORunConfig(),
                 frontend: Optional[PrimitiveFrontEnd] = None,
                 n_frames: Optional[int] = None,
                 on_frame: Optional[FrameHook] = None,
                 saved_map: Optional[SavedMap] = None) -> VORun:
    """Run the VO over ``frames`` (see the module docstring).

    Args:
        frames: :class:`~spgeo.frame.Frame` objects in time order (a list, a
            data-set reader, a generator), all from one camera size;
            ``T_world_cam`` is kept as ground truth, never given to the VO.
            ``depth`` is read only when the front-end uses depth.
        config: :class:`VORunConfig`.
        frontend: an already-built front-end (overrides ``config.frontend``;
            its working size should be the processing size,
            :meth:`spgeo.vo.OdometryConfig.processing_size_for`).
        n_frames: total for the progress bar (default ``len(frames)`` when
            available).
        on_frame: optional hook called after every tracked frame as
            ``on_frame(frame, frame_result, odometry)``: ``frame`` is the frame
            as the VO saw it (resized) with the ground-truth ``T_world_cam``
            when known (never given to the VO), ``frame_result`` the
            :class:`~spgeo.vo.result.FrameResult`, ``odometry`` the
            :class:`~spgeo.vo.Odometry` (e.g. :class:`spgeo.apps.rerun_logger.RerunLogger`).
        saved_map: a :class:`~spgeo.vo.saved_map.SavedMap` the run relocalises into and
            continues in (``spgeo vo --load-map``; default None: a map of its own).

    Ctrl-C (``KeyboardInterrupt``) after the first frame ends the run early: the
    frames processed so far are returned with ``VORun.interrupted`` set.

    Raises:
        ValueError: ``config.depth_model`` with a front-end other than
            ``onnx-depth`` (before any frame), a ``saved_map`` saved at another
            processing camera, primitive model or units, no frame (or every frame
            skipped), frames of different camera sizes, timestamps not
            strictly increasing, a depth-using front-end and a frame without
            depth, or an image the VO rejects.
        FrameReadError: (a ``ValueError``) with ``config.strict``, the first
            frame whose file cannot be read.
    """
    check_model_options(config.frontend, config.normal_model, config.depth_model)
    with blas_threads(config.blas_threads):
        return _run_odometry(frames, config, frontend, n_frames, on_frame, saved_map)


def blas_threads(n: Optional[int]):
    """Context manager limiting BLAS to ``n`` threads (no-op for None)."""
    import contextlib

    if n is None:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=int(n), user_api="blas")


def _indexed_frames(frames: Iterable[Frame]) -> Iterator[Tuple[int, Union[Frame, FrameReadError]]]:
    """``(position, frame)`` pairs.  For a random-access sequence (a list, a
    data-set reader) a frame whose file cannot be read gives its
    :class:`~spgeo.validation.FrameReadError` in place of the frame and the
    iteration goes on; any other iterable is consumed as it is (an error raised
    inside a generator ends it)."""
    if isinstance(frames, SequenceABC):
        for i in range(len(frames)):
            try:
                f = frames[i]
            except FrameReadError as exc:
                yield i, exc
                continue
            yield i, f
        return
    yield from enumerate(frames)


def _checked_stamp(i: int, f: Frame, cam_in: PinholeCamera, stamps: List[float]) -> float:
    """Frame ``i``'s timestamp, after checking its camera and that the
    timestamp is finite and after the previous one (ValueError otherwise)."""
    if f.camera.shape != cam_in.shape:
        raise ValueError(f"{frame_label(f.name, i)} is {f.camera.width}x{f.camera.height}, "
                         f"the first frame {cam_in.width}x{cam_in.height}: all frames "
                         "must share one camera")
    ts = float(f.timestamp)
    if not np.isfinite(ts) or (stamps and ts <= stamps[-1]):
        raise ValueError(f"{frame_label(f.name, i)}: timestamp {ts} is not finite or not "
                         f"after the previous one ({stamps[-1] if stamps else None})")
    return ts


@dataclass
class _Loop:
    """State of one :func:`run_odometry` loop: the odometry (opened on the first
    readable frame, with its processing size) and the per-frame records."""

    config: VORunConfig
    frontend: Optional[PrimitiveFrontEnd]
    on_frame: Optional[FrameHook] = None
    vo: Optional[Odometry] = None
    cam_in: Optional[PinholeCamera] = None
    cam: Optional[PinholeCamera] = None
    gt: List[Optional[np.ndarray]] = field(default_factory=list)
    stamps: List[float] = field(default_factory=list)
    names: List[str] = field(default_factory=list)
    memory: RssCheckpoints = field(default_factory=lambda: RssCheckpoints(RSS_EVERY))
    counts: Counter = field(default_factory=Counter)
    skipped: List[SkippedFrame] = field(default_factory=list)
    metric_model: Optional[MetricDepthEstimator] = None
    saved_map: Optional[SavedMap] = None

    def _open(self, camera: PinholeCamera) -> None:
        """The processing size, front-end and :class:`Odometry` from the first frame's camera."""
        size = self.config.odometry.processing_size_for(camera.size)
        fe = self.frontend if self.frontend is not None else make_vo_frontend(self.config, size)
        ain, aout = camera.width / camera.height, size[0] / size[1]
        if abs(ain / aout - 1.0) > 0.01:
            log.warning("resolution %dx%d changes the aspect ratio of the %dx%d input "
                        "(fx and fy scale differently)", size[0], size[1],
                        camera.width, camera.height)
        self.vo = Odometry(camera, self.config.odometry, fe, saved_map=self.saved_map)
        self.cam_in, self.cam = camera, self.vo.camera

    def step(self, i: int, f: Frame):
        """Track frame ``i``; returns its :class:`~spgeo.vo.result.FrameResult`."""
        if self.vo is None:
            self._open(f.camera)
        ts = _checked_stamp(i, f, self.cam_in, self.stamps)
        small = resize_for_vo(f, self.cam, bool(self.vo.frontend.uses_depth), i)
        r = self.vo.track(small)
        self.gt.append(None if f.T_world_cam is None
                       else np.asarray(f.T_world_cam, dtype=np.float64).copy())
        self.stamps.append(ts)
        self.names.append(str(f.name))
        self.counts[r.status] += 1
        self.memory.frame_done()
        if self.on_frame is not None:
            gt = self.gt[-1]
            self.on_frame(small if gt is None else replace(small, T_world_cam=gt), r, self.vo)
        return r

    def skip(self, exc: FrameReadError) -> None:
        """Record an unreadable frame (or, with ``config.strict``, raise ``exc``)."""
        if self.config.strict:
            raise exc
        log.warning("skipping frame %d: %s", exc.index, exc)
        self.skipped.append(SkippedFrame(exc.index, exc.timestamp, exc.path, exc.reason))
        self.counts["skipped"] += 1


def _run_odometry(frames: Iterable[Frame], config: VORunConfig,
                  frontend: Optional[PrimitiveFrontEnd], n_frames: Optional[int],
                  on_frame: Optional[FrameHook] = None,
                  saved_map: Optional[SavedMap] = None) -> VORun:
    if n_frames is None and hasattr(frames, "__len__"):
        n_frames = len(frames)  # type: ignore[arg-type]
    from tqdm import tqdm

    loop = _Loop(config, frontend, on_frame, metric_model=load_metric_model(config.metric_scale),
                 saved_map=saved_map)
    interrupted = False
    t0 = time.perf_counter()
    bar = tqdm(total=n_frames, disable=not config.progress, desc="vo", unit="frame",
               dynamic_ncols=True)
    try:
        for i, f in _indexed_frames(frames):
            bar.update(1)
            if isinstance(f, FrameReadError):
                loop.skip(f)
                continue
            r = loop.step(i, f)
            if config.progress:
                fps = len(loop.stamps) / max(time.perf_counter() - t0, 1e-9)
                bar.set_postfix({"fps": f"{fps:.1f}",
                                 "kf": loop.vo.n_keyframes, "lost": loop.counts["lost"],
                                 "skipped": loop.counts["skipped"], "status": r.status},
                                refresh=False)
    except KeyboardInterrupt:
        if not loop.stamps:
            raise
        interrupted = True
        log.warning("VO interrupted after %d frames", len(loop.stamps))
    finally:
        bar.close()
    return _finish(loop, time.perf_counter() - t0, interrupted)


def _finish(loop: _Loop, wall: float, interrupted: bool) -> VORun:
    """The :class:`VORun` of a finished loop (``ValueError`` when no frame was tracked)."""
    if loop.vo is None:
        what = (f"all {len(loop.skipped)} frames were skipped as unreadable; the first: "
                f"{loop.skipped[0].reason}"
                if loop.skipped else "no frames (empty sequence or frame selection)")
        raise ValueError(f"run_odometry: {what}")
    n = len(loop.stamps)
    metric, metric_failure = _metric_outcome(loop)
    log.info("VO: %d frames in %.2f s (%.1f FPS), %d keyframes, %d lost, %d skipped", n, wall,
             n / max(wall, 1e-9), loop.vo.n_keyframes, loop.counts["lost"], len(loop.skipped))
    return VORun(loop.vo, loop.gt, np.array(loop.stamps, dtype=np.float64), loop.names, wall,
                 n / max(wall, 1e-9), loop.config, interrupted,
                 resolution=loop.cam.size, skipped=loop.skipped,
                 memory=loop.memory.report(),
                 metric_scale=metric, metric_scale_failure=metric_failure)


def _metric_outcome(loop: _Loop) -> Tuple[Optional[MetricScale], Optional[str]]:
    """``(MetricScale, None)`` of a finished loop with a metric model, ``(None,
    reason)`` when no keyframe allows it (logged: the outputs stay in VO
    units), ``(None, None)`` without a model."""
    if loop.metric_model is None:
        return None, None
    try:
        return run_metric_scale(loop.vo, loop.metric_model, loop.config.metric_scale), None
    except ValueError as exc:
        log.warning("outputs left in VO units: %s", exc)
        return None, str(exc)


def load_metric_model(name: Optional[str]) -> Optional[MetricDepthEstimator]:
    """The metric-depth network of ``VORunConfig.metric_scale`` (None for None):
    :func:`spgeo.frontend.metric_depth_from_cache`, its ``FileNotFoundError`` /
    ``ValueError`` (missing, broken contract, not metric) re-raised naming the option."""
    if name is None:
        return None
    from ..frontend import metric_depth_from_cache

    try:
        return metric_depth_from_cache(name)
    except (FileNotFoundError, ValueError) as exc:
        raise type(exc)(f"metric scale model {name!r}: {exc}") from None


def run_metric_scale(odometry: Odometry, model: MetricDepthEstimator,
                     name: Optional[str] = None) -> MetricScale:
    """The :class:`~spgeo.vo.metric_scale.MetricScale` of a finished run from
    ``model.predict_metric`` on its keyframes with depth (images at the
    primitives' size, :func:`spgeo.io.fusion.odometry_views`), with ``model``
    ``name`` and the seconds it took.  Raises ``ValueError`` when no keyframe
    allows it (no keyframe with depth: no map; no overlap)."""
    from ..io.fusion import odometry_views

    if not odometry.keyframes_with_depth():
        raise ValueError("no metric scale: no keyframe carries depth (no map was initialised)")
    t0 = time.perf_counter()
    pairs = ((image, depth) for image, depth, _, _ in odometry_views(odometry))
    est = estimate_metric_scale(pairs, model.predict_metric)
    return replace(est, model=name, seconds=time.perf_counter() - t0)


def run_dataset(kind: str, path: Union[str, Path], frames: Optional[str] = None,
                config: VORunConfig = VORunConfig(),
                frontend: Optional[PrimitiveFrontEnd] = None,
                on_frame: Optional[FrameHook] = None, saved_map: Optional[SavedMap] = None,
                **reader_options) -> VORun:
    """Open a data set with :func:`spgeo.datasets.open_dataset` and run the VO.

    Args:
        kind: a key of :data:`spgeo.datasets.DATASET_KINDS` (``"tum"``,
            ``"7scenes"``, ``"icl"``, ``"folder"``, ``"kitti"``, ``"euroc"``,
            ``"video"``, ``"camera"``).
        path: the sequence folder, video file or camera index.
        frames: ``"A:B[:S]"`` selection by frame number (default None: all).
        config, frontend, on_frame, saved_map: as for :func:`run_odometry`.
        reader_options: further reader-config fields (e.g. ``calibration="fr1"``)
            or ``given_camera`` (:func:`~spgeo.datasets.open_dataset`).

    The run's ``intrinsics`` (``report.json``) is the reader's ``intrinsics``.  A live
    camera (``"camera"``) runs with ``OdometryConfig.mapping.schedule="ready"`` (its
    input already depends on timing: updates are applied as soon as they are ready);
    recorded input keeps the configured schedule (default ``"fixed"``: deterministic).

    With a monocular front-end the data set is opened with ``load_depth=False``
    (no depth file is read).  Raises ``FileNotFoundError`` / ``ValueError``
    from the reader (missing folder, empty selection, ...), and ``ValueError``
    for ``config.depth_model`` with a front-end other than ``onnx-depth``
    before the data set is opened.
    """
    from ..datasets import open_dataset

    check_model_options(config.frontend, config.normal_model, config.depth_model)

    uses_depth = (bool(frontend.uses_depth) if frontend is not None
                  else config.frontend not in MONOCULAR_FRONTENDS)
    opts = dict(reader_options)
    opts.setdefault("load_depth", uses_depth)
    if opts["load_depth"] is False and uses_depth:
        raise ValueError("the front-end uses depth: the data set must be read with depth")
    seq = open_dataset(kind, path, frames=frames, **opts)
    n = len(seq) if hasattr(seq, "__len__") else None      # a live camera has no length
    if n == 0:
        raise ValueError(f"{path}: the frame selection {frames!r} is empty")
    log.info("VO on %s (%s): %s frames, camera %r, processing size %s", seq.name, kind,
             "live" if n is None else n, seq.camera,
             config.odometry.processing_size_for(seq.camera.size))
    if kind == "camera":
        run = run_live(seq, config, frontend, on_frame=on_frame, saved_map=saved_map)
    else:
        run = run_odometry(seq, config, frontend, n_frames=n, on_frame=on_frame,
                           saved_map=saved_map)
    run.intrinsics = seq.intrinsics
    return run


def run_live(source: Iterable[Frame], config: VORunConfig = VORunConfig(),
             frontend: Optional[PrimitiveFrontEnd] = None,
             on_frame: Optional[FrameHook] = None,
             saved_map: Optional[SavedMap] = None) -> VORun:
    """The VO on a live source (a camera, or a simulated one): its frames read
    by a capture thread into a :class:`~spgeo.datasets.capture.CaptureRing` of
    ``config.capture_ring`` frames, and :func:`run_odometry` with
    ``OdometryConfig.mapping.schedule="ready"`` (the input already depends on
    timing: the tracker never waits for the back end, :mod:`spgeo.vo.mapping_port`).
    The returned :attr:`VORun.capture` is the ring's report (frames dropped, with
    their names); arguments and errors as :func:`run_odometry`."""
    from ..datasets.capture import CaptureRing

    config = dataclasses.replace(config, odometry=dataclasses.replace(
        config.odometry, mapping=dataclasses.replace(config.odometry.mapping, schedule="ready")))
    ring = CaptureRing(source, config.capture_ring)
    try:
        run = run_odometry(ring, config, frontend, on_frame=on_frame, saved_map=saved_map)
    finally:
        ring.close()
    run.capture = ring.report()
    if run.capture["dropped"]:
        log.warning("live input: %d of %d frames dropped by the capture ring (longest run %d)",
                    run.capture["dropped"], run.capture["arrived"],
                    run.capture["longest_drop_run"])
    return run


def run_vo(frames: Iterable[Frame], resolution: Optional[Tuple[int, int]] = None,
           frontend: str = "classical", config: OdometryConfig = OdometryConfig(),
           progress: bool = True) -> Tuple[Odometry, List[Optional[np.ndarray]], float]:
    """VO over a frame sequence resized to ``resolution`` (width, height pixels;
    default None: ``config.resolution``, else the processing size of the
    frames' size, as ``spgeo vo``).

    Returns ``(odometry, ground-truth camera-to-world poses (None per frame
    without), frames per wall-clock second)``; see :func:`run_odometry`.
    """
    if resolution is not None:
        config = replace(config, resolution=tuple(resolution))
    run = run_odometry(frames, VORunConfig(frontend=frontend, odometry=config,
                                           progress=progress))
    return run.odometry, run.gt_poses, run.fps
