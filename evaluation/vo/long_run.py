"""Long-run VO benchmark: ATE, loop closures, scale drift, end-pose error, FPS, peak RSS.

One fresh process per (sequence, variant) run.

    spgeo eval vo_long_run --out DIR [--sequences 7scenes,7scenes-palindrome,7scenes-foreign,
                                             kitti,synthetic-loop,road-straight,road-block]
        [--variants default,loops] [--frames N] [--timeout SECONDS] [--reference colmap]

Sequences (:data:`SEQUENCES`; all with ground truth, timestamps = position in
the run):

* ``7scenes``: the first :data:`SEVENSCENES_FRAMES` frames of the shared
  7-Scenes redkitchen sample (:func:`spgeo.evaluation.shared_data.shared_data_root`);
* ``7scenes-palindrome``: the same frames played forward, then back to the
  first (:func:`spgeo.evaluation.vo.memory.palindrome`): real images with an
  exact revisit, the last frame's true pose is the first's;
* ``7scenes-foreign``: the first 120 of those frames with frames 50-61 replaced
  by 12 images of other rooms (the shared TUM fr1_desk frames, then ICL-NUIM's;
  :data:`~spgeo.evaluation.vo.long_run_sequences.FOREIGN_SPAN`): a hand over the
  lens, someone walking past; the camera is back where it was when they end
  (issue 51).  The foreign frames have no ground truth;
* ``kitti``: the shared KITTI odometry clip (grey left camera, intrinsics from
  P0 of ``calib.txt``, ground truth ``poses.txt``), read by the ``folder``
  reader with that camera, no temporary folder;
* ``synthetic-loop``: a synthetic palindrome (as ``scripts/loop_synthetic_experiment.py``):
  subsampled poses of :func:`spgeo.synthetic.make_trajectory` rendered at the
  size of :data:`SYNTHETIC_LOOP`, played forward and back to the first pose,
  with the keyframe spacing of that experiment (``odometry.keyframe.max_translation``,
  scene units);
* ``road-straight``, ``road-block``: the synthetic roads of :mod:`spgeo.synthetic.road`
  (500 frames, 600 m straight ahead at 1.2 m per frame; 725 frames round a block, a stop
  and four corners, back to the start) at 504x153, 8-bit grey as KITTI's images.

``--frames N`` caps each sequence at ``N`` frames; a palindrome is then made of
its first half (rounded up), so it still returns to its start.

Variants (:data:`VARIANTS`): name -> :class:`spgeo.apps.vo_run.VORunConfig`
overrides (dotted field names, :func:`spgeo.configs.apply_overrides`) applied
after the sequence's own; ``default`` (none), ``loops``
(``odometry.loop_closure.enabled``) and ``no-landmarks``
(``odometry.landmarks.enabled=False``: the window-only map) and
``no-landmarks+loops`` (the window-only map with loop closure: where nothing else
remembers the start, so loops are sought), ``inline`` (the back end between two
frames instead of the live mapping worker) and ``no-feature-check``
(``odometry.feature_retry.min_agreement=None``: a pose refused for its photometric
cost is never kept at its own pose; since issue 51 the PnP pose is kept instead) and
``sensor-depth`` (``frontend=depth``: the sensor-depth front-end, the floor of the depth
columns; run only on the sequences with depth: ``7scenes``, ``7scenes-palindrome``,
``synthetic-loop``).  Adding a variant is one entry there.

Each (sequence, variant) runs in a fresh ``python -m`` process, one after
the other, with one BLAS / OpenMP thread, through
:func:`spgeo.apps.vo_run.run_odometry` (classical front-end unless a variant
says otherwise); the run is saved in ``DIR/<sequence>.<variant>/``
(:meth:`spgeo.apps.vo_run.VORun.save`: ``report.json``, trajectory, clouds,
plots) with the process's output in ``log.txt`` and its row in ``row.json``.
Columns: frames run, tracked (not ``lost``), lost, relocalised (status ``relocalised``:
tracked again after a loss or against an older keyframe), map segments, skipped (unreadable),
keyframes, per-frame and keyframe-only Sim(3) ATE RMSE (metres of the ground
truth; synthetic: scene units), loop closures accepted / rejected
(``report.json`` ``loop_closures``; ``-`` when loop closure is off), scale
drift (:mod:`spgeo.evaluation.vo.scale_drift`: the last keyframe's median
sensor-depth / keyframe-depth ratio over the first keyframe's, or without
sensor depth the ratio of ground-truth to estimated keyframe baselines, last
over first; one means no drift), keyframe depth (issue 54; on the sequences with depth:
each keyframe's primitive depth map at the processing size against its frame's sensor
depth resized with nearest neighbours, one median scale per keyframe, clipped to 0.1-10,
AbsRel and delta < 1.25 averaged over the keyframes, :mod:`spgeo.evaluation.depth_eval`),
end-pose error (the estimated relative pose
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
in ``DIR/colmap/<data>-<frames>/`` (``trajectory.txt`` + status, ``gt.npy``,
``reference.json``) and reused on a rerun; a palindrome takes the poses of its
frames.  Every run's row gains, against COLMAP, the relative rotation error over
30 frames, the orientation after the best constant rotation (median / max) and
the Sim(3) scale onto COLMAP over 50-frame windows (min / max, relative to the
whole run's), and against the ground truth its relative rotation error over 30
frames (:mod:`spgeo.evaluation.vo.reference_metrics`); one ``colmap`` row per
sequence gives COLMAP's own ATE and rotation error against the ground truth.

This module is the command line; the parts, whose names it re-exports, are
:mod:`~spgeo.evaluation.vo.long_run_sequences` (sequences, variants, a run's
configuration), :mod:`~spgeo.evaluation.vo.long_run_runner` (one run, in this process
or a fresh one, and its row), :mod:`~spgeo.evaluation.vo.long_run_reference` (the
COLMAP reference) and :mod:`~spgeo.evaluation.vo.long_run_table` (the table and files).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from spgeo.evaluation.jobs import RunnerConfig, provenance, run_jobs
from spgeo.evaluation.runner import protocol_argv, protocol_parser, run_protocol
from spgeo.evaluation.vo.long_run_reference import (REFERENCES, ColmapReference,
                                                    colmap_reference, colmap_references,
                                                    colmap_row, loop_edges, reference_columns,
                                                    with_reference)
from spgeo.evaluation.vo.long_run_runner import (child_main, end_pose_error, make_jobs,
                                                 run_metrics, run_one, run_subprocess,
                                                 scale_drift)
from spgeo.evaluation.vo.long_run_sequences import (SEQUENCES, SEVENSCENES_FRAMES,
                                                    SYNTHETIC_LOOP, VARIANTS, LongRunSequence,
                                                    Reordered, run_config)
from spgeo.evaluation.vo.long_run_sequences import _order  # noqa: F401  (tests use long_run._order)
from spgeo.evaluation.vo.long_run_table import REFERENCE_TABLE, TABLE, markdown, write_outputs

__all__ = ["LongRunSequence", "SEQUENCES", "VARIANTS", "TABLE", "Reordered", "run_config",
           "run_one", "run_metrics", "end_pose_error", "scale_drift", "run_subprocess",
           "make_jobs", "markdown", "write_outputs", "build_parser", "run", "main",
           "REFERENCES", "REFERENCE_TABLE", "ColmapReference", "colmap_reference",
           "reference_columns", "loop_edges", "with_reference", "colmap_row", "colmap_references"]


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
        return child_main(*argv[1:5])
    parser = build_parser()
    parser.set_defaults(argv_protocol=argv)     # recorded in the provenance
    return run_protocol(parser, run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
