"""The COLMAP reference of the long-run VO benchmark (``vo_long_run --reference colmap``).

:func:`colmap_reference` runs COLMAP once on a sequence's distinct frames (cached in
``DIR/colmap/<data>-<frames>/``) and gives its poses as played (:class:`ColmapReference`);
:func:`with_reference` adds to a run's row its :func:`reference_columns` (rotation,
orientation and window scale against the ground truth and COLMAP, the run's loop edges,
:func:`loop_edges`, against COLMAP's relative poses); :func:`colmap_row` is COLMAP's own
row against the ground truth, :func:`colmap_references` both for every sequence.  The
contract is in the docstring of :mod:`spgeo.evaluation.vo.long_run`; the columns are
:data:`spgeo.evaluation.vo.long_run_table.REFERENCE_TABLE`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.runner import write_json
from spgeo.evaluation.vo.long_run_runner import base_row
from spgeo.evaluation.vo.long_run_sequences import SEQUENCES, Reordered, run_config
from spgeo.evaluation.vo.reference_metrics import compare_to_reference, edge_errors

__all__ = ["REFERENCES", "ColmapReference", "colmap_reference", "loop_edges",
           "reference_columns", "with_reference", "colmap_row", "colmap_references"]

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
    the ground truth and against COLMAP
    (:data:`~spgeo.evaluation.vo.long_run_table.REFERENCE_TABLE`; ``reference``: both
    :meth:`~spgeo.evaluation.vo.reference_metrics.ReferenceComparison.summary`),
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
    return {**base_row(sequence, "colmap", cap), "frames": n, "tracked": tracked,
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
            rows.append({**base_row(s, "colmap", cap), "error": f"{type(exc).__name__}: {exc}"})
            continue
        refs[s] = ref
    return refs, rows
