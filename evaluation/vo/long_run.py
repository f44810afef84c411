"""Long-run VO benchmark: ATE, loop closures, scale drift, end-pose error, FPS, peak RSS.

One fresh process per (sequence, variant) run.

    spgeo eval vo_long_run --out DIR [--sequences 7scenes,7scenes-palindrome,kitti,synthetic-loop]
        [--variants default,loops] [--frames N] [--timeout SECONDS] [--reference colmap]

Sequences (:data:`SEQUENCES`; all with ground truth, timestamps = position in
the run):

* ``7scenes``: the first :data:`SEVENSCENES_FRAMES` frames of the shared
  7-Scenes redkitchen sample (:func:`spgeo.evaluation.shared_data.shared_data_root`);
* ``7scenes-palindrome``: the same frames played forward, then back to the
  first (:func:`spgeo.evaluation.vo.memory.palindrome`): real images with an
  exact revisit, the last frame's true pose is the first's;
* ``kitti``: the shared KITTI odometry clip (grey left camera, intrinsics from
  P0 of ``calib.txt``, ground truth ``poses.txt``), read by the ``folder``
  reader with that camera, no temporary folder;
* ``synthetic-loop``: a synthetic palindrome (as ``scripts/loop_synthetic_experiment.py``):
  subsampled poses of :func:`spgeo.synthetic.make_trajectory` rendered at the
  size of :data:`SYNTHETIC_LOOP`, played forward and back to the first pose,
  with the keyframe spacing of that experiment (``odometry.keyframe.max_translation``,
  scene units).

``--frames N`` caps each sequence at ``N`` frames; a palindrome is then made of
its first half (rounded up), so it still returns to its start.

Variants (:data:`VARIANTS`): name -> :class:`spgeo.apps.vo_run.VORunConfig`
overrides (dotted field names, :func:`spgeo.configs.apply_overrides`) applied
after the sequence's own; ``default`` (none), ``loops``
(``odometry.loop_closure.enabled``) and ``no-landmarks``
(``odometry.landmarks.enabled=False``: the window-only map) and
``no-landmarks+loops`` (the window-only map with loop closure: where nothing else
remembers the start, so loops are sought) and ``inline`` (the back end between two
frames instead of the live mapping worker).  Adding a variant is one entry there.

Each (sequence, variant) runs in a fresh ``python -m`` process, one after
the other, with one BLAS / OpenMP thread, through
:func:`spgeo.apps.vo_run.run_odometry` (classical front-end unless a variant
says otherwise); the run is saved in ``DIR/<sequence>.<variant>/``
(:meth:`spgeo.apps.vo_run.VORun.save`: ``report.json``, trajectory, clouds,
plots) with the process's output in ``log.txt`` and its row in ``row.json``.
Columns: frames run, tracked (not ``lost``), lost, skipped (unreadable),
keyframes, per-frame and keyframe-only Sim(3) ATE RMSE (metres of the ground
truth; synthetic: scene units), loop closures accepted / rejected
(``report.json`` ``loop_closures``; ``-`` when loop closure is off), scale
drift (:mod:`spgeo.evaluation.vo.scale_drift`: the last keyframe's median
sensor-depth / keyframe-depth ratio over the first keyframe's, or without
sensor depth the ratio of ground-truth to estimated keyframe baselines, last
over first; one means no drift), end-pose error (the estimated relative pose
from the first to the last evaluated frame after the Sim(3) alignment's scale,
against the ground truth's: metres and degrees; on a palindrome the true
relative pose is the identity), FPS (frames over the run loop's wall time),
peak RSS (``report.json`` ``run.memory``, MiB) and the process's wall time.  The table is printed and
written as ``DIR/long_run.md`` and ``DIR/long_run.json`` (rows and
provenance), each atomically and after every run, so an interrupted benchmark
keeps what it did.  Exit status 2 for an unknown sequence or variant, 1 when
a run failed, else 0.

``--reference colmap`` judges rotations and local scale against COLMAP's
reconstruction of the same frames (issue 30; 7-Scenes' ground truth cannot judge
rotations at the degree level): COLMAP
(:func:`~spgeo.evaluation.references.colmap_vo.run_colmap_vo`, in this process,
at the VO's processing size) runs once on each sequence's distinct frames, cached
in ``DIR/colmap/<data>-<frames>/`` (``trajectory.txt`` + status, ``gt.txt``,
``reference.json``) and reused on a rerun; a palindrome takes the poses of its
frames.  Every run's row gains, against COLMAP, the relative rotation error over
30 frames, the orientation after the best constant rotation (median / max) and
the Sim(3) scale onto COLMAP over 50-frame windows (min / max, relative to the
whole run's), and against the ground truth its relative rotation error over 30
frames (:mod:`spgeo.evaluation.vo.reference_metrics`); one ``colmap`` row per
sequence gives COLMAP's own ATE and rotation error against the ground truth.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.jobs import (THREAD_ENV, EvalTable, Job, RunnerConfig, provenance,
                                   run_jobs, write_atomic)
from spgeo.evaluation.runner import protocol_argv, protocol_parser, run_protocol, write_json
from spgeo.evaluation.shared_data import shared_data_root
from spgeo.evaluation.vo.memory import palindrome
from spgeo.evaluation.vo.reference_metrics import compare_to_reference, edge_errors

__all__ = ["LongRunSequence", "SEQUENCES", "VARIANTS", "TABLE", "Reordered", "run_config",
           "run_one", "run_metrics", "end_pose_error", "scale_drift", "run_subprocess",
           "make_jobs", "markdown", "write_outputs", "build_parser", "run", "main",
           "REFERENCES", "REFERENCE_TABLE", "ColmapReference", "colmap_reference",
           "reference_columns", "loop_edges", "with_reference", "colmap_row", "colmap_references"]

#: Frames of the 7-Scenes sample the ``7scenes`` sequences use (frame numbers ``0:N``).
SEVENSCENES_FRAMES = 300
#: Synthetic loop: distinct poses, pose subsampling, seed and keyframe spacing of
#: ``scripts/loop_synthetic_experiment.py 80 0 0.03 3`` (docs/results.md).
SYNTHETIC_LOOP = {"n_unique": 80, "step": 3, "seed": 0, "size": (160, 120)}


class Reordered(SequenceABC):
    """Lazy, random-access view of a frame sequence in the order ``order``:
    item ``i`` is ``base[order[i]]`` with timestamp ``i``, name ``i``
    (zero-padded), depth only when ``depth`` (else None), and ground truth
    ``poses[order[i]]`` when ``poses`` is given (else the frame's own).  Frames
    are read from ``base`` at each access, so the view holds no image."""

    def __init__(self, base: Sequence, order: Sequence[int], poses: Optional[np.ndarray] = None,
                 depth: bool = True) -> None:
        self.base, self.order, self.poses, self.depth = base, list(order), poses, depth

    def __len__(self) -> int:
        return len(self.order)

    def __getitem__(self, i: int):
        if not isinstance(i, (int, np.integer)) or not 0 <= i < len(self.order):
            raise IndexError(i)
        j = self.order[i]
        f = self.base[j]
        gt = f.T_world_cam if self.poses is None else self.poses[j]
        return replace(f, timestamp=float(i), name=f"{i:06d}", T_world_cam=gt,
                       depth=f.depth if self.depth else None)


def _order(n: int, cap: Optional[int], loop: bool) -> List[int]:
    """Positions played: ``0..n-1`` (at most ``cap``), or with ``loop`` the
    palindrome ``0..m-1..0`` of ``m = min(n, (cap + 1) // 2)`` frames."""
    if not loop:
        return list(range(min(n, cap) if cap else n))
    m = min(n, (cap + 1) // 2) if cap else n
    return list(palindrome(m, 2 * m - 1))


def _sevenscenes(cap: Optional[int], depth: bool, loop: bool) -> Reordered:
    from spgeo.datasets import open_dataset

    path = shared_data_root() / "7scenes_redkitchen_dev"
    seq = open_dataset("7scenes", path, frames=f"0:{SEVENSCENES_FRAMES}", load_depth=depth)
    return Reordered(seq, _order(len(seq), cap, loop), depth=depth)


def _kitti(cap: Optional[int], depth: bool, loop: bool = False) -> Reordered:
    """The KITTI clip: camera from P0 of ``calib.txt``, ground truth ``poses.txt``."""
    import cv2

    from spgeo.camera import PinholeCamera
    from spgeo.datasets import open_dataset
    from spgeo.datasets.kitti import read_kitti_calib, read_kitti_poses

    root = shared_data_root() / "kitti_odometry_clip_51"
    P0 = read_kitti_calib(root / "calib.txt")["P0"]
    first = sorted((root / "image_l").glob("*.png"))[0]
    h, w = cv2.imread(str(first), cv2.IMREAD_UNCHANGED).shape[:2]
    cam = PinholeCamera.from_K(P0[:, :3], w, h)
    seq = open_dataset("folder", root / "image_l", camera=cam, load_depth=False)
    poses = np.stack(read_kitti_poses(root / "poses.txt")[:len(seq)])
    return Reordered(seq, _order(len(seq), cap, loop), poses, depth=False)


@functools.lru_cache(maxsize=1)
def _synthetic_views(n: int) -> Tuple[Any, ...]:
    """The first ``n`` views of the synthetic loop (:data:`SYNTHETIC_LOOP`), rendered with depth."""
    from spgeo import synthetic

    p = SYNTHETIC_LOOP
    cam = synthetic.default_camera(*p["size"])
    poses = synthetic.make_trajectory(p["n_unique"] * p["step"], p["seed"])[::p["step"]]
    scene = synthetic.SyntheticScene.generate(p["seed"])
    return tuple(synthetic.render_frames(scene, cam, poses[:n]))


def _synthetic_loop(cap: Optional[int], depth: bool, loop: bool = True) -> Reordered:
    """The palindrome over the rendered views (rendered once per process)."""
    order = _order(SYNTHETIC_LOOP["n_unique"], cap, loop)
    return Reordered(_synthetic_views(max(order) + 1), order, depth=depth)


@dataclass(frozen=True)
class LongRunSequence:
    """A benchmark sequence.

    Attributes:
        open: ``open(cap, depth, loop) -> frames`` (a :class:`Reordered`):
            at most ``cap`` frames (None: all), with sensor depth when ``depth``.
        loop: played as a palindrome (returns to its first frame).
        overrides: :class:`~spgeo.apps.vo_run.VORunConfig` overrides of this
            sequence (dotted names), applied before the variant's.
    """

    open: Callable[..., Reordered]
    loop: bool = False
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def frames(self, cap: Optional[int] = None, depth: bool = False) -> Reordered:
        """The frames of the sequence (see :attr:`open`)."""
        return self.open(cap, depth, self.loop)


#: ``--sequences`` name -> :class:`LongRunSequence`.
SEQUENCES: Dict[str, LongRunSequence] = {
    "7scenes": LongRunSequence(_sevenscenes),
    "7scenes-palindrome": LongRunSequence(_sevenscenes, loop=True),
    "kitti": LongRunSequence(_kitti),
    "synthetic-loop": LongRunSequence(
        _synthetic_loop, loop=True,
        overrides={"odometry.resolution": SYNTHETIC_LOOP["size"], "odometry.keyframe.max_translation": 0.03}),
}

#: ``--variants`` name -> :class:`~spgeo.apps.vo_run.VORunConfig` overrides (dotted names).
VARIANTS: Dict[str, Mapping[str, Any]] = {
    "default": {},
    "loops": {"odometry.loop_closure.enabled": True},
    "no-landmarks": {"odometry.landmarks.enabled": False},
    "no-landmarks+loops": {"odometry.landmarks.enabled": False,
                           "odometry.loop_closure.enabled": True},
    "inline": {"odometry.mapping": "inline"},
}


def run_config(sequence: str, variant: str):
    """The :class:`~spgeo.apps.vo_run.VORunConfig` of one run: no progress bar,
    the sequence's overrides, then the variant's.  Raises ``KeyError`` for an
    unknown name, :class:`spgeo.configs.ConfigError` for an unknown field."""
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.configs import apply_overrides

    cfg = apply_overrides(VORunConfig(progress=False), dict(SEQUENCES[sequence].overrides))
    return apply_overrides(cfg, dict(VARIANTS[variant]))


# ------------------------------------------------------------------ metrics of one run
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


def run_metrics(run, ate, report: Mapping[str, Any], depth_frames) -> Dict[str, Any]:
    """The row fields of a finished run: ``run`` (:class:`~spgeo.apps.vo_run.VORun`),
    ``ate`` (its :meth:`~spgeo.apps.vo_run.VORun.ate`), ``report`` (its saved
    ``report.json``), ``depth_frames`` (its frames with sensor depth, for the
    scale drift)."""
    counts = run.status_counts()
    per, kf = (ate or {}).get("per-frame"), (ate or {}).get("keyframe-only")
    loops = report.get("loop_closures")
    end_m, end_deg = end_pose_error(run, per)
    drift, drift_from = scale_drift(run, depth_frames)
    return {
        "status": run.status, "status_counts": counts, "frames": run.n_frames,
        "tracked": run.n_frames - counts.get("lost", 0), "lost": counts.get("lost", 0),
        "skipped": len(run.skipped), "keyframes": int(run.result().is_keyframe.sum()),
        "ate_m": None if per is None else per.rmse,
        "ate_pct": None if per is None else per.rmse_percent_of_length,
        "kf_ate_m": None if kf is None else kf.rmse,
        "loops_accepted": None if loops is None else len(loops["accepted"]),
        "loops_rejected": None if loops is None else int(loops["rejected"]),
        "scale_drift": drift, "scale_drift_from": drift_from,
        "end_err_m": end_m, "end_err_deg": end_deg, "fps": run.fps,
        "peak_rss_mb": (report.get("run") or {}).get("memory", {}).get("peak_rss_mb"),
    }


def run_one(sequence: str, variant: str, cap: Optional[int], folder: Path) -> Dict[str, Any]:
    """Run one (sequence, variant) in this process: the VO
    (:func:`~spgeo.apps.vo_run.run_odometry`), the run saved in ``folder``
    (:meth:`~spgeo.apps.vo_run.VORun.save`) and its row (:func:`run_metrics`)."""
    from spgeo.apps.vo_run import run_odometry

    seq = SEQUENCES[sequence]
    frames = seq.frames(cap, depth=False)
    run = run_odometry(frames, run_config(sequence, variant), n_frames=len(frames))
    ate = run.ate()
    run.save(folder, ate=ate, title=f"{sequence} {variant}")
    report = json.loads((Path(folder) / "report.json").read_text(encoding="utf-8"))
    return run_metrics(run, ate, report, seq.frames(cap, depth=True))


# ------------------------------------------------------------------ one process per run
def _base_row(sequence: str, variant: str, cap: Optional[int]) -> Dict[str, Any]:
    return {"sequence": sequence, "variant": variant, "frames_cap": cap}


def _child_main(sequence: str, variant: str, cap: str, folder: str) -> int:
    """Entry point of a run's process: :func:`run_one`, its row in ``folder/row.json``."""
    import logging

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    n = int(cap) or None
    row = {**_base_row(sequence, variant, n), **run_one(sequence, variant, n, Path(folder))}
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
    row = _base_row(sequence, variant, cap)
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
    """One :class:`~spgeo.evaluation.jobs.Job` per (sequence, variant), sequence-major."""
    return [Job(f"{s}.{v}", run_subprocess, (s, v, cap, Path(out), timeout),
                meta=_base_row(s, v, cap)) for s in sequences for v in variants]


# ------------------------------------------------------------------ the COLMAP reference
#: ``--reference`` values.
REFERENCES = ("colmap",)


@dataclass
class ColmapReference:
    """COLMAP's reconstruction of a sequence's frames, as played (:func:`colmap_reference`).

    Attributes:
        trajectory: per played frame (timestamp = position in the run, as the runs')
            COLMAP's camera-to-world pose (arbitrary world and scale; NaN / ``lost``
            where COLMAP did not register the frame).
        gt: ``(timestamps, poses)``: the ground truth on the same frames (NaN where none).
        info: ``reference.json`` (registration, models, seconds, resolution, cached).
    """

    trajectory: Any
    gt: Tuple[np.ndarray, np.ndarray]
    info: Dict[str, Any]


def _run_colmap(sequence: str, frames: Reordered, positions: List[int],
                folder: Path) -> Dict[str, Any]:
    """COLMAP on the distinct ``positions`` of ``frames`` at the processing size of
    ``sequence``'s VO runs, written to ``folder`` (``trajectory.txt`` + status,
    ``gt.npy``: (n, 4, 4) ground truth, NaN where none; ``reference.json`` last)."""
    from spgeo.evaluation.references.colmap_vo import (ColmapVOConfig, run_colmap_vo,
                                                      with_ground_truth)

    distinct = Reordered(frames.base, positions, frames.poses, depth=False)
    odometry = run_config(sequence, "default").odometry
    size = tuple(odometry.processing_size_for(tuple(distinct[0].camera.size)))
    gt: List[Optional[np.ndarray]] = []
    res = run_colmap_vo(with_ground_truth(distinct, gt), ColmapVOConfig(resolution=size))
    folder.mkdir(parents=True, exist_ok=True)
    res.save_tum(folder / "trajectory.txt")
    np.save(folder / "gt.npy", np.stack([np.full((4, 4), np.nan) if T is None else T
                                         for T in gt]))
    info = {"frames": len(positions), "resolution": list(size), **res.summary()}
    write_json(folder / "reference.json", info, indent=1)
    return info


def colmap_reference(sequence: str, cap: Optional[int], out: Path) -> ColmapReference:
    """COLMAP's reconstruction of ``sequence``'s frames (at most ``cap``) as played:
    run once on the distinct frames and cached in ``out/colmap/<data>-<frames>/``
    (reused when its ``reference.json`` is there: 7-Scenes and its palindrome share
    it when they play the same frames); a palindrome takes its frames' poses."""
    from spgeo.trajectory import Trajectory

    seq = SEQUENCES[sequence]
    frames = seq.frames(cap, depth=False)
    positions = sorted(set(frames.order))
    folder = Path(out) / "colmap" / f"{seq.open.__name__.strip('_')}-{len(positions)}"
    if (folder / "reference.json").is_file():
        info = {**json.loads((folder / "reference.json").read_text(encoding="utf-8")),
                "cached": True}
    else:
        info = {**_run_colmap(sequence, frames, positions, folder), "cached": False}
    traj = Trajectory.load(folder / "trajectory.txt")
    index = [positions.index(j) for j in frames.order]
    stamps = np.arange(len(index), dtype=np.float64)
    played = Trajectory(stamps, traj.poses[index], [traj.status[k] for k in index])
    return ColmapReference(played, (stamps, np.load(folder / "gt.npy")[index]), info)


#: ``(header, row key, decimals)`` of the reference columns (``--reference colmap``).
REFERENCE_TABLE: Tuple[Tuple[str, str, int], ...] = (
    ("rot/30 vs GT deg", "rot_vs_gt_deg", 2), ("rot/30 vs COLMAP deg", "rot_vs_colmap_deg", 2),
    ("orient. vs COLMAP med deg", "orient_vs_colmap_median_deg", 2),
    ("orient. vs COLMAP max deg", "orient_vs_colmap_max_deg", 2),
    ("win. scale vs COLMAP min", "window_scale_vs_colmap_min", 3),
    ("win. scale vs COLMAP max", "window_scale_vs_colmap_max", 3),
    ("loop edges rot. vs COLMAP mean deg", "loop_rot_vs_colmap_mean_deg", 2),
    ("loop edges rot. vs COLMAP max deg", "loop_rot_vs_colmap_max_deg", 2),
    ("loop edges dir. vs COLMAP max deg", "loop_dir_vs_colmap_max_deg", 1))


def _finite(x: float) -> Optional[float]:
    return float(x) if np.isfinite(x) else None


def loop_edges(report: Mapping[str, Any]) -> List[Tuple[float, float, np.ndarray]]:
    """The accepted loop edges of a run's ``report.json`` as
    :func:`~spgeo.evaluation.vo.reference_metrics.edge_errors` wants them:
    ``(candidate frame, query frame, S_cand_query)`` (frames = played positions)."""
    loops = report.get("loop_closures") or {}
    return [(float(a["candidate_frame"]), float(a["query_frame"]),
             np.asarray(a["S_cand_query"], dtype=np.float64))
            for a in loops.get("accepted", []) if "query_frame" in a]


def reference_columns(traj, ref: ColmapReference,
                      edges: Sequence[Tuple[float, float, np.ndarray]] = ()) -> Dict[str, Any]:
    """The reference fields of a row whose run has trajectory ``traj``
    (:class:`~spgeo.trajectory.Trajectory`, timestamps = played positions): against
    the ground truth and against COLMAP (:data:`REFERENCE_TABLE`; ``reference``:
    both :meth:`~spgeo.evaluation.vo.reference_metrics.ReferenceComparison.summary`),
    and the run's loop ``edges`` (:func:`loop_edges`) against COLMAP's relative poses
    of the same frames (rotation angle, translation direction; None without edges)."""
    vs_gt = compare_to_reference(traj, ref.gt, "ground truth", with_ate=False)
    vs_col = compare_to_reference(traj, ref.trajectory, "colmap", with_ate=False)
    o, w = vs_col.orientation, vs_col.window_scale
    e = edge_errors(list(edges), ref.trajectory)
    dirs = e.translation_direction_deg[np.isfinite(e.translation_direction_deg)]
    return {"loop_rot_vs_colmap_mean_deg": _finite(e.mean_deg),
            "loop_rot_vs_colmap_max_deg": _finite(e.max_deg),
            "loop_dir_vs_colmap_max_deg": _finite(dirs.max()) if len(dirs) else None,
            "rot_vs_gt_deg": _finite(vs_gt.relative_rotation.mean_deg),
            "rot_vs_colmap_deg": _finite(vs_col.relative_rotation.mean_deg),
            "orient_vs_colmap_median_deg": _finite(o.median_deg),
            "orient_vs_colmap_max_deg": _finite(o.max_deg),
            "window_scale_vs_colmap_min": _finite(w.min),
            "window_scale_vs_colmap_max": _finite(w.max),
            "reference": {"ground truth": vs_gt.summary(), "colmap": vs_col.summary()}}


def with_reference(row: Dict[str, Any], out: Path,
                   refs: Mapping[str, ColmapReference]) -> Dict[str, Any]:
    """``row`` with :func:`reference_columns` of its run (``out/<sequence>.<variant>/
    trajectory.txt``) when its sequence has a reference in ``refs`` and the run wrote
    a trajectory (``reference: {"error": ...}`` when they raised); else ``row`` itself."""
    from spgeo.trajectory import Trajectory

    path = Path(out) / f"{row['sequence']}.{row['variant']}" / "trajectory.txt"
    ref = refs.get(row["sequence"])
    if ref is None or row.get("error") or not path.is_file():
        return row
    report = path.parent / "report.json"
    try:
        edges = loop_edges(json.loads(report.read_text(encoding="utf-8"))) \
            if report.is_file() else []
        return {**row, **reference_columns(Trajectory.load(path), ref, edges)}
    except ValueError as exc:       # e.g. a pose that is not a rigid transform
        return {**row, "reference": {"error": str(exc)}}


def colmap_row(sequence: str, cap: Optional[int], ref: ColmapReference) -> Dict[str, Any]:
    """The ``colmap`` row of a sequence: COLMAP's registration, Sim(3) ATE and
    rotation error over 30 frames against the ground truth."""
    c = compare_to_reference(ref.trajectory, ref.gt, "ground truth")
    n, tracked = len(ref.trajectory), int(ref.trajectory.tracked.sum())
    return {**_base_row(sequence, "colmap", cap), "frames": n, "tracked": tracked,
            "lost": n - tracked, "ate_m": None if c.ate is None else c.ate.rmse,
            "ate_pct": None if c.ate is None else c.ate.rmse_percent_of_length,
            "rot_vs_gt_deg": _finite(c.relative_rotation.mean_deg),
            "run_s": (ref.info.get("timings_s") or {}).get("total"),
            "status": "reference (cached)" if ref.info.get("cached") else "reference",
            "reference": {"ground truth": c.summary(), "colmap": ref.info}, "error": None}


def colmap_references(sequences: Sequence[str], cap: Optional[int],
                      out: Path) -> Tuple[Dict[str, ColmapReference], List[Dict[str, Any]]]:
    """:func:`colmap_reference` of each sequence and its :func:`colmap_row`; a
    sequence whose COLMAP run raised gets a row with ``error`` and no reference."""
    refs: Dict[str, ColmapReference] = {}
    rows: List[Dict[str, Any]] = []
    for s in sequences:
        try:
            ref = colmap_reference(s, cap, out)
            rows.append(colmap_row(s, cap, ref))
        except Exception as exc:  # an evaluation reports, it does not die
            rows.append({**_base_row(s, "colmap", cap), "error": f"{type(exc).__name__}: {exc}"})
            continue
        refs[s] = ref
    return refs, rows


# ------------------------------------------------------------------ the table
#: ``(header, row key, decimals)`` of the Markdown table.
TABLE: Tuple[Tuple[str, str, int], ...] = (
    ("sequence", "sequence", 0), ("variant", "variant", 0), ("frames", "frames", 0),
    ("tracked", "tracked", 0), ("lost", "lost", 0), ("skipped", "skipped", 0),
    ("KFs", "keyframes", 0), ("ATE m", "ate_m", 4), ("ATE %", "ate_pct", 2),
    ("KF ATE m", "kf_ate_m", 4), ("loops acc.", "loops_accepted", 0),
    ("loops rej.", "loops_rejected", 0), ("scale drift", "scale_drift", 3),
    ("end err m", "end_err_m", 4), ("end err deg", "end_err_deg", 2), ("FPS", "fps", 1),
    ("peak RSS MiB", "peak_rss_mb", 0), ("run s", "run_s", 1),
    ("status", "status", 0), ("error", "error", 0))

_NOTE = ("ATE: Sim(3)-aligned RMSE of camera centres, frames flagged lost excluded (metres of the "
         "ground truth; synthetic-loop: scene units). Scale drift: last keyframe's over first "
         "keyframe's median sensor-depth / map-depth ratio (KITTI, no sensor depth: ground-truth / "
         "estimated keyframe baseline), 1 = none. End err: first-to-last relative pose against the "
         "ground truth's after the Sim(3) scale (palindromes: the true one is the identity; target "
         "<= 0.02 m and 1 deg). FPS: frames / wall time of the run loop. Peak RSS: report.json "
         "run.memory of the run's own process.")


_REFERENCE_NOTE = ("Against COLMAP (--reference colmap; COLMAP's reconstruction of the same "
                   "frames, rows 'colmap' give its own ATE and rotation error against the ground "
                   "truth): rot/30 = mean relative rotation error over 30 frames; orient. = "
                   "per-frame orientation after the best constant rotation; win. scale = Sim(3) "
                   "scale taking the run onto COLMAP over 50-frame windows, relative to the whole "
                   "run's (1 = none; max / min = the local scale drift).")


def markdown(rows: Sequence[Mapping[str, Any]], prov: Optional[Mapping[str, Any]] = None) -> str:
    """The rows as a Markdown table with the note and, given ``prov``, a provenance line;
    the :data:`REFERENCE_TABLE` columns (before status / error) when a row has them."""
    columns, note = TABLE, _NOTE
    if any("rot_vs_gt_deg" in r for r in rows):
        columns, note = TABLE[:-2] + REFERENCE_TABLE + TABLE[-2:], _NOTE + " " + _REFERENCE_NOTE
    lines = [EvalTable(list(rows), columns).markdown(rows_only=True), "", note]
    if prov:
        lines += ["", f"Provenance: commit {prov.get('commit')}"
                      f"{' (uncommitted changes)' if prov.get('dirty') else ''}, "
                      f"{prov.get('hostname')} ({prov.get('cpu_count')} CPUs), {prov.get('time')}; "
                      f"command: spgeo eval vo_long_run {' '.join(prov.get('argv_protocol', []))}"]
    return "\n".join(lines)


def write_outputs(rows: Sequence[Mapping[str, Any]], out: Path,
                  prov: Optional[Mapping[str, Any]] = None) -> Dict[str, Path]:
    """``out/long_run.json`` (``{"rows", "provenance"}``) and ``out/long_run.md``
    (:func:`markdown`), each written atomically; returns the paths."""
    from spgeo.jsonio import json_default

    paths = {"json": Path(out) / "long_run.json", "md": Path(out) / "long_run.md"}
    write_atomic(paths["json"], json.dumps({"rows": list(rows), "provenance": dict(prov or {})},
                                           indent=1, default=json_default))
    write_atomic(paths["md"], markdown(rows, prov) + "\n")
    return paths


def _names(text: str, known: Mapping[str, Any], what: str) -> List[str]:
    """Comma-separated names, each checked against ``known`` (``ValueError``
    naming the first unknown one)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    for n in names:
        if n not in known:
            raise ValueError(f"unknown {what} {n!r} (known: {', '.join(known)})")
    if not names:
        raise ValueError(f"no {what} given")
    return names


NAME = "vo_long_run"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--out", required=True, help="folder of the runs and long_run.json/.md")
    ap.add_argument("--sequences", default=",".join(SEQUENCES),
                    help="comma-separated (default %(default)s)")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help="comma-separated (default %(default)s)")
    ap.add_argument("--frames", type=int, default=None,
                    help="cap of frames per sequence (smoke runs; a palindrome keeps its return)")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per run")
    ap.add_argument("--reference", choices=REFERENCES, default=None,
                    help="judge rotations and local scale against COLMAP's reconstruction of "
                         "the same frames (run once per sequence, cached in --out/colmap/)")
    ap.add_argument("--colmap", dest="reference", action="store_const", const="colmap",
                    help="same as --reference colmap")
    return ap


def run(args: argparse.Namespace) -> int:
    """Run every (sequence, variant), rewriting ``--out/long_run.json/.md`` after each;
    print the table and one stderr line per failed run; 1 when a run failed.
    ValueError for an unknown name or ``--frames`` < 5 (nothing written)."""
    sequences = _names(args.sequences, SEQUENCES, "sequence")
    variants = _names(args.variants, VARIANTS, "variant")
    if args.frames is not None and args.frames < 5:
        raise ValueError(f"--frames must be >= 5, got {args.frames}")
    out = Path(args.out)
    prov = provenance({"sequences": sequences, "variants": variants, "frames": args.frames,
                       "timeout": args.timeout, "variant_overrides": VARIANTS,
                       "reference": args.reference})
    prov["argv_protocol"] = getattr(args, "argv_protocol", [])
    refs, ref_rows = ({}, []) if args.reference is None else colmap_references(
        sequences, args.frames, out)
    done: Dict[int, Dict[str, Any]] = {}

    def on_row(i: int, row: Dict[str, Any]) -> None:
        done[i] = with_reference(row, out, refs)
        write_outputs([done[k] for k in sorted(done)] + ref_rows, out, prov)

    rows = run_jobs(make_jobs(sequences, variants, args.frames, out, args.timeout),
                    RunnerConfig(progress=False, desc="vo_long_run"), on_row)
    rows = [with_reference(r, out, refs) for r in rows] + ref_rows
    write_outputs(rows, out, prov)
    print(markdown(rows, prov))
    for r in rows:
        if r.get("error"):
            print(f"error: {r['sequence']} {r['variant']}: {r['error']}", file=sys.stderr)
    return 1 if any(r.get("error") for r in rows) else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The protocol; ``--_run ...`` runs one (sequence, variant) (the child process of
    :func:`run_subprocess`)."""
    argv = protocol_argv(argv)
    if argv[:1] == ["--_run"]:
        return _child_main(*argv[1:5])
    parser = build_parser()
    parser.set_defaults(argv_protocol=argv)     # recorded in the provenance
    return run_protocol(parser, run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
