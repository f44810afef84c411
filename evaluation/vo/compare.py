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

This module runs the comparison (:func:`compare_vo`) and is the command line; the
parts, whose names it re-exports, are :mod:`~spgeo.evaluation.vo.compare_methods` (the
methods, the size they see, :class:`VOCompareConfig`, the frames resized once) and
:mod:`~spgeo.evaluation.vo.compare_results` (:class:`VOCompareRow`, the tables and the
files).
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from typing import Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.apps.args import parse_resolution
from spgeo.frame import Frame

from spgeo.evaluation.trajectory import (AteResult, ate_per_frame_and_keyframes,
                                         default_max_time_diff, path_length)
from spgeo.evaluation.runner import open_sequence, protocol_argv, protocol_parser, run_protocol
from spgeo.evaluation.vo.compare_methods import (AUTO_RESOLUTION, DEFAULT_RESOLUTION,
                                                 METHOD_LABELS, METHODS, ORACLE_METHODS,
                                                 VOCompareConfig, check_methods, compare_size,
                                                 prepare_frames, run_method)
from spgeo.evaluation.vo.compare_results import (VOCompareRow, format_markdown_table,
                                                 format_reference_table, write_results)
from spgeo.evaluation.vo.reference_metrics import (DEFAULT_GAP, DEFAULT_WINDOW,
                                                   compare_to_reference)

__all__ = ["METHODS", "METHOD_LABELS", "ORACLE_METHODS", "DEFAULT_RESOLUTION", "VOCompareConfig",
           "AUTO_RESOLUTION", "compare_size", "VOCompareRow", "prepare_frames", "compare_vo",
           "format_markdown_table", "format_reference_table", "write_results", "build_parser",
           "run", "main"]

logger = logging.getLogger(__name__)


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


def _fill_ate(row: VOCompareRow, out, gt_ts: np.ndarray, gt_poses: np.ndarray,
              gt_length: float, tol: float) -> None:
    """Store the method's output ``out`` (:func:`run_method`) and its ATE in ``row``
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
        out = run_method(method, frames, cfg)
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
    methods = check_methods(methods)
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
