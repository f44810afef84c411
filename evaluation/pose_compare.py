"""Relative-pose comparison tables of several few-view methods.

:func:`compare_methods` / :func:`compare_fewview` report rotation and
translation-direction errors of several methods' ``T_ref_view`` lists against
ground truth and against each other; :func:`compare_on_dataset` runs pluggable
estimators (``callable(ref_frame, view_frames) -> list of T_ref_view``) on
data-set frames; :func:`format_comparison` prints the result.
"""
from __future__ import annotations

import logging
import time
from typing import Callable, Dict, List, Mapping, Optional, Sequence

import numpy as np

from spgeo.evaluation.tables import MISSING, cell
from spgeo.geometry import relative_pose

from .pose_metrics import compare_pose_lists, relative_pose_errors

__all__ = ["Estimator", "compare_methods", "compare_fewview", "compare_on_dataset",
           "format_comparison"]

logger = logging.getLogger(__name__)

PoseList = List[Optional[np.ndarray]]
#: ``callable(ref_frame, view_frames) -> one T_ref_view (4x4 or None) per view``.
Estimator = Callable[[object, Sequence[object]], Sequence[Optional[np.ndarray]]]


def compare_methods(estimates: Mapping[str, Sequence[Optional[np.ndarray]]],
                    T_ref_view_gt: Optional[Sequence[Optional[np.ndarray]]] = None,
                    view_names: Optional[Sequence[str]] = None) -> Dict[str, object]:
    """Rotation / translation-direction errors of several methods' relative poses.

    Args:
        estimates: method name -> list of ``T_ref_view`` (None = not posed), all
            of the same length (one per supporting view).
        T_ref_view_gt: optional ground truth, same length.
        view_names: optional names of the views.
    Returns:
        dict with ``"views"`` (names), ``"vs_gt"`` (method -> per-view rows and
        summary of :func:`~spgeo.evaluation.pose_metrics.compare_pose_lists`;
        empty without ground truth), ``"pairwise"`` (``"a_vs_b"`` -> the same
        between each pair of methods) and ``"gt_motion"`` (per view rotation
        angle in degrees and translation norm of the ground truth, if given).
    """
    names = list(estimates)
    lengths = {len(list(v)) for v in estimates.values()}
    if T_ref_view_gt is not None:
        lengths.add(len(list(T_ref_view_gt)))
    if len(lengths) > 1:
        raise ValueError(f"compare_methods: pose lists of different lengths {sorted(lengths)}")
    n = lengths.pop() if lengths else 0
    vnames = [f"view{j + 1}" for j in range(n)] if view_names is None else list(view_names)
    out: Dict[str, object] = {"views": vnames, "vs_gt": {}, "pairwise": {}, "gt_motion": []}
    if T_ref_view_gt is not None:
        gt = list(T_ref_view_gt)
        for name in names:
            out["vs_gt"][name] = compare_pose_lists(list(estimates[name]), gt, vnames).to_dict()
        out["gt_motion"] = [
            None if T is None else {
                "rotation_deg": relative_pose_errors(np.eye(4), T)["gt_rotation_deg"],
                "translation_norm": float(np.linalg.norm(np.asarray(T)[:3, 3]))}
            for T in gt]
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            out["pairwise"][f"{a}_vs_{b}"] = compare_pose_lists(
                list(estimates[a]), list(estimates[b]), vnames).to_dict()
    return out


def compare_fewview(T_ref_view_spgeo: Sequence[Optional[np.ndarray]],
                    T_ref_view_colmap: Sequence[Optional[np.ndarray]],
                    T_ref_view_gt: Optional[Sequence[Optional[np.ndarray]]] = None,
                    view_names: Optional[Sequence[str]] = None) -> Dict[str, object]:
    """spgeo vs COLMAP (vs ground truth when given): :func:`compare_methods` with
    the methods ``"spgeo"`` and ``"colmap"``; the pairwise entry is
    ``result["pairwise"]["spgeo_vs_colmap"]``."""
    return compare_methods({"spgeo": T_ref_view_spgeo, "colmap": T_ref_view_colmap},
                           T_ref_view_gt, view_names)


def format_comparison(comparison: Mapping[str, object]) -> str:
    """Plain-text table of a :func:`compare_methods` / :func:`compare_on_dataset`
    result: one row per view, rotation error / translation-direction error in
    degrees for each method vs ground truth and for each pair of methods."""
    views = list(comparison.get("views", []))
    blocks = [("vs GT", k, v) for k, v in dict(comparison.get("vs_gt", {})).items()]
    blocks += [("pair", k, v) for k, v in dict(comparison.get("pairwise", {})).items()]
    gt_motion = list(comparison.get("gt_motion", []) or [])
    header = ["view"] + (["gt rot", "gt |t|"] if gt_motion else [])
    for kind, name, _ in blocks:
        label = name if kind == "pair" else f"{name} vs gt"
        header += [f"{label} rot", f"{label} tdir"]
    rows = [header]
    for j, v in enumerate(views):
        row = [str(v)]
        if gt_motion:
            g = gt_motion[j] if j < len(gt_motion) else None
            row += [cell(None if g is None else g["rotation_deg"]),
                    cell(None if g is None else g["translation_norm"], 3)]
        for _, _, block in blocks:
            r = block["rows"][j]
            if not r.get("available", False):
                row += [MISSING, MISSING]
            else:
                row += [cell(r["rotation_error_deg"], 3),
                        cell(r["translation_direction_error_deg"])]
        rows.append(row)
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    lines = ["  ".join(text.rjust(w) for text, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append("(errors in degrees: rotation angle, translation-direction angle; "
                 "'-' = not posed or not finite)")
    return "\n".join(lines)


def compare_on_dataset(frames: Sequence[object],
                       estimators: Mapping[str, Estimator]) -> Dict[str, object]:
    """Run pose estimators on a reference frame plus supporting frames and
    compare them with the frames' ground truth and with each other.

    Args:
        frames: :class:`spgeo.frame.Frame` objects, reference first (at least
            two); ground truth comes from their ``T_world_cam`` (views without
            one are skipped in the ground-truth comparison).
        estimators: name -> ``callable(ref_frame, view_frames)`` returning one
            ``T_ref_view`` (4x4 or None) per supporting view.  An estimator that
            raises is recorded (``"error"``) and counted as posing nothing.
    Returns:
        :func:`compare_methods`'s dict plus ``"frames"`` (frame names),
        ``"estimates"`` (name -> poses as nested lists or None), ``"errors"``
        (name -> message or None) and ``"time_s"`` (name -> seconds).
    """
    frames = list(frames)
    if len(frames) < 2:
        raise ValueError("compare_on_dataset needs a reference and at least one view")
    ref, views = frames[0], frames[1:]
    gt: Optional[PoseList] = None
    if ref.T_world_cam is not None:
        gt = [None if f.T_world_cam is None else relative_pose(ref.T_world_cam, f.T_world_cam)
              for f in views]
    estimates: Dict[str, PoseList] = {}
    errors: Dict[str, Optional[str]] = {}
    times: Dict[str, float] = {}
    for name, fn in estimators.items():
        t = time.perf_counter()
        try:
            poses = list(fn(ref, views))
            if len(poses) != len(views):
                raise ValueError(f"returned {len(poses)} poses for {len(views)} views")
            estimates[name] = [None if T is None else np.asarray(T, np.float64) for T in poses]
            errors[name] = None
        except Exception as exc:  # an evaluation must report, not die
            logger.exception("estimator %r failed", name)
            estimates[name] = [None] * len(views)
            errors[name] = f"{type(exc).__name__}: {exc}"
        times[name] = time.perf_counter() - t
    names = [getattr(f, "name", "") or f"view{j + 1}" for j, f in enumerate(views)]
    out = compare_methods(estimates, gt, names)
    out["frames"] = [getattr(f, "name", "") for f in frames]
    out["estimates"] = {k: [None if T is None else T.tolist() for T in v]
                        for k, v in estimates.items()}
    out["errors"] = errors
    out["time_s"] = times
    return out
