"""One run of the long-run VO benchmark (:mod:`spgeo.evaluation.vo.long_run`) and its row.

:func:`run_one` runs one (sequence, variant) in this process
(:func:`spgeo.apps.vo_run.run_odometry`), saves it and returns its row's fields
(:func:`run_metrics`: counts, ATE, loop closures, :func:`scale_drift`,
:func:`keyframe_depth`, :func:`end_pose_error`, FPS, peak RSS).  :func:`run_subprocess` runs it in a fresh
``python -m spgeo.evaluation.vo.long_run --_run ...`` process (one BLAS / OpenMP thread,
this checkout first on ``PYTHONPATH``) whose entry is :func:`child_main` (the row in
``row.json``); :func:`make_jobs` makes one job per (sequence, variant).  Every row
starts with :func:`base_row`.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.jobs import THREAD_ENV, Job, write_atomic
from spgeo.evaluation.vo.long_run_sequences import SEQUENCES, run_config, runs_on

__all__ = ["end_pose_error", "scale_drift", "kitti_errors", "keyframe_depth", "run_metrics", "run_one", "base_row",
           "child_main", "run_subprocess", "make_jobs"]


def end_pose_error(run, ate) -> Tuple[Optional[float], Optional[float]]:
    """``(metres, degrees)``: the estimated relative pose from the first to the
    last frame evaluated by ``ate`` (the per-frame
    :class:`~spgeo.evaluation.trajectory.AteResult`; translation after its
    Sim(3) alignment) against the ground truth's; ``(None, None)`` without."""
    from spgeo.evaluation.pose_metrics import rotation_error_deg

    if ate is None or ate.n_associated < 2:
        return None, None
    d_est = ate.aligned_positions[-1] - ate.aligned_positions[0]
    d_gt = ate.gt_positions[-1] - ate.gt_positions[0]
    res = run.result()
    index = {float(t): i for i, t in enumerate(res.timestamps)}
    a, b = index[float(ate.timestamps[0])], index[float(ate.timestamps[-1])]
    gt_a, gt_b = run.gt_poses[a], run.gt_poses[b]
    if gt_a is None or gt_b is None:
        return float(np.linalg.norm(d_est - d_gt)), None
    R_est = res.poses[a][:3, :3].T @ res.poses[b][:3, :3]
    R_gt = gt_a[:3, :3].T @ gt_b[:3, :3]
    return float(np.linalg.norm(d_est - d_gt)), float(rotation_error_deg(R_est, R_gt))


def scale_drift(run, depth_frames) -> Tuple[Optional[float], Optional[str]]:
    """``(drift, source)``: the last keyframe's ratio over the first's, from
    :func:`~spgeo.evaluation.vo.scale_drift.keyframe_depth_ratios` (``source``
    ``"depth"``) or, with fewer than two keyframes with sensor depth,
    :func:`~spgeo.evaluation.vo.scale_drift.keyframe_baseline_ratios`
    (``"baseline"``); ``(None, None)`` when neither has two values."""
    from spgeo.evaluation.vo.scale_drift import keyframe_baseline_ratios, keyframe_depth_ratios

    ratios = [r for _, r in keyframe_depth_ratios(run, depth_frames)]
    source = "depth"
    if len(ratios) < 2:
        base = keyframe_baseline_ratios(run)
        ratios, source = [base[k] for k in sorted(base)], "baseline"
    if len(ratios) < 2 or not ratios[0] > 0:
        return None, None
    return float(ratios[-1] / ratios[0]), source


def kitti_errors(run, ate) -> Dict[str, Any]:
    """KITTI's relative errors of ``run`` (:mod:`spgeo.evaluation.kitti_metrics`:
    ``t_rel_pct``, ``r_rel_deg_per_100m`` and the segment ``kitti_lengths``) against its
    ground truth at the Sim(3) scale of ``ate`` (its per-frame
    :class:`~spgeo.evaluation.trajectory.AteResult`); lost frames end no segment.  All
    None without ground truth for every frame, without ``ate`` or when no segment fits."""
    from spgeo.evaluation.kitti_metrics import kitti_relative_errors
    from spgeo.trajectory import FrameStatus

    none = {"t_rel_pct": None, "r_rel_deg_per_100m": None, "kitti_lengths": None}
    res, gt = run.result(), run.gt_poses
    if ate is None or len(gt) != len(res) or any(g is None for g in gt):
        return none
    est = np.array(res.poses, dtype=float)
    est[np.array([s is FrameStatus.LOST for s in res.statuses], dtype=bool)] = np.nan
    try:
        k = kitti_relative_errors(est, np.array(gt, dtype=float), ate.scale)
    except ValueError:
        return none
    return {"t_rel_pct": k.t_rel_pct, "r_rel_deg_per_100m": k.r_rel_deg_per_100m,
            "kitti_lengths": list(k.lengths)}


def keyframe_depth(run, depth_frames) -> Dict[str, Any]:
    """The depth columns of a run: its keyframes' dense depth against the sensor depth of
    ``depth_frames`` (:func:`~spgeo.evaluation.depth_eval.vo_keyframe_depth`, one median
    scale per keyframe, mean over the keyframes): ``depth_abs_rel``, ``depth_delta``
    (delta < 1.25), ``depth_coverage``, ``depth_maps`` (keyframes scored); None each
    (``depth_maps`` 0) where no keyframe's frame has depth."""
    from spgeo.evaluation.depth_eval import summarize, vo_keyframe_depth

    s = summarize(vo_keyframe_depth(run.odometry, depth_frames))
    some = s["n_maps"] > 0
    return {"depth_abs_rel": s["abs_rel"] if some else None,
            "depth_delta": s["delta_1.25"] if some else None,
            "depth_coverage": s["coverage"] if some else None, "depth_maps": s["n_maps"]}


def run_metrics(run, ate, report: Mapping[str, Any], depth_frames) -> Dict[str, Any]:
    """The row fields of a finished run: ``run`` (:class:`~spgeo.apps.vo_run.VORun`),
    ``ate`` (its :meth:`~spgeo.apps.vo_run.VORun.ate`), ``report`` (its saved
    ``report.json``), ``depth_frames`` (its frames with sensor depth, for the
    scale drift and :func:`keyframe_depth`)."""
    counts = run.status_counts()
    per, kf = (ate or {}).get("per-frame"), (ate or {}).get("keyframe-only")
    loops = report.get("loop_closures")
    end_m, end_deg = end_pose_error(run, per)
    drift, drift_from = scale_drift(run, depth_frames)
    return {
        "status": run.status, "status_counts": counts, "frames": run.n_frames,
        "tracked": run.n_frames - counts.get("lost", 0), "lost": counts.get("lost", 0),
        "relocalised": counts.get("relocalised", 0),
        "segments": len(set(run.result().segment.tolist())),
        "skipped": len(run.skipped), "keyframes": int(run.result().is_keyframe.sum()),
        "ate_m": None if per is None else per.rmse,
        "ate_pct": None if per is None else per.rmse_percent_of_length,
        "kf_ate_m": None if kf is None else kf.rmse,
        "loops_accepted": None if loops is None else len(loops["accepted"]),
        "loops_rejected": None if loops is None else int(loops["rejected"]),
        "scale_drift": drift, "scale_drift_from": drift_from,
        **keyframe_depth(run, depth_frames),
        "end_err_m": end_m, "end_err_deg": end_deg, "fps": run.fps,
        "peak_rss_mb": (report.get("run") or {}).get("memory", {}).get("peak_rss_mb"),
        **kitti_errors(run, per),
    }


def run_one(sequence: str, variant: str, cap: Optional[int], folder: Path) -> Dict[str, Any]:
    """Run one (sequence, variant) in this process: the VO
    (:func:`~spgeo.apps.vo_run.run_odometry`), the run saved in ``folder``
    (:meth:`~spgeo.apps.vo_run.VORun.save`) and its row (:func:`run_metrics`)."""
    from spgeo.apps.vo_run import run_odometry
    from spgeo.frontend import MONOCULAR_FRONTENDS

    seq = SEQUENCES[sequence]
    cfg = run_config(sequence, variant)
    frames = seq.frames(cap, depth=cfg.frontend not in MONOCULAR_FRONTENDS)
    run = run_odometry(frames, cfg, n_frames=len(frames))
    ate = run.ate()
    run.save(folder, ate=ate, title=f"{sequence} {variant}")
    report = json.loads((Path(folder) / "report.json").read_text(encoding="utf-8"))
    return run_metrics(run, ate, report, seq.frames(cap, depth=True))


# ------------------------------------------------------------------ one process per run
def base_row(sequence: str, variant: str, cap: Optional[int]) -> Dict[str, Any]:
    """The fields every row starts with: sequence, variant, ``frames_cap``."""
    return {"sequence": sequence, "variant": variant, "frames_cap": cap}


def child_main(sequence: str, variant: str, cap: str, folder: str) -> int:
    """Entry point of a run's process: :func:`run_one`, its row in ``folder/row.json``."""
    import logging

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    n = int(cap) or None
    row = {**base_row(sequence, variant, n), **run_one(sequence, variant, n, Path(folder))}
    from spgeo.jsonio import json_default

    write_atomic(Path(folder) / "row.json", json.dumps(row, indent=1, default=json_default))
    return 0


def _child_env() -> Dict[str, str]:
    """This environment with one BLAS / OpenMP thread and this spgeo first on
    ``PYTHONPATH`` (the child imports the same checkout)."""
    import spgeo

    root = str(Path(spgeo.__file__).resolve().parents[1])
    path = os.environ.get("PYTHONPATH")
    return {**os.environ, **THREAD_ENV,
            "PYTHONPATH": root if not path else os.pathsep.join([root, path])}


def run_subprocess(sequence: str, variant: str, cap: Optional[int], out: Path,
                   timeout: Optional[float] = None) -> Dict[str, Any]:
    """Run one (sequence, variant) in a fresh ``python -m`` process writing
    ``out/<sequence>.<variant>/``; its row with ``run_s`` (the process's wall
    time), or the row with ``error`` (exit status and the last lines of its
    ``log.txt``, or the timeout)."""
    folder = Path(out) / f"{sequence}.{variant}"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "row.json").unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "spgeo.evaluation.vo.long_run", "--_run", sequence, variant,
           str(cap or 0), str(folder)]
    t0 = time.perf_counter()
    row = base_row(sequence, variant, cap)
    with open(folder / "log.txt", "w", encoding="utf-8") as log:
        try:
            proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=_child_env(),
                                  timeout=timeout)
        except subprocess.TimeoutExpired:
            return {**row, "run_s": time.perf_counter() - t0,
                    "error": f"timed out after {timeout} s"}
    row["run_s"] = time.perf_counter() - t0
    if proc.returncode == 0 and (folder / "row.json").is_file():
        return {**json.loads((folder / "row.json").read_text(encoding="utf-8")), **row}
    lines = (folder / "log.txt").read_text(encoding="utf-8", errors="replace").splitlines()
    tail = " | ".join([ln for ln in lines if ln.strip()][-3:]) or "no output"
    return {**row, "error": f"exit status {proc.returncode}: {tail}"}


def make_jobs(sequences: Sequence[str], variants: Sequence[str], cap: Optional[int], out: Path,
              timeout: Optional[float] = None) -> List[Job]:
    """One :class:`~spgeo.evaluation.jobs.Job` per (sequence, variant), sequence-major;
    a variant that reads sensor depth only on sequences with depth
    (:func:`~spgeo.evaluation.vo.long_run_sequences.runs_on`)."""
    return [Job(f"{s}.{v}", run_subprocess, (s, v, cap, Path(out), timeout),
                meta=base_row(s, v, cap)) for s in sequences for v in variants
            if runs_on(s, v)]
