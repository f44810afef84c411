"""Few-view SfM at wide baselines, judged against COLMAP (issue 40): the gap cases of
``spgeo eval sfm_real`` (:mod:`.real`).

Triplets ``(ref, ref + G, ref + 2G)`` of one sequence (the shared 7-Scenes clip) for
each gap ``G`` and reference frame ``ref``; every estimator runs on each triplet through
:func:`spgeo.evaluation.pose_compare.compare_on_dataset`.  Each view of each method
gets its rotation / translation-direction error against the ground truth *and* against
COLMAP's pose of the same view (where COLMAP posed it; how, ``"incremental"`` or
``"two_view"``, is recorded, :attr:`ColmapResult.view_method
<spgeo.evaluation.references.colmap.ColmapResult.view_method>`).  COLMAP judges the
rotations because the clip's ground truth itself disagrees with COLMAP by about as
much as the errors judged (docs/results.md, "Few-view SfM at wider baselines").

Per gap and method (:func:`summarize_views`): medians over the posed views (NaN errors
left out, views flagged by the method kept in), views posed / flagged and the flagged
views' own median, median seconds per triplet.  For a method that reports pose
covariances (spgeo's ``SfMResult.pose_covariances``), :func:`rotation_coverage` says
how often its rotation error is within ``k`` times ``sigma_rot_deg``
(:func:`sigma_rot_deg`: the RMS of the rotation-error angle the covariance predicts).
The pure functions (:func:`parse_int_list`, :func:`sigma_rot_deg`,
:func:`rotation_coverage`, :func:`view_records`, :func:`summarize_views`,
:func:`coverage_report`) take plain arrays / dicts and are unit-tested
(``tests/test_sfm_gaps.py``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.pose_compare import compare_on_dataset
from spgeo.evaluation.tables import MISSING, cell, markdown_table

__all__ = ["GAP_DATA", "JUDGE", "MAX_JUDGE_DISAGREEMENT_DEG", "parse_int_list", "sigma_rot_deg",
           "rotation_coverage", "view_records", "summarize_views", "coverage_report",
           "clip_estimator", "methods_with", "gap_triplets", "DEPTH_FLOOR", "run_gap_triplet",
           "GapResults",
           "run_gaps"]

log = logging.getLogger(__name__)

#: the shared data folder (under ``../shared/data``) of the gap cases
GAP_DATA = "7scenes_redkitchen_dev"
#: the estimator whose poses judge the others
JUDGE = "colmap"
#: ``ColmapConfig().max_rotation_disagreement_deg``: a judge pose further than this from
#: its two-view rotation is *inconsistent* (COLMAP's own check, status ``"inconsistent"``)
MAX_JUDGE_DISAGREEMENT_DEG = 2.0

Record = Dict[str, object]
EstimatorFactory = Callable[[], Dict[str, Callable]]


# ======================================================================= pure helpers
def parse_int_list(text: Optional[str], name: str = "value", minimum: int = 0) -> List[int]:
    """``"10, 30,60"`` -> ``[10, 30, 60]``; None, ``""`` or ``"none"`` -> ``[]``.

    Raises:
        ValueError: a part that is not an integer, or is below ``minimum`` (the
            message names ``name``)."""
    if text is None or text.strip().lower() in ("", "none"):
        return []
    out = []
    for part in text.split(","):
        part = part.strip()
        try:
            value = int(part)
        except ValueError:
            raise ValueError(f"{name}: expected comma-separated integers, got {text!r}") from None
        if value < minimum:
            raise ValueError(f"{name}: {value} is below {minimum}")
        out.append(value)
    return out


def sigma_rot_deg(cov: Optional[np.ndarray]) -> float:
    """``degrees(sqrt(trace(cov[:3, :3])))``: the RMS rotation-error angle a 6x6 pose
    covariance (rotation block first, radians) predicts; NaN for None, a wrong shape,
    non-finite entries or a negative trace."""
    if cov is None:
        return float("nan")
    c = np.asarray(cov, np.float64)
    if c.shape != (6, 6) or not np.all(np.isfinite(c[:3, :3])):
        return float("nan")
    tr = float(np.trace(c[:3, :3]))
    return math.degrees(math.sqrt(tr)) if tr >= 0 else float("nan")


def _median(values: Sequence[float]) -> float:
    """Median of the finite values; NaN when there are none."""
    a = np.asarray(list(values), np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else float("nan")


def rotation_coverage(errors_deg: Sequence[float], sigmas_deg: Sequence[float],
                      k: float = 3.0) -> Dict[str, float]:
    """How well predicted rotation sigmas cover measured rotation errors.

    Args:
        errors_deg, sigmas_deg: per view, equally long; a view counts only where both
            are finite and the sigma is > 0.
        k: the coverage multiple.
    Returns:
        ``{"n": views counted, "within": of those, error <= k * sigma, "fraction":
        within / n (NaN when n is 0), "median_ratio": median of error / sigma (NaN
        when n is 0)}``.
    Raises:
        ValueError: lists of different lengths."""
    e = np.asarray(list(errors_deg), np.float64).reshape(-1)
    s = np.asarray(list(sigmas_deg), np.float64).reshape(-1)
    if e.shape != s.shape:
        raise ValueError(f"rotation_coverage: {e.size} errors for {s.size} sigmas")
    use = np.isfinite(e) & np.isfinite(s) & (s > 0)
    n = int(use.sum())
    ratio = e[use] / s[use]
    within = int(np.sum(ratio <= k))
    return {"n": n, "within": within, "fraction": within / n if n else float("nan"),
            "median_ratio": float(np.median(ratio)) if n else float("nan")}


def _rows_against(comp: Mapping, method: str, judge: str) -> Optional[List[Mapping]]:
    """The pairwise rows of ``method`` against ``judge`` in a compare_methods dict
    (either key order; the errors are symmetric), None when absent."""
    pairs = comp.get("pairwise", {})
    for key in (f"{method}_vs_{judge}", f"{judge}_vs_{method}"):
        if key in pairs:
            return pairs[key]["rows"]
    return None


def _errors(row: Optional[Mapping]) -> Tuple[float, float]:
    if row is None or not row.get("available"):
        return float("nan"), float("nan")
    return float(row["rotation_error_deg"]), float(row["translation_direction_error_deg"])


def view_records(comp: Mapping, gap: int, ref: int, judge_how: Sequence[Optional[str]],
                 statuses: Optional[Mapping[str, Sequence[str]]] = None,
                 sigmas: Optional[Mapping[str, Sequence[float]]] = None,
                 judge: str = JUDGE, judge_disagreement_deg: Optional[Sequence[float]] = None,
                 max_disagreement_deg: float = MAX_JUDGE_DISAGREEMENT_DEG) -> List[Record]:
    """One record per method and view of a :func:`compare_on_dataset` dict.

    Args:
        comp: the comparison (``"views"``, ``"estimates"``, ``"vs_gt"``, ``"pairwise"``).
        gap, ref: the triplet's gap and reference frame number (copied).
        judge_how: per view, how the judge posed it (``"incremental"``,
            ``"two_view"``; None = not posed).
        statuses: method -> status per view (spgeo's ``view_status``); a posed view
            whose status is not ``"ok"`` is *flagged*.  Methods absent: no status.
        sigmas: method -> ``sigma_rot_deg`` per view (NaN where none).
        judge: the judging method's name in ``comp``.
        judge_disagreement_deg: per view, the angle between the judge's incremental
            and two-view rotations (``ColmapResult.two_view_disagreement_deg``; NaN
            where not checked); None: not known.
        max_disagreement_deg: above it the judge's pose of the view is *inconsistent*
            (COLMAP's own check; its errors are kept, the record says so).
    Returns:
        records with ``gap, ref, view, method, posed, status, flagged,
        rotation_vs_gt_deg, tdir_vs_gt_deg, rotation_vs_colmap_deg,
        tdir_vs_colmap_deg`` (NaN where the judge did not pose the view, and for the
        judge itself), ``colmap_posed_by``, ``colmap_disagreement_deg``,
        ``colmap_inconsistent`` and ``sigma_rot_deg``."""
    statuses, sigmas = statuses or {}, sigmas or {}
    views = list(comp["views"])
    dis = [float("nan") if d is None else float(d) for d in (judge_disagreement_deg or [])]
    dis += [float("nan")] * (len(views) - len(dis))
    out: List[Record] = []
    for method, poses in comp["estimates"].items():
        gt_rows = comp.get("vs_gt", {}).get(method, {}).get("rows")
        judge_rows = None if method == judge else _rows_against(comp, method, judge)
        for j, view in enumerate(views):
            posed = poses[j] is not None
            status = statuses[method][j] if method in statuses else None
            rg, tg = _errors(gt_rows[j] if gt_rows else None)
            rc, tc = _errors(judge_rows[j] if judge_rows else None)
            sig = sigmas[method][j] if method in sigmas else float("nan")
            out.append({"gap": int(gap), "ref": int(ref), "view": str(view), "method": method,
                        "posed": posed, "status": status,
                        "flagged": bool(posed and status is not None and status != "ok"),
                        "rotation_vs_gt_deg": rg, "tdir_vs_gt_deg": tg,
                        "rotation_vs_colmap_deg": rc, "tdir_vs_colmap_deg": tc,
                        "colmap_posed_by": judge_how[j] if j < len(judge_how) else None,
                        "colmap_disagreement_deg": dis[j],
                        "colmap_inconsistent": bool(dis[j] > max_disagreement_deg),
                        "sigma_rot_deg": float(sig) if sig is not None else float("nan")})
    return out


def summarize_views(records: Sequence[Record],
                    seconds: Optional[Mapping[str, Sequence[float]]] = None
                    ) -> Dict[str, Dict[str, float]]:
    """Per method (in the records' order): ``views``, ``posed``, ``flagged`` (posed and
    flagged), ``judged`` (finite rotation error vs COLMAP), ``judged_inconsistent`` (of
    those, judged by a COLMAP pose that fails COLMAP's own two-view check), the medians
    over the posed views, flagged ones included (NaN errors left out)
    ``rotation_vs_colmap_deg, tdir_vs_colmap_deg, rotation_vs_gt_deg, tdir_vs_gt_deg``,
    ``rotation_vs_consistent_colmap_deg`` (the views whose COLMAP pose is not
    inconsistent), the medians of the rotation error vs COLMAP of the unflagged and of
    the flagged posed views (``rotation_vs_colmap_ok_deg``,
    ``rotation_vs_colmap_flagged_deg``), ``common`` views and the medians over them
    ``rotation_vs_colmap_common_deg``, ``tdir_vs_colmap_common_deg`` (the views every
    judged method posed without a flag: :func:`_common_views`) and ``seconds``: the
    median of ``seconds[method]`` (time per triplet; NaN without)."""
    out: Dict[str, Dict[str, float]] = {}
    methods = list(dict.fromkeys(str(r["method"]) for r in records))
    common = _common_views(records)
    for m in methods:
        rows = [r for r in records if r["method"] == m]
        posed = [r for r in rows if r["posed"]]
        flagged = [r for r in posed if r["flagged"]]
        ok = [r for r in posed if not r["flagged"]]
        judged = [r for r in posed if math.isfinite(float(r["rotation_vs_colmap_deg"]))]
        s = {"views": len(rows), "posed": len(posed), "flagged": len(flagged),
             "judged": len(judged),
             "judged_inconsistent": sum(bool(r.get("colmap_inconsistent")) for r in judged)}
        for key in ("rotation_vs_colmap_deg", "tdir_vs_colmap_deg", "rotation_vs_gt_deg",
                    "tdir_vs_gt_deg"):
            s[key] = _median([float(r[key]) for r in posed])
        s["rotation_vs_consistent_colmap_deg"] = _median(
            [float(r["rotation_vs_colmap_deg"]) for r in judged
             if not r.get("colmap_inconsistent")])
        s["rotation_vs_colmap_ok_deg"] = _median([float(r["rotation_vs_colmap_deg"]) for r in ok])
        s["rotation_vs_colmap_flagged_deg"] = _median(
            [float(r["rotation_vs_colmap_deg"]) for r in flagged])
        on_common = [r for r in judged if (r["ref"], r["view"]) in common]
        s["common"] = len(on_common)
        s["rotation_vs_colmap_common_deg"] = _median(
            [float(r["rotation_vs_colmap_deg"]) for r in on_common])
        s["tdir_vs_colmap_common_deg"] = _median(
            [float(r["tdir_vs_colmap_deg"]) for r in on_common])
        s["seconds"] = _median((seconds or {}).get(m, []))
        out[m] = s
    return out


def _common_views(records: Sequence[Record]) -> set:
    """``(ref, view)`` of the views every judged method posed without a flag and the
    judge posed too: where the methods are compared on equal terms."""
    keys: Dict[str, set] = {}
    for r in records:
        keys.setdefault(str(r["method"]), set())
        if (r["posed"] and not r["flagged"]
                and math.isfinite(float(r["rotation_vs_colmap_deg"]))):
            keys[str(r["method"])].add((r["ref"], r["view"]))
    judged = [k for k in keys.values() if k]
    return set.intersection(*judged) if judged else set()


def coverage_report(records: Sequence[Record], method: str, k: float = 3.0
                    ) -> Dict[str, Dict[str, object]]:
    """:func:`rotation_coverage` of ``method``'s posed views against COLMAP and against
    the ground truth, per gap (keys ``"gap G"``) and over all (``"all"``); each entry
    ``{"n_sigma": views with a finite sigma > 0, "median_sigma_deg", "vs_colmap": ...,
    "vs_gt": ...}``.  Flagged views are included (the sigma should cover them too)."""
    rows = [r for r in records if r["method"] == method and r["posed"]]
    groups: Dict[str, List[Record]] = {}
    for r in rows:
        groups.setdefault(f"gap {r['gap']}", []).append(r)
    groups["all"] = rows
    out: Dict[str, Dict[str, object]] = {}
    for name, grp in groups.items():
        sig = [float(r["sigma_rot_deg"]) for r in grp]
        good = [x for x in sig if math.isfinite(x) and x > 0]
        out[name] = {"n_sigma": len(good), "median_sigma_deg": _median(good),
                     "vs_colmap": rotation_coverage(
                         [float(r["rotation_vs_colmap_deg"]) for r in grp], sig, k),
                     "vs_gt": rotation_coverage([float(r["rotation_vs_gt_deg"]) for r in grp],
                                                sig, k)}
    return out


# ============================================================================ running
class _ClipPoses:
    """``last_result`` of :func:`clip_estimator`: how each view was posed."""

    def __init__(self, view_method: List[Optional[str]]) -> None:
        self.view_method = view_method


def clip_estimator(traj, max_time_diff: float = 1e-3) -> Callable:
    """An estimator (for :func:`compare_on_dataset`) that reads the poses of a reference
    trajectory of the whole clip (a :class:`spgeo.trajectory.Trajectory`, e.g.
    ``spgeo eval colmap_vo --out DIR``'s ``trajectory.txt``, loaded with its status
    file): ``T_ref_view`` of each view from the frames' timestamps (within
    ``max_time_diff``); None for a frame the trajectory lost or lacks.  Its
    ``last_result.view_method`` says ``"clip"`` per posed view.  COLMAP on hundreds of
    frames is a sharper judge than COLMAP on the three views (docs/results.md, issue 40).
    """
    stamps = np.asarray(traj.timestamps, np.float64)
    usable = traj.tracked

    def pose_of(frame) -> Optional[np.ndarray]:
        i = int(np.argmin(np.abs(stamps - float(frame.timestamp)))) if len(stamps) else -1
        if i < 0 or abs(stamps[i] - float(frame.timestamp)) > max_time_diff or not usable[i]:
            return None
        return traj.poses[i]

    def estimate(ref, views):
        T_ref = pose_of(ref)
        poses = [None if T_ref is None or pose_of(v) is None
                 else np.linalg.inv(T_ref) @ pose_of(v) for v in views]
        estimate.last_result = _ClipPoses(["clip" if T is not None else None for T in poses])
        return poses

    estimate.last_result = None  # type: ignore[attr-defined]
    return estimate


def gap_triplets(frame_numbers: Sequence[int], gaps: Sequence[int], refs: Sequence[int]
                 ) -> List[Tuple[int, int, List[int]]]:
    """``(gap, ref, [ref, ref + gap, ref + 2 gap])`` for every gap and ref, gaps outer.

    Raises:
        ValueError: a frame number the sequence lacks (all triplets checked first)."""
    have = {int(n) for n in frame_numbers}
    out = [(int(g), int(r), [int(r) + k * int(g) for k in (0, 1, 2)]) for g in gaps for r in refs]
    missing = sorted({n for _, _, nums in out for n in nums if n not in have})
    if missing:
        hi = max(have) if have else None
        raise ValueError(f"gap cases: frames {missing} not in the sequence (frames "
                         f"{min(have) if have else None}..{hi})")
    return out


def _last(fn: Callable) -> object:
    return getattr(fn, "last_result", None)


#: the depth table's floor row (:func:`spgeo.evaluation.dense_depth.sensor_depth_floor`)
DEPTH_FLOOR = "sensor-depth primitives (floor)"


def run_gap_triplet(seq, gap: int, ref: int, estimators: Mapping[str, Callable],
                    judge: str = JUDGE, depth_floor: bool = False
                    ) -> Tuple[Dict[str, object], List[Record]]:
    """Run ``estimators`` (fresh ones: their ``last_result`` is read) on the triplet
    ``(ref, ref + gap, ref + 2 gap)`` of ``seq`` (frames looked up by frame number).

    Returns:
        ``(triplet dict, view records)``: the triplet dict holds ``gap, ref, frames``,
        ``comparison`` (:func:`compare_on_dataset`'s dict), ``colmap`` (the judge's
        ``ColmapResult.summary()`` or None) and ``per_method`` (method -> ``status,
        view_status, heldout_px, sigma_rot_deg, pose_covariances, depth`` where its
        result has them; ``heldout_px``: spgeo's held-out check of the photometric
        poses; ``depth``: its reference depth against the reference frame's sensor
        depth, :func:`spgeo.evaluation.depth_eval.sfm_reference_depth`) and, with
        ``depth_floor`` and a reference with depth, ``depth_floor``
        (:func:`spgeo.evaluation.dense_depth.sensor_depth_floor`)."""
    from spgeo.evaluation.depth_eval import sfm_reference_depth

    index = {int(n): i for i, n in enumerate(seq.frame_numbers)}
    numbers = [ref, ref + gap, ref + 2 * gap]
    frames = [seq[index[n]] for n in numbers]
    comp = compare_on_dataset(frames, estimators)
    statuses: Dict[str, List[str]] = {}
    sigmas: Dict[str, List[float]] = {}
    per_method: Dict[str, Dict[str, object]] = {}
    for name, fn in estimators.items():
        res = _last(fn)
        if name == judge or res is None or not hasattr(res, "view_status"):
            continue
        statuses[name] = [str(s) for s in res.view_status]
        info: Dict[str, object] = {"status": res.status, "view_status": statuses[name],
                                   "heldout_px": getattr(res, "report", {}).get("heldout_px")}
        covs = getattr(res, "pose_covariances", None)
        if covs is not None:
            sigmas[name] = [sigma_rot_deg(c) for c in covs]
            info["sigma_rot_deg"] = sigmas[name]
            info["pose_covariances"] = [None if c is None else np.asarray(c).tolist()
                                        for c in covs]
        if (getattr(res, "depth", None) is not None
                and getattr(frames[0], "depth", None) is not None):
            info["depth"] = sfm_reference_depth(res, frames[0].depth)
        per_method[name] = info
    jres = _last(estimators[judge]) if judge in estimators else None
    how = list(getattr(jres, "view_method", [])) or [None] * (len(numbers) - 1)
    records = view_records(comp, gap, ref, how, statuses, sigmas, judge,
                           getattr(jres, "two_view_disagreement_deg", None))
    triplet = {"gap": gap, "ref": ref, "frames": numbers, "comparison": comp,
               "colmap": jres.summary() if hasattr(jres, "summary") else None,
               "per_method": per_method}
    if depth_floor and getattr(frames[0], "depth", None) is not None:
        from spgeo.evaluation.dense_depth import sensor_depth_floor

        triplet["depth_floor"] = sensor_depth_floor(frames[0])
    return triplet, records


def _summary_row(gap: str, method: str, s: Mapping[str, object]) -> List[str]:
    """The cells of one method's :func:`summarize_views` in :meth:`GapResults.summary_table`."""
    return [gap, method, cell(s["rotation_vs_colmap_deg"]), cell(s["tdir_vs_colmap_deg"], 1),
            cell(s["rotation_vs_gt_deg"]), cell(s["tdir_vs_gt_deg"], 1),
            f"{s['posed']} of {s['views']}", f"{s['judged']} ({s['judged_inconsistent']})",
            cell(s["rotation_vs_consistent_colmap_deg"]), cell(s["flagged"]),
            f"{cell(s['rotation_vs_colmap_ok_deg'])} / {cell(s['rotation_vs_colmap_flagged_deg'])}",
            f"{cell(s['rotation_vs_colmap_common_deg'])} / "
            f"{cell(s['tdir_vs_colmap_common_deg'], 1)} ({s['common']})", cell(s["seconds"], 1)]


def methods_with(records: Sequence[Record], key: str) -> List[str]:
    """Methods (in order) with a non-None ``status`` (``key="status"``) or a finite
    ``sigma_rot_deg`` (``key="sigma_rot_deg"``) in some record."""
    def has(r: Record) -> bool:
        v = r[key]
        return v is not None if key == "status" else math.isfinite(float(v))  # type: ignore
    return list(dict.fromkeys(str(r["method"]) for r in records if has(r)))


@dataclass
class GapResults:
    """Output of :func:`run_gaps`.

    Attributes:
        data: the sequence's name / folder.
        gaps, refs: the gaps and reference frame numbers run.
        judge: the method whose poses judge the others (the tables' "COLMAP").
        label, ref_label: what the tables call ``gap`` and ``ref`` (the synthetic
            cases: the angle and the seed).
        triplets: one dict per triplet (:func:`run_gap_triplet`).
        records: the view records of every triplet (:func:`view_records`).
        summary: ``"gap G"`` -> :func:`summarize_views` of that gap's records.
        coverage: method with covariances -> :func:`coverage_report` (k = 3).
    """

    data: str
    gaps: List[int]
    refs: List[int]
    judge: str = JUDGE
    label: str = "gap"
    ref_label: str = "ref"
    triplets: List[Dict[str, object]] = field(default_factory=list)
    records: List[Record] = field(default_factory=list)
    summary: Dict[str, Dict[str, Dict[str, float]]] = field(default_factory=dict)
    coverage: Dict[str, Dict[str, Dict[str, object]]] = field(default_factory=dict)

    def summary_table(self) -> str:
        """Markdown: per gap and method the medians over the gap's posed views
        (flagged ones included), views posed / judged by COLMAP (of those, by an
        inconsistent COLMAP pose) / flagged, the median rotation error vs the consistent
        COLMAP poses only, the unflagged and flagged views' median rotation error vs
        COLMAP, seconds."""
        header = [self.label, "method", "rot vs COLMAP", "tdir vs COLMAP", "rot vs GT",
                  "tdir vs GT", "posed", "judged (inconsistent judge)",
                  "rot vs consistent COLMAP", "flagged", "rot vs COLMAP: ok / flagged views",
                  "rot / tdir vs COLMAP on common views", "s per triplet"]
        rows = [_summary_row(gname.split()[-1], m, s)
                for gname, per in self.summary.items() for m, s in per.items()]
        return "\n".join(markdown_table(header, rows, "ll" + "r" * 11))

    def coverage_table(self) -> str:
        """Markdown: per method with covariances, per gap and overall, the views with
        a sigma, their median ``sigma_rot_deg`` and the 3-sigma coverage / median
        error-to-sigma ratio against COLMAP and against the ground truth."""
        rows = []
        for m, rep in self.coverage.items():
            for gname, c in rep.items():
                cells = [m, gname.replace("gap ", ""), cell(c["n_sigma"]),
                         cell(c["median_sigma_deg"], "{:.3g}")]
                for judge in ("vs_colmap", "vs_gt"):
                    cov = c[judge]
                    cells += [f"{cov['within']} of {cov['n']} ({cell(cov['fraction'])})",
                              cell(cov["median_ratio"], "{:.3g}")]
                rows.append(cells)
        header = ["method", self.label, "views with sigma", "median sigma_rot deg",
                  "within 3 sigma of COLMAP", "median err/sigma (COLMAP)",
                  "within 3 sigma of GT", "median err/sigma (GT)"]
        return "\n".join(markdown_table(header, rows, "ll" + "r" * 6))

    def views_table(self) -> str:
        """Markdown: one row per view, how COLMAP posed it (with ``inconsistent, D``
        where its incremental rotation is D degrees from its two-view one) and each
        method's rotation error vs COLMAP / vs GT (degrees; ``[status]`` where the
        method gives one; ``sigma`` columns for methods with covariances)."""
        methods = list(dict.fromkeys(str(r["method"]) for r in self.records))
        with_sigma = methods_with(self.records, "sigma_rot_deg")
        head = ([self.label, self.ref_label, "view", "COLMAP posed by"]
                + [f"{m} rot vs COLMAP / GT" for m in methods]
                + [f"{m} sigma_rot deg" for m in with_sigma])
        rows = []
        by_view: Dict[Tuple[int, int, str], Dict[str, Record]] = {}
        for r in self.records:
            by_view.setdefault((int(r["gap"]), int(r["ref"]), str(r["view"])), {})[
                str(r["method"])] = r
        for (gap, ref, view), per in by_view.items():
            first = next(iter(per.values()))
            how = str(first["colmap_posed_by"] or "not posed")
            if first.get("colmap_inconsistent"):
                how += f" (inconsistent, {cell(first['colmap_disagreement_deg'], 1)})"
            cells = [str(gap), str(ref), view, how]
            for m in methods:
                r = per.get(m)
                if r is None or not r["posed"]:
                    cells.append("unposed")
                    continue
                cells.append(f"{cell(r['rotation_vs_colmap_deg'])} / "
                             f"{cell(r['rotation_vs_gt_deg'])}"
                             + (f" [{r['status']}]" if r["status"] is not None else ""))
            cells += [cell(per[m]["sigma_rot_deg"], "{:.3g}") if m in per else MISSING
                      for m in with_sigma]
            rows.append(cells)
        return "\n".join(markdown_table(head, rows, "llll" + "r" * (len(head) - 4)))

    def depth_summary(self) -> Dict[str, Dict[str, Dict[str, float]]]:
        """``"gap G"`` -> method -> :func:`spgeo.evaluation.depth_eval.summarize` of the
        reference depths (``per_method[m]["depth"]`` of each triplet: one median scale
        per depth map, the mean over the gap's triplets; :data:`DEPTH_FLOOR`: the
        triplets' ``depth_floor``); methods without depth absent."""
        from spgeo.evaluation.depth_eval import DepthMapScore, summarize

        maps: Dict[str, Dict[str, List[DepthMapScore]]] = {}
        for t in self.triplets:
            depths = {m: info.get("depth") for m, info in t.get("per_method", {}).items()}
            depths[DEPTH_FLOOR] = t.get("depth_floor")
            for m, d in depths.items():
                if d is not None:
                    maps.setdefault(f"gap {t['gap']}", {}).setdefault(m, []).append(
                        DepthMapScore(f"ref {t['ref']}", int(t["ref"]), d))
        return {g: {m: summarize(s) for m, s in per.items()} for g, per in maps.items()}

    def depth_table(self) -> str:
        """Markdown: per gap and method, the reference depth against the sensor depth
        (:meth:`depth_summary`): maps, AbsRel, delta < 1.25, coverage."""
        rows = [[g.split()[-1], m, cell(s["n_maps"]), cell(s["abs_rel"], 3),
                 cell(s["delta_1.25"], 3), cell(s["coverage"])]
                for g, per in self.depth_summary().items() for m, s in per.items()]
        header = [self.label, "method", "depth maps", "depth AbsRel", "depth d<1.25",
                  "coverage"]
        return "\n".join(markdown_table(header, rows, "ll" + "r" * 4))

    def table(self) -> str:
        """The tables, each under a one-line title (the depth table where a method
        gave a reference depth and the frames have depth)."""
        parts = [
            f"Gap cases on {self.data}, refs {self.refs}, judged by {self.judge!r} (the "
            "tables' COLMAP): medians over each gap's views "
            "(degrees; rot = rotation error, tdir = translation-direction error)",
            self.summary_table(),
            "Rotation covariance coverage (sigma_rot = degrees(sqrt(trace(C_rot))))",
            self.coverage_table(), "Per view: rotation error vs COLMAP / vs GT (degrees)",
            self.views_table()]
        if self.depth_summary():
            parts += ["Reference depth against the sensor depth (one median scale per depth "
                      "map, clipped to 0.1-10; mean over the refs; spgeo.evaluation.depth_eval)",
                      self.depth_table()]
        return "\n\n".join(parts)

    def to_dict(self) -> Dict[str, object]:
        """Everything, JSON-friendly (numpy values through ``json_default``)."""
        return {"data": self.data, "gaps": list(self.gaps), "refs": list(self.refs),
                "judge": self.judge,
                "summary": self.summary, "coverage": self.coverage,
                "depth": self.depth_summary(), "views": self.records,
                "triplets": self.triplets}


def run_gaps(seq, gaps: Sequence[int], refs: Sequence[int], make_estimators: EstimatorFactory,
             data: str = "", judge: str = JUDGE, k: float = 3.0,
             depth_floor: bool = False) -> GapResults:
    """Every triplet of :func:`gap_triplets` through :func:`run_gap_triplet` with
    fresh estimators from ``make_estimators()`` (name -> estimator, the judge among
    them; ``depth_floor`` passed on), then the per-gap summaries and the coverage of
    each method with covariances.

    Raises:
        ValueError: a triplet frame the sequence lacks (before anything runs)."""
    plan = gap_triplets(seq.frame_numbers, gaps, refs)
    out = GapResults(data=data or str(getattr(seq, "name", "")), gaps=list(gaps),
                     refs=list(refs), judge=judge)
    seconds: Dict[int, Dict[str, List[float]]] = {}
    for gap, ref, numbers in plan:
        log.info("gap %d, frames %s", gap, numbers)
        triplet, records = run_gap_triplet(seq, gap, ref, make_estimators(), judge,
                                           depth_floor)
        out.triplets.append(triplet)
        out.records.extend(records)
        for m, s in triplet["comparison"]["time_s"].items():  # type: ignore[index]
            seconds.setdefault(gap, {}).setdefault(m, []).append(float(s))
    for gap in dict.fromkeys(g for g, _, _ in plan):
        out.summary[f"gap {gap}"] = summarize_views(
            [r for r in out.records if r["gap"] == gap], seconds.get(gap))
    for m in methods_with(out.records, "sigma_rot_deg"):
        out.coverage[m] = coverage_report(out.records, m, k)
    return out
