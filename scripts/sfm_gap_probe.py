"""Few-view SfM at growing baselines on the shared 7-Scenes clip (issue 40's starting point).

Triplets (ref, ref + G, ref + 2G) of ``../shared/data/7scenes_redkitchen_dev`` for gaps
G = 10, 30, 60 frames and refs 0, 60, 120; per triplet spgeo (classical front-end, the
default ``SfMConfig``), COLMAP on the same three views (pycolmap) and the OpenCV SIFT +
essential-matrix pair, each view's rotation / translation-direction error against the
ground truth (:func:`spgeo.evaluation.pose_compare.compare_on_dataset`); printed as the
median over the six views of a gap (NaN errors, e.g. a zero translation, left out),
unposed views counted.

Run::

    python scripts/sfm_gap_probe.py [--shared ../shared/data] [--gaps 10,30,60]
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from spgeo.datasets import open_dataset
from spgeo.evaluation.pose_compare import compare_on_dataset
from spgeo.evaluation.references.colmap import colmap_estimator
from spgeo.evaluation.sfm.real import spgeo_estimator, twoview_estimator

REFS = (0, 60, 120)


def gap_rows(seq, gap: int) -> dict:
    """method -> list of (rotation error deg, translation-direction error deg) or None
    (unposed) over the views of the triplets of ``gap``."""
    index = {int(n): i for i, n in enumerate(seq.frame_numbers)}
    out: dict = {}
    for ref in REFS:
        frames = [seq[index[ref + k * gap]] for k in (0, 1, 2)]
        comp = compare_on_dataset(frames, {"spgeo classical": spgeo_estimator("classical"),
                                           "colmap": colmap_estimator(),
                                           "sift two-view": twoview_estimator()})
        for method, res in comp["vs_gt"].items():
            for r in res["rows"]:
                out.setdefault(method, []).append(
                    (r["rotation_error_deg"], r["translation_direction_error_deg"])
                    if r.get("available") else None)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shared", default="../shared/data")
    ap.add_argument("--gaps", default="10,30,60")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    seq = open_dataset("7scenes", Path(args.shared) / "7scenes_redkitchen_dev")
    print("| gap | method | median rotation error deg | median translation-direction error deg "
          "| views posed |")
    print("|---|---|---:|---:|---:|")
    for gap in (int(g) for g in args.gaps.split(",")):
        for method, rows in gap_rows(seq, gap).items():
            ok = np.array([r for r in rows if r is not None]).reshape(-1, 2)
            med = np.nanmedian(ok, 0) if ok.size else (np.nan, np.nan)
            print(f"| {gap} | {method} | {med[0]:.2f} | {med[1]:.1f} | {len(ok)} of {len(rows)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
