"""Few-view SfM on real sample frames: spgeo vs COLMAP (pycolmap) vs SIFT two-view,
relative rotation / translation-direction errors against ground truth.

    python -m spgeo.evaluation.sfm.real [--shared ../shared/data] [--json OUT]

Cases (reference first): TUM fr1_desk frames 0, 4, 8 (the bundled 9-frame
sample; ``../shared/data/tum_fr1_desk_9`` is the same data) and ICL-NUIM living
room frames 1, 2, 3 of ``icl_nuim_lr_5`` (when the shared data is present).
The regression test ``tests/test_sfm_real.py`` asserts the spgeo numbers stay
below bounds set from this script's output.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Callable, Dict, Optional, Sequence

from spgeo.datasets import load_bundled_tum, open_dataset
from spgeo.evaluation.references.colmap import colmap_estimator
from spgeo.evaluation.pose_compare import compare_on_dataset
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.shared_data import shared_data_root
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.sfm import SfMConfig, few_view_sfm

__all__ = ["CASES", "spgeo_estimator", "twoview_estimator", "run_case", "build_parser", "run",
           "main"]

log = logging.getLogger(__name__)

CASES = {
    "tum_fr1_desk_0_4_8": ("tum", "tum_fr1_desk_9", [0, 4, 8]),
    "icl_lr_1_2_3": ("icl", "icl_nuim_lr_5", [1, 2, 3]),
}


def spgeo_estimator(frontend: str = "classical", config: SfMConfig = SfMConfig(marginals=False)
                    ) -> Callable:
    """An estimator for :func:`spgeo.evaluation.pose_compare.compare_on_dataset`."""

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
        lines.append(f"  {method:30s} " + "   ".join(cells) + f"   ({comp['time_s'][method]:.1f} s)")
    return "\n".join(lines)


NAME = "sfm_real"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, __doc__, dataset=False)
    ap.add_argument("--shared", default=str(shared_data_root()),
                    help="folder with tum_fr1_desk_9/ and icl_nuim_lr_5/ (default ../shared/data)")
    ap.add_argument("--json", default=None, help="write all results as JSON here")
    return ap


def run(args: argparse.Namespace) -> int:
    """Each case of :data:`CASES` (the TUM one from the bundled sample when the shared
    folder lacks it): print its table; write ``--json``."""
    shared = Path(args.shared)
    out = {}
    for name, (kind, sub, _) in CASES.items():
        use = shared if (shared / sub).is_dir() else None
        if use is None and kind != "tum":
            print(f"{name}: skipped ({shared / sub} not found)")
            continue
        comp = run_case(name, use)
        out[name] = comp
        print(_table(name, comp))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2, default=str))
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Few-view SfM on the real sample frames: print the tables (module docstring)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
