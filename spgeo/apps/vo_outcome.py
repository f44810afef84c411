"""The outcome of a batch VO run (:class:`VORun`, made by
:func:`spgeo.apps.vo_run.run_odometry`): trajectory, Sim(3) ATE against the ground
truth (:mod:`spgeo.metrics.ate`), summary lines, files, COLMAP and
nerfstudio exports and the fused mesh (:meth:`VORun.fuse`).

Frames: ``T_world_cam`` is the 4x4 camera-to-world pose; the VO's world is
keyframe 0's camera (arbitrary scale for a monocular front-end), the ground
truth's world is the data set's; ATE is in ground-truth metres after the Sim(3)
alignment.
"""
from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, Iterator, List, Optional, Tuple, Union

import numpy as np

from ..configs import config_to_dict
from ..frame import Frame
from ..io.outputs import FileInfo
from ..metrics.ate import AteResult, ate_per_frame_and_keyframes, ate_sim3
from ..trajectory import METRES, Trajectory
from ..vo import Odometry, OdometryResult
from ..vo.metric_scale import MetricScale, ScaledOdometry
from ..vo.result import write_keyframe_clouds

__all__ = ["VORun", "SkippedFrame", "ATE_LABELS", "SAVED_FILES", "GROUND_TRUTH_FILE"]

log = logging.getLogger(__name__)

#: ATE labels, as in :func:`spgeo.metrics.ate.ate_per_frame_and_keyframes`.
ATE_LABELS = ("per-frame", "keyframe-only")

#: the ground truth :meth:`VORun.save` writes beside ``trajectory.txt``
GROUND_TRUTH_FILE = "groundtruth.txt"

_TIME = "seconds (frame numbers for data sets without times, e.g. 7-Scenes)"
_TUM = "TUM 'timestamp tx ty tz qx qy qz qw', camera-to-world T_world_cam"

#: What each file of :meth:`VORun.save` is (an output manifest's ``"what"`` and
#: ``"units"``, :meth:`VORun.describe_files`), by the key of the paths ``save`` returns;
#: ``{pos}``: :attr:`VORun.position_units`, ``{time}``: the timestamps' unit, ``{name}``:
#: the file's stem.  A file ``save`` writes must have its entry here.
SAVED_FILES: Dict[str, Tuple[str, str]] = {
    "trajectory": (f"every processed frame with a pose of its own, {_TUM}, VO world "
                   "(keyframe 0's camera); a lost frame has no line (its status is in "
                   "trajectory.status.txt)", "positions in {pos}; timestamps in {time}"),
    "keyframes": (f"the keyframes' final poses, {_TUM}, VO world",
                  "positions in {pos}; timestamps in {time}"),
    "status": ("per frame (skipped frames too): timestamp, status (init ok keyframe lost "
               "relocalised reinit skipped), keyframe flag, map segment", "timestamps in {time}"),
    "report": ("the run's report (JSON): counts, timings, configuration (config, "
               "run_config), units, ATE (ate), metric scale, fusion parameters (fusion)",
               "as each key says; ATE in ground-truth metres; positions in {pos}"),
    "groundtruth": (f"the data set's ground truth, {_TUM}, data-set world, of the frames of "
                    "trajectory.txt that the ATE evaluates (with ground truth, not lost): "
                    "'evo_ape tum groundtruth.txt trajectory.txt -as' gives report.json's "
                    "ate per-frame, with keyframes.txt its keyframe-only",
                    "positions in metres (the data set's); timestamps in {time}"),
    "clouds": ("point cloud of one keyframe ({name}: its index in creation order, as in "
               "keyframes.txt): its primitives' points in the VO world, coloured, PLY", "{pos}"),
    "plot_topview": ("top view of the trajectory after the per-frame Sim(3) alignment onto the "
                     "ground truth, and the ground truth (PNG)", "metres (ground truth)"),
    "plot_error": ("per-frame ATE (translation error after the Sim(3) alignment) over time "
                   "(PNG)", "metres (ground truth); timestamps in {time}"),
}


@dataclass(frozen=True)
class SkippedFrame:
    """A frame the runner skipped because its file could not be read
    (:class:`~spgeo.validation.FrameReadError`).

    Attributes:
        index: its position in the input sequence (0-based, counting every frame).
        timestamp: its timestamp (seconds, or frame number), None where unknown.
        path: its image file, None where unknown.
        reason: the reader's message (names the file that failed).
    """

    index: int
    timestamp: Optional[float]
    path: Optional[str]
    reason: str

    def to_dict(self) -> Dict[str, object]:
        return {"index": self.index, "timestamp": self.timestamp, "path": self.path,
                "reason": self.reason}


@dataclass
class VORun:
    """Outcome of :func:`run_odometry`.

    Attributes:
        odometry: the :class:`~spgeo.vo.Odometry` after the last frame
            (trajectory, keyframes, :meth:`Odometry.save`).
        gt_poses: per processed frame, the ground-truth camera-to-world 4x4
            ``T_world_cam`` (data-set world, metres) or None where absent.
        timestamps: (n,) frame timestamps (seconds; frame numbers for data
            sets without timestamps, e.g. 7-Scenes).
        names: per-frame names (file stems).
        wall_seconds: wall time of the whole loop (frame loading, resizing and
            VO), seconds.
        fps: processed frames per wall-clock second (``n / wall_seconds``).
        config: the :class:`~spgeo.apps.vo_run.VORunConfig` used (typed ``Any``:
            this module does not import the runner, which imports it).
        interrupted: the run was stopped by Ctrl-C (``KeyboardInterrupt``)
            between or during frames; it holds the frames processed before.
        resolution: the processing ``(width, height)`` the VO saw
            (:meth:`spgeo.vo.OdometryConfig.processing_size_for`; None only
            for a hand-made VORun: ``config.odometry.resolution``).
        skipped: the frames skipped as unreadable, in input order; they are
            not among the processed frames above (no pose, no ATE).
        memory: resident memory of the run
            (:meth:`spgeo.apps.memory.RssCheckpoints.report`: ``peak_rss_mb``
            at the end of the loop, ``rss_mb``: frames processed -> RSS then);
            ``report.json``'s ``run.memory``.
        intrinsics: where the input camera came from and its values
            (a reader's ``intrinsics``: ``source`` ``"file"`` | ``"given"`` |
            ``"guessed"``, ``fx fy cx cy width height distortion detail``);
            ``report.json``'s ``intrinsics`` when set (:func:`run_dataset` sets it).
        metric_scale: the estimated OUTPUT scale (metres per VO unit,
            ``VORunConfig.metric_scale``): when set, every output of the run
            (:meth:`result`, :meth:`trajectory`, :meth:`ate`, :meth:`save`'s
            trajectories and clouds, :meth:`fuse`, the exports) is the map
            under ``x -> scale x`` about the world origin
            (:attr:`output_odometry`); ``odometry`` itself stays in VO units.
        metric_scale_failure: why a requested metric scale could not be
            estimated (the outputs are then in VO units).
        capture: live input (:func:`~spgeo.apps.vo_run.run_live`): the capture
            ring's report (:meth:`spgeo.datasets.capture.CaptureRing.report`:
            frames dropped, with their names); ``report.json``'s ``"capture"``.
    """

    odometry: Odometry
    gt_poses: List[Optional[np.ndarray]]
    timestamps: np.ndarray
    names: List[str]
    wall_seconds: float
    fps: float
    config: Any
    interrupted: bool = False
    resolution: Optional[Tuple[int, int]] = None
    skipped: List[SkippedFrame] = field(default_factory=list)
    memory: Dict[str, object] = field(default_factory=dict)
    intrinsics: Optional[Dict[str, object]] = None
    metric_scale: Optional[MetricScale] = None
    metric_scale_failure: Optional[str] = None
    capture: Optional[Dict[str, object]] = None

    @property
    def output_odometry(self) -> Union[Odometry, ScaledOdometry]:
        """What the outputs read: :attr:`odometry`, or with :attr:`metric_scale`
        its :class:`~spgeo.vo.metric_scale.ScaledOdometry` (metres)."""
        if self.metric_scale is None:
            return self.odometry
        return ScaledOdometry(self.odometry, self.metric_scale.scale)

    def metric_scale_report(self) -> Optional[Dict[str, object]]:
        """``report.json``'s ``"metric_scale"``: :meth:`MetricScale.to_dict`, or
        ``{"estimated": False, "model", "reason"}`` when it failed; None when
        not asked for."""
        if self.metric_scale is not None:
            return self.metric_scale.to_dict()
        if self.metric_scale_failure is None:
            return None
        return {"estimated": False, "model": getattr(self.config, "metric_scale", None),
                "reason": self.metric_scale_failure}

    @property
    def keyframe_images(self) -> "Mapping[int, np.ndarray]":
        """Keyframe index -> the resized RGB image (float32 [0, 1]) the keyframe
        was made from, read from the odometry at each access
        (:meth:`Odometry.keyframe_image`: from disk for keyframes that left the
        window), so the run holds no image of its own."""
        return _KeyframeImages(self.odometry)

    @property
    def n_frames(self) -> int:
        """Frames processed by the VO (skipped frames not counted)."""
        return len(self.timestamps)

    @property
    def processing_size(self) -> Tuple[int, int]:
        """``(width, height)`` the VO saw: :attr:`resolution`, else
        ``config.odometry.resolution``."""
        size = self.resolution if self.resolution is not None else self.config.odometry.resolution
        return (int(size[0]), int(size[1]))

    def trajectory(self) -> Trajectory:
        """:meth:`result` with the skipped frames of known timestamp inserted
        (status ``skipped``, no pose: :meth:`Trajectory.with_skipped`): what
        :meth:`save` writes."""
        stamps = [s.timestamp for s in self.skipped if s.timestamp is not None]
        return self.result().with_skipped(stamps)

    @property
    def has_map(self) -> bool:
        """Whether some frame was tracked against a map: a keyframe after frame 0
        (keyframe 1 of a segment, or one the policy made), or a frame ``ok`` or
        ``relocalised`` (a segment that has its keyframe pair, or whose keyframe 0
        came with its scale: sensor depth, a saved map).  Frames ``init`` (a
        monocular segment waiting for keyframe 1) do not count: their poses are
        provisional; a depth run whose frames were all lost has no map (issue 53;
        before, any depth run had one)."""
        statuses = self.result().statuses
        return (any(s in ("ok", "relocalised") for s in statuses)
                or any(s == "keyframe" for s in statuses[1:]))

    @property
    def status(self) -> str:
        """``"interrupted"`` (Ctrl-C), ``"no_map"`` (no segment initialised: the
        poses are provisional; :attr:`Odometry.init_failure` says why) or ``"ok"``."""
        if self.interrupted:
            return "interrupted"
        return "ok" if self.has_map else "no_map"

    @property
    def has_ground_truth(self) -> bool:
        """True when at least one frame has a ground-truth pose."""
        return any(T is not None for T in self.gt_poses)

    def result(self) -> OdometryResult:
        """The VO trajectory (:meth:`Odometry.result`; in metres with
        :attr:`metric_scale`)."""
        return self.output_odometry.result()

    def __repr__(self) -> str:
        """One line: status, frames (skipped, lost), keyframes, front-end and size,
        FPS, ground truth and the positions' unit (no ATE: that takes evo)."""
        w, h = self.processing_size
        counts = self.status_counts()
        unit = self.output_odometry.units
        return (f"VORun({self.status}, {self.n_frames} frames ({len(self.skipped)} skipped, "
                f"{counts.get('lost', 0)} lost), {self.odometry.n_keyframes} keyframes, "
                f"{self.frontend_name} at {w}x{h}, {self.fps:.1f} FPS, "
                f"{'with' if self.has_ground_truth else 'no'} ground truth, positions in {unit})")

    def status_counts(self) -> Dict[str, int]:
        """Number of frames per status (``init``, ``ok``, ``keyframe``, ``lost``,
        ..., and ``skipped`` when frames were skipped)."""
        counts = Counter(str(s) for s in self.result().statuses)
        if self.skipped:
            counts["skipped"] = len(self.skipped)
        return dict(counts)

    def ground_truth(self, exclude_lost: bool = True) -> Optional[Trajectory]:
        """The ground truth of the processed frames that have one
        (:meth:`Trajectory.from_ground_truth` of :attr:`gt_poses`: data-set
        world, metres, camera-to-world), with ``exclude_lost`` (default) only
        those not flagged ``"lost"``: the frames :meth:`ate` evaluates, what
        :meth:`save` writes as ``groundtruth.txt``.  None without ground truth."""
        if not self.has_ground_truth:
            return None
        poses = self.gt_poses
        if exclude_lost:
            lost = [s == "lost" for s in self.result().statuses]
            poses = [None if bad else T for T, bad in zip(poses, lost)]
        return Trajectory.from_ground_truth(self.timestamps, poses)

    @property
    def position_units(self) -> str:
        """The unit of the run's output positions (trajectories, clouds, mesh), the
        :attr:`output_odometry`'s ``units`` in words with where it comes from:
        metres with :attr:`metric_scale` or a front-end that reads the sensor
        depth, else the VO's own unit (unknown scale)."""
        if self.output_odometry.units != METRES:
            return ("VO units (unknown scale: monocular; report.json ate per-frame scale is "
                    "metres per VO unit where there is ground truth; --metric-scale writes metres)")
        if self.metric_scale is not None:
            return ("metres (scale estimated by --metric-scale, VORunConfig.metric_scale: "
                    "report.json metric_scale)")
        return f"metres (the sensor depth read by the front-end {self.frontend_name!r})"

    def ate(self) -> Optional[Dict[str, object]]:
        """Sim(3)-aligned ATE of the processed frames not flagged ``"lost"``
        (skipped frames have no pose and are never among them).

        Returns ``{"per-frame": AteResult, "keyframe-only": AteResult or None}``
        (:class:`spgeo.metrics.ate.AteResult`; errors in ground-truth
        metres; keyframe-only aligns on the keyframes alone and is None with
        fewer than 3 keyframes), or None when no frame has ground truth or
        fewer than 3 poses can be evaluated (logged).
        """
        gt = self.ground_truth(exclude_lost=False)
        if gt is None:
            return None
        res = self.result()
        keep = np.array([s != "lost" for s in res.statuses], dtype=bool)
        n_seg = len(set(res.segment[keep].tolist()))
        if n_seg > 1:
            log.warning("the per-frame ATE aligns %d map segments with one Sim(3) although "
                        "each has its own scale: see the per-segment ATE", n_seg)
        try:
            return ate_per_frame_and_keyframes(
                (res.timestamps[keep], res.poses[keep]), gt, res.is_keyframe[keep],
                max_time_diff=self.config.ate_max_time_diff)
        except ValueError as exc:
            log.warning("ATE not available: %s", exc)
            return None

    def segment_ates(self) -> List[Tuple[int, Optional[AteResult]]]:
        """Per map segment (a run that re-initialised has several, each in its own
        scale), the Sim(3) ATE of its frames not ``lost``: ``(segment, AteResult
        or None with fewer than 3 poses)``; empty for a run with one segment or
        without ground truth (issue 53)."""
        gt = self.ground_truth(exclude_lost=False)
        res = self.result()
        keep = np.array([s != "lost" for s in res.statuses], dtype=bool)
        segments = sorted(set(res.segment[keep].tolist()))
        if gt is None or len(segments) < 2:
            return []
        out: List[Tuple[int, Optional[AteResult]]] = []
        for k in segments:
            m = keep & (res.segment == k)
            try:
                out.append((int(k), ate_sim3((res.timestamps[m], res.poses[m]), gt,
                                             self.config.ate_max_time_diff,
                                             label=f"segment {k}", warn_dropped=False)))
            except ValueError:
                out.append((int(k), None))
        return out

    def ate_report(self, ate: Optional[Dict[str, object]] = None) -> Optional[Dict[str, object]]:
        """JSON-friendly :meth:`ate`: per label the summary (``rmse_m``,
        ``rmse_percent_of_length``, ``trajectory_length_m``, ``scale``, ...) or
        None, plus ``n_lost_excluded``; None without ground truth.  ``ate``: a
        result of :meth:`ate` to reuse (default: computed here)."""
        if ate is None:
            ate = self.ate()
        if ate is None:
            return None
        out: Dict[str, object] = {lab: (None if ate.get(lab) is None else ate[lab].summary())
                                  for lab in ATE_LABELS}
        out["per_segment"] = [{"segment": k, **({} if a is None else a.summary())}
                              for k, a in self.segment_ates()]
        out["n_lost_excluded"] = int(sum(s == "lost" for s in self.result().statuses))
        out["n_skipped_excluded"] = len(self.skipped)
        out["alignment"] = "Sim(3) (Umeyama, evo_ape -as), translation RMSE"
        return out

    def summary_lines(self, ate: Optional[Dict[str, object]] = None) -> List[str]:
        """Short human-readable summary (frames, lost, keyframes, FPS, ATE lines).

        ``ate``: a result of :meth:`ate` to reuse (default: computed here).
        """
        res = self.result()
        n_lost = int(sum(s == "lost" for s in res.statuses))
        w, h = self.processing_size
        skipped = f", {len(self.skipped)} skipped (unreadable)" if self.skipped else ""
        lines = [f"{self.n_frames} frames, {n_lost} lost{skipped}, {int(res.is_keyframe.sum())} "
                 f"keyframes, {self.fps:.1f} FPS (front-end {self.frontend_name}, {w}x{h})"]
        lines.extend(self._metric_lines())
        if ate is None:
            ate = self.ate()
        if ate is None:
            lines.append("ATE: no ground truth" if not self.has_ground_truth
                         else "ATE: not available (too few poses)")
            return lines
        for lab in ATE_LABELS:
            a = ate.get(lab)
            if a is None:
                lines.append(f"Sim(3) ATE {lab}: not available (fewer than 3 keyframes)")
            else:
                lines.append(f"Sim(3) ATE {lab}: {a.rmse:.4f} m = "
                             f"{a.rmse_percent_of_length:.2f}% of {a.trajectory_length:.3f} m "
                             f"({a.n_associated} poses, scale {a.scale:.4g})")
        for k, a in self.segment_ates():
            lines.append(f"  segment {k}: " + ("fewer than 3 poses" if a is None else
                         f"{a.rmse:.4f} m ({a.n_associated} poses, scale {a.scale:.4g})"))
        return lines

    def _metric_lines(self) -> List[str]:
        """The summary line of a requested metric scale (none without one)."""
        m = self.metric_scale
        if m is not None:
            lo, hi = m.interval
            return [f"metric scale (estimated, outputs in metres): {m.scale:.4g} m per VO unit, "
                    f"spread x{m.spread:.3g} (16-84%: {lo:.4g}-{hi:.4g}) over {m.n_keyframes} "
                    f"keyframes, {m.seconds or 0.0:.2f} s ({m.model})"]
        if self.metric_scale_failure is not None:
            return [f"metric scale: not estimated, outputs in VO units "
                    f"({self.metric_scale_failure})"]
        return []

    @property
    def frontend_name(self) -> str:
        fe = self.odometry.frontend
        return str(getattr(fe, "name", "") or type(fe).__name__)

    def save(self, directory: Union[str, Path], with_ate: bool = True,
             ate: Optional[Dict[str, object]] = None,
             title: Optional[str] = None, fusion=None) -> Dict[str, object]:
        """Write the run to ``directory`` (created).

        Files: :meth:`Odometry.save`'s ``trajectory.txt`` (every processed
        frame, TUM ``timestamp tx ty tz qx qy qz qw``, camera-to-world),
        ``keyframes.txt``, ``trajectory.status.txt``, ``report.json`` and
        keyframe point clouds (world frame, PLY) in ``clouds/``; with ground
        truth, ``groundtruth.txt`` (:meth:`ground_truth`: TUM, camera-to-world,
        the frames the ATE evaluates; ``evo_ape tum groundtruth.txt
        trajectory.txt -as`` gives the report's per-frame ATE); with ``fusion``
        (a :class:`~spgeo.io.fusion.FusionResult` of :meth:`fuse`), its
        ``mesh.ply`` and ``cloud.ply``.  This adds
        ``"run"`` (processing resolution, front-end, wall time, FPS, ``n_skipped``),
        ``"intrinsics"`` (:attr:`intrinsics`, when set), ``"capture"``
        (:attr:`capture`, live input),
        ``"skipped"`` (one :meth:`SkippedFrame.to_dict` per skipped frame; such a
        frame is ``skipped`` in the status file and has no line in
        ``trajectory.txt``), ``"run_config"``
        (this :class:`~spgeo.apps.vo_run.VORunConfig` without ``odometry``),
        ``"units"`` (positions: :attr:`position_units`, timestamps, ATE),
        ``"fusion"`` (with ``fusion``: :meth:`FusionResult.summary`, the
        parameters used) and, with
        ``with_ate`` and ground truth, ``"ate"`` (:meth:`ate_report`) to the
        report and the plots ``trajectory_topview.png`` and
        ``trajectory_error.png`` (per-frame ATE; :mod:`spgeo.apps.trajectory_plots`,
        paths ``"plot_topview"`` / ``"plot_error"``).  ``"run"`` holds
        :attr:`status` (``ok``, ``no_map``, ``interrupted``), the odometry's
        ``init_failure`` and :attr:`memory` (peak and per-100-frame RSS, MiB).
        ``ate``: a result of :meth:`ate` to reuse; ``title``:
        the plots' title (default the folder's name).  With a requested metric
        scale the report's ``"metric_scale"`` is :meth:`metric_scale_report` and
        the trajectories and clouds are in metres (:attr:`output_odometry`).
        Returns the paths by the keys of :data:`SAVED_FILES` (``"clouds"``: a
        list; what they are: :meth:`describe_files`).
        """
        out = Path(directory)
        if with_ate:
            ate = self.ate() if ate is None else ate
        extra = self._report_extra(ate if with_ate else None, with_ate, fusion)
        traj = self.trajectory()
        extra["status_counts"] = traj.status_counts()     # skipped frames included
        paths: Dict[str, object] = dict(self.odometry.save(out, clouds=False, extra_report=extra,
                                                           trajectory=traj))
        gt = self.ground_truth()
        if gt is not None:
            paths["groundtruth"] = gt.save(
                out / GROUND_TRUTH_FILE, status_file=False,
                header=["ground truth (data-set world, metres) of the frames of trajectory.txt "
                        "that the ATE evaluates (with ground truth, not lost)",
                        "evo_ape tum groundtruth.txt trajectory.txt -as: report.json's ATE"])
        view = self.output_odometry
        paths["clouds"] = write_keyframe_clouds(
            out / "clouds", view.iter_keyframes(view.keyframes_with_depth()))
        if with_ate and ate is not None and ate.get("per-frame") is not None:
            paths.update(self._write_plots(out, ate["per-frame"], title or out.name or str(out)))
        if fusion is not None:
            paths.update(fusion.write(out))
        return paths

    def _report_extra(self, ate: Optional[Dict[str, object]], with_ate: bool,
                      fusion) -> Dict[str, object]:
        """What :meth:`save` adds to the odometry's report (its docstring)."""
        w, h = self.processing_size
        extra: Dict[str, object] = {
            "run": {"status": self.status, "init_failure": self.odometry.init_failure,
                    "resolution": [w, h], "frontend": self.frontend_name,
                    "wall_seconds": self.wall_seconds, "fps_wall": self.fps,
                    "n_frames": self.n_frames, "n_skipped": len(self.skipped),
                    "n_ground_truth": int(sum(T is not None for T in self.gt_poses)),
                    "frame_names": list(self.names), "memory": dict(self.memory)},
            "skipped": [s.to_dict() for s in self.skipped],
            # the odometry's own configuration is the report's "config"
            "run_config": {k: v for k, v in config_to_dict(self.config).items()
                           if k != "odometry"}}
        if self.intrinsics is not None:
            extra["intrinsics"] = dict(self.intrinsics)
        if self.capture is not None:
            extra["capture"] = dict(self.capture)
        if with_ate:
            extra["ate"] = self.ate_report(ate) if ate is not None else None
        metric = self.metric_scale_report()
        if metric is not None:
            extra["metric_scale"] = metric
        extra["units"] = {"positions": self.position_units, "timestamps": _TIME,
                          "ate": "metres (the ground truth's), after the Sim(3) alignment"}
        if fusion is not None:
            extra["fusion"] = {**fusion.summary(), "units": self.position_units}
        return extra

    def describe_files(self, paths: Mapping[str, object]) -> Dict[Path, FileInfo]:
        """What each file of :meth:`save` is (:data:`SAVED_FILES`, with this
        run's units; the mesh and cloud: :data:`spgeo.io.fusion.FUSION_FILES`),
        by path: the ``described`` of :meth:`spgeo.io.outputs.StagedFolder.commit`.
        ``paths``: what :meth:`save` returned.  Raises ``KeyError`` for a key
        with no description (every file written must have one)."""
        from ..io.fusion import FUSION_FILES

        pos = self.position_units
        out: Dict[Path, FileInfo] = {}
        for key, value in paths.items():
            for path in (value if isinstance(value, list) else [value]):
                path = Path(path)
                if key in FUSION_FILES:
                    out[path] = FileInfo(FUSION_FILES[key], pos)
                    continue
                what, units = SAVED_FILES[key]
                out[path] = FileInfo(what.format(name=path.stem),
                                     units.format(pos=pos, time=_TIME))
        return out

    def _write_plots(self, out: Path, ate, title: str) -> Dict[str, Path]:
        """``trajectory_topview.png`` / ``trajectory_error.png`` of the per-frame
        ATE (:mod:`spgeo.apps.trajectory_plots`); none without matplotlib (logged)."""
        try:
            from .trajectory_plots import write_trajectory_plots

            plots = write_trajectory_plots(ate, out, title=title)
        except ImportError as exc:
            log.warning("no trajectory plots: %s", exc)
            return {}
        return {"plot_topview": plots.topview, "plot_error": plots.error}

    def export_colmap(self, directory: Union[str, Path], frames: Optional[Iterable[Frame]] = None,
                      stride: int = 4, max_points: int = 200_000) -> Path:
        """:func:`spgeo.io.colmap_export.export_odometry` of the run: the
        keyframes, or with ``frames`` (the run's input frames again, e.g. the
        data set re-opened without depth) every frame not lost.  Returns the
        COLMAP model folder."""
        from ..io.colmap_export import export_odometry

        images = None if frames is None else ((str(f.name), f.image) for f in frames)
        return export_odometry(directory, self.output_odometry, self.names,
                               self.keyframe_images, images, stride, max_points)


    def export_nerfstudio(self, directory: Union[str, Path],
                          frames: Optional[Iterable[Frame]] = None) -> Path:
        """:func:`spgeo.io.nerfstudio_export.export_odometry_nerfstudio` of the
        run: the keyframes, or with ``frames`` (the run's input frames again)
        every frame not lost, as for :meth:`export_colmap`.  Returns the path of
        ``transforms.json``."""
        from ..io.nerfstudio_export import export_odometry_nerfstudio

        images = None if frames is None else ((str(f.name), f.image) for f in frames)
        return export_odometry_nerfstudio(directory, self.output_odometry, self.names,
                                          self.keyframe_images, images)

    def fuse(self, config=None):
        """TSDF fusion of the keyframes' depth maps at their final poses
        (:func:`spgeo.io.fusion.fuse_odometry`; ``config`` a
        :class:`~spgeo.io.fusion.FusionConfig`, default the run config's
        ``fusion``, else the defaults; :meth:`save` writes it): a
        :class:`~spgeo.io.fusion.FusionResult` in the VO's world and unit (metres
        with :attr:`metric_scale`).  Raises ``ValueError`` when no keyframe
        carries depth."""
        from ..io.fusion import FusionConfig, fuse_odometry

        if config is None:
            config = getattr(self.config, "fusion", None) or FusionConfig()
        return fuse_odometry(self.output_odometry, config)


class _KeyframeImages(Mapping):
    """Read-only mapping keyframe index -> input image of an :class:`Odometry`
    (:meth:`Odometry.keyframe_image` at each access)."""

    def __init__(self, odometry: Odometry) -> None:
        self._odometry = odometry

    def __getitem__(self, k: int) -> np.ndarray:
        if not isinstance(k, (int, np.integer)) or not 0 <= int(k) < len(self):
            raise KeyError(k)
        return self._odometry.keyframe_image(int(k))

    def __iter__(self) -> Iterator[int]:
        return iter(range(len(self)))

    def __len__(self) -> int:
        return self._odometry.n_keyframes
