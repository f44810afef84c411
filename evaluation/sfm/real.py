"""Few-view SfM on real sample frames: spgeo vs COLMAP (pycolmap) vs SIFT two-view,
relative rotation / translation-direction errors against ground truth and COLMAP.

    spgeo eval sfm_real [--shared ../shared/data] [--cases tum,icl,gaps,synthetic]
                        [--gaps 10,30,60] [--refs 0,60,120] [--clip-reference TRAJ]
                        [--angles 5,20,45] [--seeds 0,1,2,3,4,5] [--json OUT]

Cases (reference first; ``--cases`` picks them by kind or name): ``tum``: TUM fr1_desk
frames 0, 4, 8 (the bundled 9-frame sample; ``../shared/data/tum_fr1_desk_9`` is the
same data); ``icl``: ICL-NUIM living room frames 1, 2, 3 of ``icl_nuim_lr_5`` (when the
shared data is present); ``gaps``: triplets (ref, ref + G, ref + 2G) of the shared
7-Scenes clip ``7scenes_redkitchen_dev`` for each gap G of ``--gaps`` ("" or "none":
none) and ref of ``--refs``, spgeo / COLMAP / SIFT two-view judged against COLMAP's
pose of each view beside the ground truth, with spgeo's rotation-covariance coverage
(:mod:`.gaps`; ``--clip-reference``: COLMAP on the whole clip judges instead);
``synthetic``: synthetic rooms with views ``--angles`` degrees from the reference, one
per seed of ``--seeds``, against the exact ground truth (:mod:`.baselines`).  Every case
also scores spgeo's reference depth against the reference frame's depth (issue 54; one
median scale per depth map, clipped to 0.1-10, AbsRel and delta < 1.25,
:mod:`spgeo.evaluation.depth_eval`; synthetic: exact depth) with a floor row
(``sensor-depth primitives (floor)``: the depth front-end's primitives with their scales
fitted to the sensor depth, no SfM, :func:`spgeo.evaluation.dense_depth.sensor_depth_floor`);
the gap cases add spgeo's SfM with the depth front-end's shapes (``spgeo depth shapes``;
its scales are the views', as those of ``spgeo depth-normals (oracle)`` in the TUM and
ICL cases).  One
``SfMConfig`` throughout: the default (marginals on, so pose
covariances exist); the gap cases use the classical front-end.  The regression tests
``tests/test_sfm_real.py`` and ``tests/test_sfm_gaps.py`` assert numbers from this
protocol's output.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

from spgeo.datasets import load_bundled_tum, open_dataset
from spgeo.evaluation.dense_depth import sensor_depth_floor
from spgeo.evaluation.depth_eval import sfm_reference_depth
from spgeo.evaluation.references.colmap import colmap_estimator
from spgeo.evaluation.pose_compare import compare_on_dataset
from spgeo.evaluation.runner import protocol_parser, run_protocol, write_json
from spgeo.evaluation.shared_data import shared_data_root
from spgeo.evaluation.sfm.baselines import ANGLES, run_baselines
from spgeo.evaluation.sfm.gaps import (DEPTH_FLOOR, GAP_DATA, GapResults, clip_estimator,
                                       parse_int_list, run_gaps)
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.sfm import SfMConfig, few_view_sfm
from spgeo.trajectory import Trajectory

__all__ = ["CASES", "CASE_KINDS", "DEPTH_SHAPES", "spgeo_estimator", "twoview_estimator", "gap_estimators",
           "run_case", "run_gap_cases", "parse_cases", "build_parser", "run", "main"]

log = logging.getLogger(__name__)

CASES = {
    "tum_fr1_desk_0_4_8": ("tum", "tum_fr1_desk_9", [0, 4, 8]),
    "icl_lr_1_2_3": ("icl", "icl_nuim_lr_5", [1, 2, 3]),
}
#: the judge's name with ``--clip-reference``
CLIP_JUDGE = "colmap clip"
#: what ``--cases`` may name (besides the names of :data:`CASES`)
CASE_KINDS = ("tum", "icl", "gaps", "synthetic")


def spgeo_estimator(frontend: str = "classical", config: Optional[SfMConfig] = None
                    ) -> Callable:
    """An estimator for :func:`spgeo.evaluation.pose_compare.compare_on_dataset`:
    :func:`few_view_sfm` with ``frontend`` at 320x240 and ``config`` (None: the
    default ``SfMConfig()``, marginals on); the last :class:`SfMResult` is the
    callable's ``last_result``."""
    config = SfMConfig() if config is None else config

    def estimate(ref, views):
        fe = make_frontend(frontend, FrontEndConfig(working_size=(320, 240)))
        res = few_view_sfm(ref.image, [v.image for v in views], ref.camera, fe, config,
                           ref_depth=ref.depth if fe.uses_depth else None)
        estimate.last_result = res  # type: ignore[attr-defined]
        return res.T_ref_view

    estimate.last_result = None  # type: ignore[attr-defined]
    return estimate


def twoview_estimator() -> Callable:
    """OpenCV SIFT + essential matrix per view (unit translations)."""
    from spgeo.twoview import estimate_relative_pose

    def estimate(ref, views):
        return [estimate_relative_pose(ref.image, v.image, ref.camera).T_ref_tgt for v in views]

    return estimate


#: the gap cases' SfM with the sensor-depth front-end's shapes (normals from the
#: reference's depth; the scales are the views', ``SfMConfig.reset_scales``)
DEPTH_SHAPES = "spgeo depth shapes"


def gap_estimators(inits: Sequence[str] = ("features",), depth_shapes: bool = False
                   ) -> Dict[str, Callable]:
    """Fresh estimators of the gap and synthetic cases: ``"spgeo"`` (:func:`spgeo_estimator`,
    classical, ``SfMConfig(init=inits[0])``), ``"spgeo init=I"`` for each further start
    ``I`` of ``inits`` (to compare starts in one run), with ``depth_shapes``
    :data:`DEPTH_SHAPES` (the ``depth`` front-end: its shapes from the reference's sensor
    depth, its scales from the views), ``"colmap"`` (the judge) and ``"sift two-view"``."""
    out = {"spgeo" if k == 0 else f"spgeo init={init}":
           spgeo_estimator("classical", SfMConfig(init=init)) for k, init in enumerate(inits)}
    if depth_shapes:
        out[DEPTH_SHAPES] = spgeo_estimator("depth", SfMConfig(init=inits[0]))
    out.update({"colmap": colmap_estimator(), "sift two-view": twoview_estimator()})
    return out


def _frames(kind: str, folder: Optional[Path], numbers: Sequence[int]):
    if kind == "tum" and folder is None:
        seq = load_bundled_tum()
        return [seq[i] for i in numbers]
    seq = open_dataset(kind, folder)
    index = {int(n): i for i, n in enumerate(seq.frame_numbers)}
    return [seq[index[n]] for n in numbers]


def run_case(name: str, shared: Optional[Path] = None,
             estimators: Optional[Dict[str, Callable]] = None) -> dict:
    """Run one case of :data:`CASES`; returns :func:`compare_on_dataset`'s dict."""
    kind, sub, numbers = CASES[name]
    folder = None if shared is None else Path(shared) / sub
    if folder is not None and not folder.is_dir():
        raise FileNotFoundError(f"data for case {name!r} not found: {folder}")
    frames = _frames(kind, folder, numbers)
    if estimators is None:
        estimators = {"spgeo classical": spgeo_estimator("classical"),
                      "spgeo depth-normals (oracle)": spgeo_estimator("depth"),
                      "colmap": colmap_estimator(),
                      "sift two-view": twoview_estimator()}
    comp = compare_on_dataset(frames, estimators)
    comp["view_status"] = {name: list(getattr(fn, "last_result").view_status)
                           for name, fn in estimators.items()
                           if getattr(fn, "last_result", None) is not None
                           and hasattr(fn.last_result, "view_status")}
    if getattr(frames[0], "depth", None) is not None:
        comp["depth"] = {name: sfm_reference_depth(fn.last_result, frames[0].depth)
                         for name, fn in estimators.items()
                         if getattr(getattr(fn, "last_result", None), "depth", None) is not None}
        comp["depth"][DEPTH_FLOOR] = sensor_depth_floor(frames[0])
    return comp


def _table(name: str, comp: dict) -> str:
    lines = [f"{name}: rotation error / translation-direction error vs ground truth (deg)"
             " [spgeo's status of each view]"]
    for method, res in comp["vs_gt"].items():
        cells = []
        status = comp.get("view_status", {}).get(method)
        for j, r in enumerate(res["rows"]):
            if not r.get("available"):
                cells.append("   unposed   ")
            else:
                cells.append(f"{r['rotation_error_deg']:5.2f} / "
                             f"{r['translation_direction_error_deg']:5.1f}"
                             + (f" [{status[j]}]" if status else ""))
        lines.append(f"  {method:30s} " + "   ".join(cells)
                     + f"   ({comp['time_s'][method]:.1f} s)")
    for method, m in comp.get("depth", {}).items():
        lines.append(f"  {method:30s} reference depth: AbsRel {m['abs_rel']:.3f}, "
                     f"d<1.25 {m['delta_1.25']:.3f}, coverage {m['coverage']:.2f} "
                     "(one median scale, clipped to 0.1-10 m)")
    return "\n".join(lines)


def parse_cases(text: str) -> List[str]:
    """``--cases``: comma-separated kinds (``tum``, ``icl``, ``gaps``, ``synthetic``) or
    names of :data:`CASES` -> the names of :data:`CASES` to run, in their order, then
    ``"gaps"`` and ``"synthetic"`` when chosen.  ``""`` / ``"all"``: everything.

    Raises:
        ValueError: an unknown kind or name (the message lists the known ones)."""
    parts = [p.strip() for p in (text or "").split(",") if p.strip()]
    if not parts or parts == ["all"]:
        parts = list(CASE_KINDS)
    known = set(CASE_KINDS) | set(CASES)
    bad = [p for p in parts if p not in known]
    if bad:
        raise ValueError(f"--cases: unknown {bad}; choose from {sorted(known)}")
    chosen = [name for name, (kind, _, _) in CASES.items() if name in parts or kind in parts]
    return chosen + [k for k in ("gaps", "synthetic") if k in parts]


def run_gap_cases(shared: Path, gaps: Sequence[int], refs: Sequence[int],
                  make_estimators: Callable[[], Dict[str, Callable]] = gap_estimators,
                  clip_reference: Optional[Path] = None,
                  depth_floor: bool = False) -> GapResults:
    """The gap cases (:func:`spgeo.evaluation.sfm.gaps.run_gaps`) on
    ``shared / GAP_DATA`` with ``make_estimators`` (default :func:`gap_estimators`).
    With ``clip_reference`` (a TUM trajectory of the whole clip with its status file,
    e.g. ``spgeo eval colmap_vo --out DIR``'s ``trajectory.txt``) its poses,
    ``"colmap clip"`` (:func:`~spgeo.evaluation.sfm.gaps.clip_estimator`), judge
    instead of COLMAP on the three views.  ``depth_floor``: the depth table's floor row
    (:func:`~spgeo.evaluation.sfm.gaps.run_gaps`).

    Raises:
        FileNotFoundError: no such folder or file; ValueError: a triplet frame the clip
        lacks, or a malformed trajectory file."""
    folder = Path(shared) / GAP_DATA
    if not folder.is_dir():
        raise FileNotFoundError(f"data of the gap cases not found: {folder}")
    seq = open_dataset("7scenes", folder)
    if clip_reference is None:
        return run_gaps(seq, gaps, refs, make_estimators, data=GAP_DATA, depth_floor=depth_floor)
    traj = Trajectory.load(clip_reference)

    def with_clip() -> Dict[str, Callable]:
        return {**make_estimators(), CLIP_JUDGE: clip_estimator(traj)}

    return run_gaps(seq, gaps, refs, with_clip, data=GAP_DATA, judge=CLIP_JUDGE,
                    depth_floor=depth_floor)


NAME = "sfm_real"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, __doc__, dataset=False)
    ap.add_argument("--shared", default=str(shared_data_root()),
                    help="folder with tum_fr1_desk_9/, icl_nuim_lr_5/ and "
                         f"{GAP_DATA}/ (default ../shared/data)")
    ap.add_argument("--cases", default=",".join(CASE_KINDS),
                    help="comma-separated kinds (tum, icl, gaps, synthetic) or case names to run "
                         "(default all)")
    ap.add_argument("--gaps", default="10,30,60",
                    help="frame gaps G of the gap cases' triplets (ref, ref+G, ref+2G); "
                         "'' or 'none': no gap cases (default 10,30,60)")
    ap.add_argument("--refs", default="0,60,120",
                    help="reference frame numbers of the gap cases (default 0,60,120)")
    ap.add_argument("--clip-reference", default=None,
                    help="TUM trajectory of the whole clip (with its .status.txt), e.g. "
                         "'spgeo eval colmap_vo --out DIR''s trajectory.txt: it judges the gap "
                         "cases instead of COLMAP on the three views")
    ap.add_argument("--angles", default=",".join(str(a) for a in ANGLES),
                    help="synthetic cases: degrees between the views and the reference "
                         "(default 5,20,45)")
    ap.add_argument("--seeds", default="0,1,2,3,4,5",
                    help="synthetic cases: the rooms' seeds (default 0-5)")
    ap.add_argument("--inits", default="features",
                    help="gap and synthetic cases: spgeo's starts (SfMConfig.init), the first "
                         "as 'spgeo', the others beside it (default features)")
    ap.add_argument("--json", default=None, help="write all results as JSON here (atomically)")
    return ap


def run(args: argparse.Namespace) -> int:
    """The chosen cases (:func:`parse_cases`; the TUM one from the bundled sample when
    the shared folder lacks it; the others skipped with a line when their data is
    missing): print each table; write ``--json`` (case name -> comparison dict, and
    ``"gaps"`` / ``"synthetic"`` -> :meth:`GapResults.to_dict`).  Bad ``--cases`` /
    ``--gaps`` / ``--refs`` / ``--angles`` / ``--seeds`` raise ``ValueError`` before
    anything runs."""
    shared = Path(args.shared)
    cases = parse_cases(args.cases)
    gaps = parse_int_list(args.gaps, "--gaps", minimum=1)
    refs = parse_int_list(args.refs, "--refs", minimum=0)
    angles = parse_int_list(args.angles, "--angles", minimum=1)
    seeds = parse_int_list(args.seeds, "--seeds", minimum=0)
    inits = [i.strip() for i in args.inits.split(",") if i.strip()]
    for init in inits:
        SfMConfig(init=init)       # ValueError naming the value before anything runs
    out: Dict[str, object] = {}
    for name in (c for c in cases if c in CASES):
        kind, sub, _ = CASES[name]
        use = shared if (shared / sub).is_dir() else None
        if use is None and kind != "tum":
            print(f"{name}: skipped ({shared / sub} not found)")
            continue
        comp = run_case(name, use)
        out[name] = comp
        print(_table(name, comp))
    if "gaps" in cases:
        if not gaps or not refs:
            print("gaps: skipped (no gaps or no refs given)")
        elif not (shared / GAP_DATA).is_dir():
            print(f"gaps: skipped ({shared / GAP_DATA} not found)")
        else:
            res = run_gap_cases(shared, gaps, refs,
                                lambda: gap_estimators(inits, depth_shapes=True),
                                args.clip_reference, depth_floor=True)
            out["gaps"] = res.to_dict()
            print(res.table())
    if "synthetic" in cases and angles and seeds:
        res = run_baselines(angles, seeds, lambda: gap_estimators(inits))
        out["synthetic"] = res.to_dict()
        print(res.table())
    if args.json:
        write_json(args.json, out)
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Few-view SfM on the real sample frames: print the tables (module docstring)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
