"""Monocular VO methods side by side on the same frames: spgeo, the OpenCV
feature baseline and the COLMAP reference, with Sim(3)-aligned ATE.

:func:`compare_vo` resizes the frames once (``cv2.INTER_AREA``, by default to
the processing size ``spgeo vo`` would choose, :data:`DEFAULT_RESOLUTION`
``"auto"``: :meth:`spgeo.vo.OdometryConfig.processing_size_for`, 320x240 for 4:3
input, the input's aspect ratio otherwise; depth with nearest
neighbour, only kept for an oracle method) and runs every requested method on
exactly those frames:

* ``spgeo-classical``: spgeo's VO (:func:`spgeo.apps.vo_run.run_vo`)
  with the classical front-end (RGB only).
* ``spgeo-depth``: the same with the ``depth`` front-end, which **reads the
  sensor depth (oracle)**; labelled so in every table.
* ``feature``: the OpenCV feature VO baseline
  (:func:`spgeo.evaluation.references.feature_vo.run_feature_vo`, RGB only).
* ``colmap``: the pycolmap incremental-SfM reference
  (:func:`spgeo.evaluation.references.colmap_vo.run_colmap_vo`): offline, all frames at
  once, so its FPS is not a VO frame rate.

Each :class:`VOCompareRow` reports the tracked (posed) fraction of the
frames, the **per-frame** ATE (every posed frame, Sim(3) Umeyama alignment
with scale, :func:`~spgeo.evaluation.trajectory.ate_sim3`) as RMSE in metres
and in % of the ground-truth path length of the whole range, the
**keyframe-only** ATE (keyframes aligned on their own) where the method has
keyframes, FPS (frames / wall seconds of the method) and wall seconds.  The
ATE is over the posed frames only: read it together with the tracked
fraction.

Rotations and local scale are judged against references
(:mod:`spgeo.evaluation.vo.reference_metrics`; 7-Scenes' ground truth cannot judge
rotations at the degree level, issue 30): every row gets its relative rotation error
over :attr:`VOCompareConfig.rotation_gap` frames (default 30) and its orientation
after the best constant rotation against the ground truth; when ``colmap`` is among
the methods, every other row also gets them against COLMAP's reconstruction of the
same frames, with its scale relative to COLMAP's over sliding windows of
:attr:`VOCompareConfig.scale_window` frames (default 50).  A second table shows them.

Command line::

    python -m spgeo.evaluation.vo.compare --dataset 7scenes PATH --frames 0:300 \
        [--resolution WxH|auto|native] [--methods feature colmap ...] [--out DIR]
        [--rotation-gap 30] [--scale-window 50]

prints a markdown table and, with ``--out``, writes ``<method>.txt`` (TUM,
camera-to-world, posed frames), ``<method>.status.txt``,
``<method>.keyframes.txt`` (methods with keyframes) and ``results.json``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
from tqdm import tqdm


from spgeo.vo import OdometryConfig
from spgeo.apps.args import parse_resolution
from spgeo.frame import Frame, resize_frame
from spgeo.jsonio import json_default

from spgeo.evaluation.references.colmap_vo import ColmapVOConfig, check_resolution, run_colmap_vo
from spgeo.evaluation.references.feature_vo import FeatureVOConfig, run_feature_vo
from spgeo.evaluation.trajectory import (AteResult, ate_per_frame_and_keyframes,
                                         default_max_time_diff, path_length, status_path_for,
                                         write_status, write_tum)
from spgeo.evaluation.runner import open_sequence, protocol_argv, protocol_parser, run_protocol
from spgeo.evaluation.vo.reference_metrics import (DEFAULT_GAP, DEFAULT_WINDOW,
                                                   compare_to_reference)

__all__ = ["METHODS", "METHOD_LABELS", "ORACLE_METHODS", "DEFAULT_RESOLUTION", "VOCompareConfig",
           "AUTO_RESOLUTION", "compare_size", "VOCompareRow", "prepare_frames", "compare_vo", "format_markdown_table",
           "format_reference_table",
           "write_results", "build_parser", "run", "main"]

logger = logging.getLogger(__name__)

#: Method names accepted by :func:`compare_vo`, in table order.
METHODS = ("spgeo-classical", "spgeo-depth", "feature", "colmap")
#: Human-readable description of each method (used in tables).
METHOD_LABELS = {
    "spgeo-classical": "spgeo VO, classical front-end (RGB only)",
    "spgeo-depth": "spgeo VO, depth front-end (ORACLE: reads sensor depth)",
    "feature": "OpenCV feature VO baseline (ORB + PnP, RGB only)",
    "colmap": "COLMAP incremental SfM reference (offline, RGB only)",
}
#: Methods that read the sensor depth (not monocular: oracle).
ORACLE_METHODS = ("spgeo-depth",)
#: ``resolution`` value meaning "the processing size ``spgeo vo`` chooses for
#: these frames" (:meth:`spgeo.vo.OdometryConfig.processing_size_for` of the
#: default :class:`~spgeo.vo.OdometryConfig`, the one rule of both tools).
AUTO_RESOLUTION = "auto"
#: What every method sees by default: :data:`AUTO_RESOLUTION`.
DEFAULT_RESOLUTION = AUTO_RESOLUTION


def compare_size(resolution: Union[None, str, Tuple[int, int]],
                 input_size: Tuple[int, int]) -> Optional[Tuple[int, int]]:
    """The ``(width, height)`` every method sees for frames of ``input_size``:
    ``spgeo vo``'s default processing size for :data:`AUTO_RESOLUTION`,
    ``resolution`` itself for a size, None (the frames' size) for None."""
    if isinstance(resolution, str):
        if resolution != AUTO_RESOLUTION:
            raise ValueError(f"resolution must be (width, height), None or "
                             f"{AUTO_RESOLUTION!r}, got {resolution!r}")
        return OdometryConfig().processing_size_for(tuple(input_size))
    return None if resolution is None else (int(resolution[0]), int(resolution[1]))


@dataclass
class VOCompareConfig:
    """Options of :func:`compare_vo`.

    Attributes:
        resolution: ``(width, height)`` in pixels every method sees; default
            :data:`DEFAULT_RESOLUTION` (``"auto"``: ``spgeo vo``'s default
            processing size for the frames, :func:`compare_size`); None keeps
            the frames' size.
        max_time_diff: ATE timestamp association tolerance; None (default):
            0.1 for frame-number timestamps, 0.02 s otherwise
            (:func:`~spgeo.evaluation.trajectory.default_max_time_diff`).
        feature: :class:`~spgeo.evaluation.references.feature_vo.FeatureVOConfig` of the
            baseline (default options).
        colmap: :class:`~spgeo.evaluation.references.colmap_vo.ColmapVOConfig` (its
            ``resolution`` is replaced by ``resolution``); default options.
        odometry: ``spgeo.odometry.OdometryConfig`` of the spgeo methods; None
            (default) = its defaults.
        progress: tqdm bars, default False.
        rotation_gap: frame gap of the relative rotation error against the
            references (default 30,
            :func:`~spgeo.evaluation.vo.reference_metrics.relative_rotation_error`).
        scale_window: frames per window of the scale against COLMAP (default 50,
            :func:`~spgeo.evaluation.vo.reference_metrics.window_scale`).
    """

    resolution: Union[None, str, Tuple[int, int]] = DEFAULT_RESOLUTION
    max_time_diff: Optional[float] = None
    feature: FeatureVOConfig = field(default_factory=FeatureVOConfig)
    colmap: ColmapVOConfig = field(default_factory=ColmapVOConfig)
    odometry: Optional[object] = None
    progress: bool = False
    rotation_gap: int = DEFAULT_GAP
    scale_window: int = DEFAULT_WINDOW

    def __post_init__(self) -> None:
        if isinstance(self.resolution, str):
            compare_size(self.resolution, (640, 480))       # only "auto" is accepted
        else:
            self.resolution = check_resolution(self.resolution, "VOCompareConfig.resolution")
        if self.max_time_diff is not None and not float(self.max_time_diff) > 0:
            raise ValueError("VOCompareConfig.max_time_diff must be > 0")
        if int(self.rotation_gap) < 1 or int(self.scale_window) < 3:
            raise ValueError("VOCompareConfig: rotation_gap must be >= 1, scale_window >= 3")


@dataclass
class VOCompareRow:
    """One method's results on the frames of :func:`compare_vo`.

    Attributes:
        method: name (:data:`METHODS`); label: its description.
        oracle: True when the method reads sensor depth.
        n_frames: frames given; n_tracked: frames with a pose.
        n_keyframes: keyframes (0 for methods without keyframes).
        ate_rmse_m: per-frame Sim(3) ATE RMSE in metres (NaN if unavailable).
        ate_percent: ``ate_rmse_m`` in % of the ground-truth path length of
            the whole range (``gt_length_m``).
        ate_n: poses evaluated; ate_scale: Sim(3) scale estimate -> metres.
        kf_ate_rmse_m, kf_ate_percent, kf_ate_n: keyframe-only ATE (NaN / 0
            when the method has no keyframes or fewer than 3).
        gt_length_m: ground-truth path length of all frames with ground truth.
        fps: ``n_frames / wall_s``; wall_s: seconds the method ran.
        error: why the method or its ATE failed (None when fine).
        info: method-specific extras (status counts, COLMAP model sizes...).
        rot_vs_gt_deg: mean relative rotation error over the configured frame gap
            against the ground truth, degrees; orient_vs_gt_median_deg /
            orient_vs_gt_max_deg: orientation after the best constant rotation.
        rot_vs_colmap_deg, orient_vs_colmap_median_deg, orient_vs_colmap_max_deg:
            the same against the ``colmap`` row (NaN for that row itself and when
            COLMAP did not run).
        window_scale_vs_colmap_min, window_scale_vs_colmap_max: the Sim(3) scale
            taking this method onto COLMAP over sliding windows, relative to the
            whole run's (:func:`~spgeo.evaluation.vo.reference_metrics.window_scale`).
        reference: reference name (``"ground truth"``, ``"colmap"``) -> the
            :meth:`~spgeo.evaluation.vo.reference_metrics.ReferenceComparison.summary`.
        timestamps, poses, is_keyframe, status: the trajectory (camera-to-world,
            NaN where no pose), not part of :meth:`to_dict`.
    """

    method: str
    label: str
    oracle: bool
    n_frames: int
    n_tracked: int = 0
    n_keyframes: int = 0
    ate_rmse_m: float = float("nan")
    ate_percent: float = float("nan")
    ate_n: int = 0
    ate_scale: float = float("nan")
    kf_ate_rmse_m: float = float("nan")
    kf_ate_percent: float = float("nan")
    kf_ate_n: int = 0
    gt_length_m: float = float("nan")
    fps: float = float("nan")
    wall_s: float = float("nan")
    error: Optional[str] = None
    info: Dict[str, object] = field(default_factory=dict)
    rot_vs_gt_deg: float = float("nan")
    orient_vs_gt_median_deg: float = float("nan")
    orient_vs_gt_max_deg: float = float("nan")
    rot_vs_colmap_deg: float = float("nan")
    orient_vs_colmap_median_deg: float = float("nan")
    orient_vs_colmap_max_deg: float = float("nan")
    window_scale_vs_colmap_min: float = float("nan")
    window_scale_vs_colmap_max: float = float("nan")
    reference: Dict[str, Dict[str, object]] = field(default_factory=dict)
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)), repr=False)
    is_keyframe: Optional[np.ndarray] = field(default=None, repr=False)
    status: List[str] = field(default_factory=list, repr=False)

    @property
    def tracked_fraction(self) -> float:
        return self.n_tracked / self.n_frames if self.n_frames else float("nan")

    def to_dict(self) -> Dict[str, object]:
        """JSON-friendly row (no trajectory arrays)."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
             if f.name not in ("timestamps", "poses", "is_keyframe", "status")}
        d["info"] = dict(self.info)
        d["reference"] = dict(self.reference)
        d["tracked_fraction"] = self.tracked_fraction
        return d


# ================================================================== frames
def prepare_frames(frames: Iterable[Frame], resolution: Union[None, str, Tuple[int, int]],
                   keep_depth: bool = False, progress: bool = False) -> List[Frame]:
    """Frames resized once to ``resolution`` (:func:`compare_size` of the first
    frame's size; ``cv2.INTER_AREA``; depth with nearest neighbour when
    ``keep_depth``, else dropped), as every method of :func:`compare_vo` would
    resize them; consumes a lazy reader frame by frame so that only the small
    copies are held."""
    out: List[Frame] = []
    size: Optional[Tuple[int, int]] = None
    for f in tqdm(frames, disable=not progress, desc="load", unit="frame"):
        if not out:
            size = compare_size(resolution, f.camera.size)
        out.append(resize_frame(f, size, keep_depth=keep_depth))
    return out


# ================================================================= methods
def _run_spgeo(frames: List[Frame], frontend: str, config: VOCompareConfig):
    from spgeo.apps.vo_run import run_vo

    kwargs = {} if config.odometry is None else {"config": config.odometry}
    size = compare_size(config.resolution, frames[0].camera.size) or frames[0].camera.size
    vo, _, _ = run_vo(frames, resolution=tuple(size), frontend=frontend,
                      progress=config.progress, **kwargs)
    r = vo.result()
    poses = np.array(r.poses, dtype=np.float64).reshape(-1, 4, 4)
    finite = np.all(np.isfinite(poses.reshape(len(poses), -1)), axis=1)
    ok = finite & np.array([s != "lost" for s in r.statuses], dtype=bool)
    poses[~ok] = np.nan
    counts: Dict[str, int] = {}
    for s in r.statuses:
        counts[s] = counts.get(s, 0) + 1
    return (np.asarray(r.timestamps, np.float64), poses, np.asarray(r.is_keyframe, bool),
            list(r.statuses), {"status_counts": counts})


def _run_feature(frames: List[Frame], config: VOCompareConfig):
    cfg = dataclasses.replace(config.feature, show_progress=config.progress)
    res = run_feature_vo(frames, frames[0].camera, cfg)
    return (res.timestamps, res.poses, res.is_keyframe, list(res.status),
            {"status_counts": res.status_counts(), "n_segments": res.n_segments})


def _run_colmap(frames: List[Frame], config: VOCompareConfig):
    cfg = dataclasses.replace(config.colmap, resolution=config.resolution,
                              show_progress=config.progress)
    res = run_colmap_vo(frames, cfg)
    info = {"model_sizes": res.model_sizes, "num_points3D": res.num_points3D,
            "mean_reprojection_error_px": res.mean_reprojection_error,
            "timings_s": dict(res.timings), "message": res.message}
    return res.timestamps, res.poses, None, res.status, info


def _check_methods(methods: Sequence[str]) -> List[str]:
    """``methods`` as a list; ValueError for an unknown one or none."""
    methods = list(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"compare_vo: unknown method(s) {unknown}; expected {list(METHODS)}")
    if not methods:
        raise ValueError("compare_vo: no methods")
    return methods


def _ground_truth(frames: List[Frame]) -> Tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(stamps of all frames, stamps with ground truth, their camera-to-world
    poses, path length)``; ValueError with fewer than 3 ground-truth poses."""
    stamps = np.array([f.timestamp for f in frames], dtype=np.float64)
    has_gt = [f.T_world_cam is not None for f in frames]
    if sum(has_gt) < 3:
        raise ValueError(f"compare_vo: {sum(has_gt)} frames have ground truth (need >= 3)")
    gt_ts = stamps[has_gt]
    gt_poses = np.array([f.T_world_cam for f in frames if f.T_world_cam is not None])
    gt_length = path_length(gt_poses[:, :3, 3])
    return stamps, gt_ts, gt_poses, gt_length


def _run_method(method: str, frames: List[Frame], cfg: VOCompareConfig):
    """``(timestamps, poses, is_keyframe, status, info)`` of one method on ``frames``."""
    n = len(frames)
    if method == "spgeo-depth" and any(f.depth is None for f in frames):
        raise ValueError("the depth front-end needs depth on every frame "
                         f"({sum(f.depth is None for f in frames)} of {n} have none)")
    if method.startswith("spgeo-"):
        return _run_spgeo(frames, method.split("-", 1)[1], cfg)
    if method == "feature":
        return _run_feature(frames, cfg)
    return _run_colmap(frames, cfg)


def _fill_ate(row: VOCompareRow, out, gt_ts: np.ndarray, gt_poses: np.ndarray,
              gt_length: float, tol: float) -> None:
    """Store the method's output ``out`` (:func:`_run_method`) and its ATE in ``row``
    (``row.error`` set when the ATE is not available)."""
    ts, poses, kf, status, info = out
    row.timestamps, row.poses, row.is_keyframe, row.status = ts, poses, kf, status
    row.info = info
    valid = np.all(np.isfinite(poses.reshape(len(poses), -1)), axis=1)
    row.n_tracked = int(valid.sum())
    row.n_keyframes = int(np.sum(kf)) if kf is not None else 0
    try:
        ates: Mapping[str, Optional[AteResult]] = ate_per_frame_and_keyframes(
            (ts, poses), (gt_ts, gt_poses), kf, max_time_diff=tol)
    except ValueError as exc:
        row.error = f"ATE not available: {exc}"
        return
    pf, kfa = ates["per-frame"], ates["keyframe-only"]
    if pf is not None:
        row.ate_rmse_m, row.ate_n, row.ate_scale = pf.rmse, pf.n_associated, pf.scale
        row.ate_percent = 100.0 * pf.rmse / gt_length if gt_length > 0 else float("nan")
    if kfa is not None:
        row.kf_ate_rmse_m, row.kf_ate_n = kfa.rmse, kfa.n_associated
        row.kf_ate_percent = 100.0 * kfa.rmse / gt_length if gt_length > 0 else float("nan")
    logger.info("compare_vo: %s: %d/%d posed, per-frame ATE %.4f m, %.1f s", row.method,
                row.n_tracked, row.n_frames, row.ate_rmse_m, row.wall_s)


def _method_row(method: str, frames: List[Frame], cfg: VOCompareConfig, gt_ts: np.ndarray,
                gt_poses: np.ndarray, gt_length: float, tol: float) -> VOCompareRow:
    """One method's :class:`VOCompareRow` (``error`` set when it raised)."""
    n = len(frames)
    row = VOCompareRow(method=method, label=METHOD_LABELS[method],
                       oracle=method in ORACLE_METHODS, n_frames=n, gt_length_m=gt_length)
    logger.info("compare_vo: running %s on %d frames", method, n)
    t0 = time.perf_counter()
    try:
        out = _run_method(method, frames, cfg)
    except Exception as exc:  # an evaluation must report, not die
        logger.exception("compare_vo: method %s failed", method)
        row.wall_s = time.perf_counter() - t0
        row.error = f"{type(exc).__name__}: {exc}"
        return row
    row.wall_s = time.perf_counter() - t0
    row.fps = n / row.wall_s if row.wall_s > 0 else float("nan")
    _fill_ate(row, out, gt_ts, gt_poses, gt_length, tol)
    return row


def compare_vo(frames: Iterable[Frame], methods: Sequence[str] = METHODS,
               resolution: Union[None, str, Tuple[int, int]] = DEFAULT_RESOLUTION,
               config: Optional[VOCompareConfig] = None) -> List[VOCompareRow]:
    """Run VO methods on the same frames and evaluate them against ground truth.

    Args:
        frames: :class:`~spgeo.frame.Frame` objects in time order with
            ground-truth ``T_world_cam`` (camera-to-world; frames without one
            are not evaluated) and, for ``spgeo-depth``, depth.  A lazy reader
            is fine (read once).
        methods: names from :data:`METHODS`, run in this order.
        resolution: ``(width, height)`` in pixels every method sees (overrides
            ``config.resolution``); ``"auto"`` (default) ``spgeo vo``'s default
            processing size for the frames (:func:`compare_size`); None keeps
            the frames' size.
        config: :class:`VOCompareConfig`.
    Returns:
        one :class:`VOCompareRow` per method.  A method that raises, or whose
        ATE cannot be computed, gets a row with ``error`` set and NaN numbers
        (an evaluation reports, it does not die).
    Raises:
        ValueError for an unknown method, no frames, or fewer than 3 frames
        with ground truth.
    """
    cfg = dataclasses.replace(config or VOCompareConfig(), resolution=resolution)
    methods = _check_methods(methods)
    need_depth = any(m in ORACLE_METHODS for m in methods)
    frames = prepare_frames(frames, cfg.resolution, keep_depth=need_depth, progress=cfg.progress)
    if not frames:
        raise ValueError("compare_vo: no frames")
    if isinstance(cfg.resolution, str):     # "auto": the size the frames now have
        cfg = dataclasses.replace(cfg, resolution=tuple(frames[0].camera.size))
    stamps, gt_ts, gt_poses, gt_length = _ground_truth(frames)
    tol = cfg.max_time_diff if cfg.max_time_diff is not None else default_max_time_diff(stamps)
    rows = [_method_row(method, frames, cfg, gt_ts, gt_poses, gt_length, tol)
            for method in methods]
    _add_reference_metrics(rows, (gt_ts, gt_poses), tol, cfg)
    return rows


def _add_reference_metrics(rows: Sequence[VOCompareRow], gt: Tuple[np.ndarray, np.ndarray],
                           tol: float, cfg: VOCompareConfig) -> None:
    """Fill the reference columns of ``rows`` (:class:`VOCompareRow`): against the
    ground truth ``gt`` = ``(timestamps, camera-to-world poses)`` for every row with
    a trajectory, against the ``colmap`` row (when it has >= 3 poses) for the others.
    A comparison that raises (e.g. a pose that is not a rigid transform) is logged and
    recorded as ``reference["error"]``; the row keeps NaN there."""
    colmap = next((r for r in rows if r.method == "colmap" and r.n_tracked >= 3), None)
    for r in rows:
        if len(r.timestamps) == 0:
            continue
        try:
            _fill_reference(r, gt, None if r is colmap else colmap, tol, cfg)
        except ValueError as exc:
            logger.warning("compare_vo: %s: reference metrics not available: %s", r.method, exc)
            r.reference["error"] = str(exc)


def _fill_reference(r: VOCompareRow, gt: Tuple[np.ndarray, np.ndarray],
                    colmap: Optional[VOCompareRow], tol: float, cfg: VOCompareConfig) -> None:
    """The reference columns of one row: against ``gt``, and against ``colmap``'s
    trajectory unless None (:func:`_add_reference_metrics`)."""
    c = compare_to_reference((r.timestamps, r.poses), gt, "ground truth",
                             cfg.rotation_gap, cfg.scale_window, tol, with_ate=False)
    r.reference["ground truth"] = c.summary()
    r.rot_vs_gt_deg = c.relative_rotation.mean_deg
    r.orient_vs_gt_median_deg = c.orientation.median_deg
    r.orient_vs_gt_max_deg = c.orientation.max_deg
    if colmap is None:
        return
    c = compare_to_reference((r.timestamps, r.poses), (colmap.timestamps, colmap.poses),
                             "colmap", cfg.rotation_gap, cfg.scale_window, tol)
    r.reference["colmap"] = c.summary()
    r.rot_vs_colmap_deg = c.relative_rotation.mean_deg
    r.orient_vs_colmap_median_deg = c.orientation.median_deg
    r.orient_vs_colmap_max_deg = c.orientation.max_deg
    r.window_scale_vs_colmap_min = c.window_scale.min
    r.window_scale_vs_colmap_max = c.window_scale.max


# ================================================================== output
def _f(x: float, digits: int) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}f}"


def format_markdown_table(rows: Sequence[VOCompareRow], title: Optional[str] = None) -> str:
    """Markdown table of :func:`compare_vo` rows, with a legend that states the
    ATE variants (per-frame / keyframe-only) and the Sim(3) alignment."""
    lines = []
    if title:
        lines += [title, ""]
    lines += ["| method | frames | tracked | per-frame ATE RMSE [m] | per-frame ATE [% GT length] "
              "| keyframe-only ATE RMSE [m] | keyframes | FPS | wall [s] |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        name = r.method + (" (oracle depth)" if r.oracle else "")
        tracked = f"{r.n_tracked}/{r.n_frames} ({100.0 * r.tracked_fraction:.0f}%)"
        lines.append(f"| {name} | {r.n_frames} | {tracked} | {_f(r.ate_rmse_m, 4)} | "
                     f"{_f(r.ate_percent, 2)} | {_f(r.kf_ate_rmse_m, 4)} | "
                     f"{r.n_keyframes if r.is_keyframe is not None else '-'} | "
                     f"{_f(r.fps, 2)} | {_f(r.wall_s, 1)} |")
    gt_len = next((r.gt_length_m for r in rows if math.isfinite(r.gt_length_m)), float("nan"))
    lines += ["",
              "ATE: RMSE of camera positions after Sim(3) alignment (Umeyama with scale, evo) "
              "to the ground truth. per-frame = every posed frame (aligned together); "
              "keyframe-only = the keyframes only (aligned on their own; '-' = method without "
              "keyframes). Untracked frames are not in the ATE: read it with the tracked "
              f"column. % is of the ground-truth path length of the whole range "
              f"({_f(gt_len, 3)} m). FPS = frames / wall seconds of the method "
              "(COLMAP is offline batch SfM)."]
    for r in rows:
        note = f"- {r.method}: {r.label}"
        if r.error:
            note += f"; error: {r.error}"
        lines.append(note)
    if any(r.reference for r in rows):
        lines += ["", format_reference_table(rows)]
    return "\n".join(lines)


def _pair(a: float, b: float, digits: int, sep: str = " / ") -> str:
    return "-" if not math.isfinite(float(a)) else f"{_f(a, digits)}{sep}{_f(b, digits)}"


def format_reference_table(rows: Sequence[VOCompareRow]) -> str:
    """Markdown table of the rows' rotation / orientation / window-scale columns
    against the ground truth and COLMAP (:func:`_add_reference_metrics`), with a legend."""
    ref = next((r.reference["ground truth"] for r in rows if "ground truth" in r.reference), {})
    gap = ref.get("relative_rotation", {}).get("gap_frames", DEFAULT_GAP)
    window = ref.get("window_scale", {}).get("window_frames", DEFAULT_WINDOW)
    lines = [f"| method | rot. err / {gap} frames vs ground truth [deg] "
             "| orientation vs ground truth, median / max [deg] "
             f"| rot. err / {gap} frames vs COLMAP [deg] "
             "| orientation vs COLMAP, median / max [deg] "
             f"| window scale onto COLMAP, {window}-frame windows, min - max (spread) |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lo, hi = r.window_scale_vs_colmap_min, r.window_scale_vs_colmap_max
        scale = "-" if not math.isfinite(lo) else f"{lo:.3f} - {hi:.3f} ({hi / lo:.3f})"
        lines.append(f"| {r.method} | {_f(r.rot_vs_gt_deg, 2)} | "
                     f"{_pair(r.orient_vs_gt_median_deg, r.orient_vs_gt_max_deg, 2)} | "
                     f"{_f(r.rot_vs_colmap_deg, 2)} | "
                     f"{_pair(r.orient_vs_colmap_median_deg, r.orient_vs_colmap_max_deg, 2)} | "
                     f"{scale} |")
    lines += ["", f"Rot. err: mean angle of (R_i^T R_i+{gap})^-1 (R_ref,i^T R_ref,i+{gap}) over "
              "the frames posed in both. Orientation: per-frame angle after the best constant "
              "rotation (chordal mean). Window scale: the Sim(3) (Umeyama) scale taking the "
              f"method's camera centres onto COLMAP's in every {window}-frame window, over the "
              "same fit on all frames (1 = the run's own scale; the spread max / min is "
              "the local scale drift). 7-Scenes' ground truth cannot judge rotations at the "
              "degree level (issue 30): rotations and scale are judged against COLMAP's "
              "reconstruction of the same frames, positions against the ground truth."]
    return "\n".join(lines)


def write_results(rows: Sequence[VOCompareRow], out_dir: Union[str, Path],
                  meta: Optional[Mapping[str, object]] = None) -> Dict[str, Path]:
    """Write each method's trajectory (``<method>.txt``, TUM camera-to-world,
    posed frames; ``<method>.status.txt``; ``<method>.keyframes.txt`` when it
    has keyframes) and ``results.json`` (``meta`` plus the rows) to
    ``out_dir``.  Returns the written paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: Dict[str, Path] = {}
    for r in rows:
        if len(r.timestamps) == 0:
            continue
        path = out / f"{r.method}.txt"
        write_tum(path, r.timestamps, list(r.poses),
                  header=[f"{r.label}; per-frame poses (posed frames only); scale arbitrary"])
        written[r.method] = path
        if r.status:
            extra = {} if r.is_keyframe is None else {
                "keyframe": [int(k) for k in r.is_keyframe]}
            write_status(status_path_for(path), r.timestamps, r.status, extra)
        if r.is_keyframe is not None:
            kf = np.asarray(r.is_keyframe, bool)
            kpath = out / f"{r.method}.keyframes.txt"
            write_tum(kpath, r.timestamps[kf], list(r.poses[kf]),
                      header=[f"{r.label}; keyframes only"])
            written[f"{r.method}.keyframes"] = kpath
    payload = {**dict(meta or {}), "ate": "Sim(3)-aligned RMSE (evo Umeyama, scale corrected); "
               "per-frame and keyframe-only", "rows": [r.to_dict() for r in rows]}
    jpath = out / "results.json"
    with open(jpath, "w", encoding="utf-8") as fh:
        json.dump(payload, fh, indent=2, default=json_default)
    written["results.json"] = jpath
    return written


# ===================================================================== CLI
NAME = "vo_compare"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m spgeo.evaluation.vo.compare``."""
    parser = protocol_parser(
        "python -m spgeo.evaluation.vo.compare",
        "spgeo VO vs the OpenCV feature baseline vs the COLMAP reference on the "
        "same frames (Sim(3)-aligned ATE, per-frame and keyframe-only).")
    parser.add_argument("--resolution", default=AUTO_RESOLUTION,
                        help="WIDTHxHEIGHT every method sees, 'native', or 'auto' (default: "
                             "the processing size spgeo vo chooses: the input's aspect ratio "
                             "at about 320x240 pixels, 320x240 for 4:3 input)")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS,
                        help=f"methods to run (default: all: {' '.join(METHODS)})")
    parser.add_argument("--out", default=None, help="write trajectories and results.json here")
    parser.add_argument("--max-time-diff", type=float, default=None,
                        help="ATE association tolerance (default 0.1 for frame-number "
                             "timestamps, else 0.02 s)")
    parser.add_argument("--rotation-gap", type=int, default=DEFAULT_GAP,
                        help="frame gap of the relative rotation error against the ground "
                             "truth and COLMAP (default %(default)s)")
    parser.add_argument("--scale-window", type=int, default=DEFAULT_WINDOW,
                        help="frames per window of the scale against COLMAP "
                             "(default %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser


def run(args: argparse.Namespace) -> int:
    """Compare the methods on ``args.dataset``; print the table, write ``--out``.
    Returns 0, 1 when every method failed (bad input raises, see :func:`main`)."""
    kind, path = args.dataset
    resolution = (AUTO_RESOLUTION if args.resolution.strip().lower() == AUTO_RESOLUTION
                  else parse_resolution(args.resolution, allow_native=True, min_size=1))
    load_depth = any(m in ORACLE_METHODS for m in args.methods)
    seq = open_sequence(args, load_depth=load_depth)
    config = VOCompareConfig(resolution=resolution, max_time_diff=args.max_time_diff,
                             progress=not args.no_progress, rotation_gap=args.rotation_gap,
                             scale_window=args.scale_window)
    rows = compare_vo(seq, args.methods, resolution, config)
    size = compare_size(resolution, seq.camera.size)
    res_txt = "native" if size is None else f"{size[0]}x{size[1]}"
    title = (f"{getattr(seq, 'name', path)} ({kind}), frames {args.frames or 'all'}, "
             f"{res_txt}: per-frame and keyframe-only ATE, Sim(3)-aligned")
    print(format_markdown_table(rows, title))
    if args.out:
        written = write_results(rows, args.out, {
            "dataset": kind, "path": str(path), "frames": args.frames,
            "resolution": res_txt, "methods": list(args.methods),
            "command": "python -m spgeo.evaluation.vo.compare " + " ".join(
                getattr(args, "argv", []))})
        print(f"wrote {len(written)} files to {args.out}")
    return 0 if any(r.error is None for r in rows) else 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.vo.compare``: compare VO methods on a data-set
    range; prints a markdown table, writes trajectories and ``results.json`` to
    ``--out``.  Returns 0, 1 when every method failed, 2 for bad arguments."""
    parser = build_parser()
    parser.set_defaults(argv=protocol_argv(argv))      # recorded in results.json
    return run_protocol(parser, run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
