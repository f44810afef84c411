"""Few-view SfM shape ablation on real frames: front-end (shape prior) x shape model ->
reference depth error after median scaling and rotation errors against ground truth.

    python -m spgeo.evaluation.sfm.ablation [--root DIR]
        [--frontends classical manhattan depth onnx-depth] [--depth-model NAME|PATH]
        [--shape-models scaled planar] [--out DIR] [--workers N | --address ADDR]

Cases (reference first, then two supporting views; ``--root``: the shared data,
default :func:`spgeo.evaluation.shared_data.shared_data_root`): TUM fr1_desk frames
0, 4, 8 (``tum_fr1_desk_9``), ICL-NUIM living room 1, 2, 3 (``icl_nuim_lr_5``) and
7-Scenes redkitchen 0/10/20, 100/110/120, 200/210/220 (``7scenes_redkitchen_dev``).
Front-ends: ``classical`` (fronto-parallel superpixels), ``manhattan``
(vanishing-point normals; both monocular) and ``depth`` (normals and initial
scales from the sensor depth: the oracle row) and ``onnx-depth`` (classical
segments + normals of the depth network ``--depth-model``, a registry name such as
a FastDepth file registered with ``spgeo models register NAME PATH --preset
fastdepth``, or a path; its rows are left out, and listed under
``skipped_frontends`` in the provenance, without ``--depth-model``).  Shape models: ``scaled`` (one
log-scale per primitive) and ``planar`` (3-DoF plane per primitive, initialised
from the front-end's normals).  Per case: SfM status, median relative error of the
reference depth after one median scale against the sensor depth (0.2-5 m), its
coverage, and the mean rotation error of the views (deg).  One job per (case,
front-end, shape model) (:mod:`spgeo.evaluation.jobs`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from spgeo.frontend import build_frontend
from spgeo.evaluation.jobs import (EvalTable, Job, add_runner_arguments, provenance, run_table,
                                   runner_config)
from spgeo.evaluation.metrics import depth_metrics
from spgeo.evaluation.pose_metrics import rotation_error_deg
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.shared_data import shared_data_root

__all__ = ["CASES", "sfm_case_row", "make_jobs", "build_parser", "run", "main"]

#: (case name, data-set kind, folder under the root, frame selection "A:B:S" of 3 frames)
CASES = (("tum 0-4-8", "tum", "tum_fr1_desk_9", "0:9:4"),
         ("icl 1-2-3", "icl", "icl_nuim_lr_5", "1:4:1"),
         ("7scenes 0-10-20", "7scenes", "7scenes_redkitchen_dev", "0:21:10"),
         ("7scenes 100-110-120", "7scenes", "7scenes_redkitchen_dev", "100:121:10"),
         ("7scenes 200-210-220", "7scenes", "7scenes_redkitchen_dev", "200:221:10"))
FRONTENDS = ("classical", "manhattan", "depth", "onnx-depth")
SHAPE_MODELS = ("scaled", "planar")
DEPTH_RANGE_M = (0.2, 5.0)

_COLUMNS = (("case", "case", 0), ("front-end", "frontend", 0), ("shape", "shape_model", 0),
            ("status", "status", 0), ("median rel. depth err", "median_rel", 3),
            ("coverage", "coverage", 2), ("mean rot. err deg", "rot_err_deg", 2),
            ("s", "seconds", 1), ("error", "error", 0))


def sfm_case_row(kind: str, folder: str, frames: str, frontend: str, shape_model: str,
                 working_size=(320, 240), depth_model: Optional[str] = None
                 ) -> Dict[str, object]:
    """One job: few-view SfM on the three frames of ``folder`` (reference first);
    ``depth_model`` is the ``onnx-depth`` front-end's depth network
    (:func:`spgeo.frontend.build_frontend`)."""
    import time

    from spgeo.datasets import open_dataset
    from spgeo.frame import Frame, resize_frame
    from spgeo.frontend import build_frontend
    from spgeo.geometry import relative_pose
    from spgeo.sfm import SfMConfig, few_view_sfm

    seq = open_dataset(kind, folder, frames=frames)
    fr = [seq[i] for i in range(len(seq))]
    if len(fr) != 3:
        raise ValueError(f"{folder} {frames}: expected 3 frames, got {len(fr)}")
    ref, views = fr[0], fr[1:]
    fe = build_frontend(frontend, working_size, depth_model=depth_model)
    t0 = time.perf_counter()
    res = few_view_sfm(ref.image, [v.image for v in views], ref.camera, fe,
                       SfMConfig(marginals=False, shape_model=shape_model),
                       ref_depth=ref.depth if fe.uses_depth else None)
    secs = time.perf_counter() - t0
    gt = resize_frame(Frame(ref.image, ref.camera, 0.0, depth=ref.depth), res.camera.size,
                      keep_depth=True).depth
    lo, hi = DEPTH_RANGE_M
    ok = np.isfinite(res.depth) & np.isfinite(gt) & (gt > lo) & (gt < hi)
    row: Dict[str, object] = {"status": res.status, "seconds": secs}
    if ok.any():
        k = float(np.median(gt[ok] / res.depth[ok]))
        m = depth_metrics(res.depth * k, gt, min_depth=lo, max_depth=hi)
        row.update(median_rel=m["median_rel"], coverage=m["coverage"])
    gt_rel = [relative_pose(ref.T_world_cam, v.T_world_cam) for v in views]
    row["rot_err_deg"] = float(np.mean([rotation_error_deg(a[:3, :3], b[:3, :3])
                                        for a, b in zip(res.T_ref_view, gt_rel)]))
    return row


def make_jobs(root: Path, frontends: Sequence[str], shape_models: Sequence[str],
              depth_model: Optional[str] = None) -> List[Job]:
    """One job per (case, front-end, shape model); cases whose folder is missing are
    left out (their names are returned in the provenance by :func:`main`), and so
    are the ``onnx-depth`` rows without a ``depth_model`` (registry name or path of
    its depth network, passed to those rows only)."""
    frontends = [fe for fe in frontends if fe != "onnx-depth" or depth_model]
    return [Job(f"{name}/{fe}/{sm}", sfm_case_row, (kind, str(root / sub), frames, fe, sm),
                {"depth_model": depth_model} if fe == "onnx-depth" else {},
                meta={"case": name, "frontend": fe, "shape_model": sm})
            for name, kind, sub, frames in CASES if (root / sub).is_dir()
            for fe in frontends for sm in shape_models]


NAME = "sfm_ablation"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, __doc__, dataset=False)
    ap.add_argument("--root", default=None, help="shared data folder (default: "
                    "$SPGEO_SHARED_DATA or ../shared/data)")
    ap.add_argument("--frontends", nargs="+", default=list(FRONTENDS), choices=FRONTENDS)
    ap.add_argument("--depth-model", default=None, metavar="NAME|PATH",
                    help="the onnx-depth rows' depth network (without it those rows are "
                         "left out)")
    ap.add_argument("--shape-models", nargs="+", default=list(SHAPE_MODELS),
                    choices=SHAPE_MODELS)
    ap.add_argument("--out", default=None, help="write sfm_ablation.md/.json/.csv here")
    add_runner_arguments(ap)
    return ap


def run(args: argparse.Namespace) -> int:
    """Run the jobs of :func:`make_jobs`, print the table, write ``--out``; 1 when a
    job failed, 2 when no case is found (a bad ``--workers`` or depth model exits
    with the usage message, code 2)."""
    root = Path(args.root) if args.root else shared_data_root()
    try:
        runner = runner_config(args, desc="sfm_ablation")
    except ValueError as exc:
        build_parser().error(str(exc))
    if args.depth_model and "onnx-depth" in args.frontends:
        try:    # a missing or misfit model: one error line, not one error row per job
            build_frontend("onnx-depth", depth_model=args.depth_model)
        except (ValueError, FileNotFoundError) as exc:
            build_parser().error(str(exc))
    jobs = make_jobs(root, args.frontends, args.shape_models, args.depth_model)
    if not jobs:
        print(f"sfm_ablation: no case found under {root}", file=sys.stderr)
        return 2
    missing = [name for name, _, sub, _ in CASES if not (root / sub).is_dir()]
    skipped = ["onnx-depth"] if "onnx-depth" in args.frontends and not args.depth_model else []
    prov = provenance({"root": str(root), "missing_cases": missing, "frontends": args.frontends,
                       "skipped_frontends": skipped, "depth_model": args.depth_model,
                       "shape_models": args.shape_models}, runner)

    def table(rows):
        return EvalTable(rows, _COLUMNS, group_by=("frontend", "shape_model"), provenance=prov,
                         note="median rel. depth err: |k d - d_gt| / d_gt after one median scale "
                              "k, sensor depth in 0.2-5 m; rotation error: mean over the views")

    result = run_table(jobs, runner, table, Path(args.out) if args.out else None,
                       stem="sfm_ablation")
    print(result.markdown())
    return 1 if result.failed else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The shape ablation (module docstring): print the table, write ``--out``."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
