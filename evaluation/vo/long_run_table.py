"""The table of the long-run VO benchmark (:mod:`spgeo.evaluation.vo.long_run`): its columns
(:data:`TABLE`; with ``--reference colmap`` also :data:`REFERENCE_TABLE`), the Markdown with
its notes and provenance (:func:`markdown`) and the files ``DIR/long_run.json`` and
``DIR/long_run.md``, each written atomically (:func:`write_outputs`).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

from spgeo.evaluation.jobs import EvalTable, write_atomic

__all__ = ["TABLE", "REFERENCE_TABLE", "markdown", "write_outputs"]

#: ``(header, row key, decimals)`` of the Markdown table.
TABLE: Tuple[Tuple[str, str, int], ...] = (
    ("sequence", "sequence", 0), ("variant", "variant", 0), ("frames", "frames", 0),
    ("tracked", "tracked", 0), ("lost", "lost", 0), ("reloc.", "relocalised", 0),
    ("segments", "segments", 0), ("skipped", "skipped", 0), ("KFs", "keyframes", 0),
    ("ATE m", "ate_m", 4), ("ATE %", "ate_pct", 2),
    ("KF ATE m", "kf_ate_m", 4), ("t_rel %", "t_rel_pct", 2),
    ("r_rel deg/100m", "r_rel_deg_per_100m", 2), ("loops acc.", "loops_accepted", 0),
    ("loops rej.", "loops_rejected", 0), ("scale drift", "scale_drift", 3),
    ("depth AbsRel", "depth_abs_rel", 3), ("depth d<1.25", "depth_delta", 3),
    ("end err m", "end_err_m", 4), ("end err deg", "end_err_deg", 2), ("FPS", "fps", 1),
    ("peak RSS MiB", "peak_rss_mb", 0), ("run s", "run_s", 1),
    ("status", "status", 0), ("error", "error", 0))


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


_NOTE = ("ATE: Sim(3)-aligned RMSE of camera centres, frames flagged lost excluded (metres of the "
         "ground truth; synthetic-loop: scene units). Scale drift: last keyframe's over first "
         "keyframe's median sensor-depth / map-depth ratio (KITTI, no sensor depth: ground-truth / "
         "estimated keyframe baseline), 1 = none. End err: first-to-last relative pose against the "
         "ground truth's after the Sim(3) scale (palindromes: the true one is the identity; target "
         "<= 0.02 m and 1 deg). FPS: frames / wall time of the run loop. Peak RSS: report.json "
         "run.memory of the run's own process. t_rel / r_rel: KITTI's relative errors over path "
         "segments (the devkit's definition, spgeo.evaluation.kitti_metrics) at the ATE's Sim(3) "
         "scale, over 100-800 m or, on a shorter path, 10-80 % of it (the KITTI clip: 5.2-41.6 m; "
         "each row's kitti_lengths in long_run.json). Depth: the keyframes' dense depth (their "
         "primitives' depth map at the processing size) against the sensor depth (resized, "
         "nearest), one median scale per keyframe, clipped to 0.1-10, AbsRel and "
         "delta < 1.25 averaged over the keyframes (spgeo.evaluation.depth_eval); '-' without "
         "depth; variant sensor-depth (the sensor-depth front-end) is its floor (7-Scenes' "
         "depth is not registered to colour; synthetic: exact).")


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
