"""Where depth completion wins or loses against linear interpolation: the
absolute error of spgeo's offline completion and of linear interpolation,
stratified by how many sparse points the primitive under each pixel holds.

    python -m spgeo.evaluation.completion.strata [--datasets 7scenes tum icl]
        [--frontend classical] [--root DIR]

Same frames, sparse points and reference as :mod:`spgeo.evaluation.completion.real`
(150 FAST keypoints, reference in 0.2-5 m).  Per data set and stratum (no
primitive, 0, 1-2, 3+ points): the fraction of the reference pixels and the
mean absolute error (mm) of both methods, pooled over the frames.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_table

__all__ = ["STRATA", "strata_errors", "StrataResult", "run_strata", "build_parser", "run", "main"]

#: (label, lowest point count, highest + 1); "no primitive" is -1
STRATA = (("no primitive", -1, 0), ("0 points", 0, 1), ("1-2 points", 1, 3),
          ("3+ points", 3, 1 << 30))


def strata_errors(name: str, frontend: str = "classical", root: Optional[Path] = None,
                  frames: Optional[str] = None) -> Dict[str, Dict[str, float]]:
    """``{stratum: {"fraction", "spgeo_mm", "linear_mm"}}`` for data set ``name``
    of :data:`spgeo.evaluation.completion.real.DATASETS` (``frames``: another
    ``A:B[:S]`` selection), with the default :class:`spgeo.completion.CompletionConfig`.
    Raises ``ValueError`` for an unknown name and ``FileNotFoundError`` when the
    data set's folder is missing (:func:`~spgeo.evaluation.completion.real.open_sample`)."""
    import cv2

    from spgeo.completion import CompletionConfig, complete_depth, working_size_for
    from spgeo.frontend import FrontEndConfig, make_frontend

    from spgeo.evaluation.references.depth_completion import linear_interpolation_completion

    from .real import open_sample, sparse_frames

    ds = open_sample(name, root, frames)
    cfg = CompletionConfig()
    fe = make_frontend(frontend, FrontEndConfig(working_size=working_size_for(ds.camera,
                                                                              cfg.working_width)))
    sums = {lab: np.zeros(3) for lab, _, _ in STRATA}
    for f, gt, sparse in sparse_frames(ds, 150, 0, f"{name} strata", progress=False):
        prims = fe.primify(f.image, f.camera, f.depth if fe.uses_depth else None)
        res = complete_depth(f.image, sparse, f.camera, prims, cfg)
        lin = linear_interpolation_completion(sparse)
        P = res.primitives
        count = np.full(P.camera.width * P.camera.height, -1.0, dtype=np.float32)
        count[P.pixels] = res.n_points[P.primitive_ids]
        count = cv2.resize(count.reshape(P.camera.shape), (gt.shape[1], gt.shape[0]),
                           interpolation=cv2.INTER_NEAREST)
        ok = (gt > 0.2) & (gt < 5.0)
        for lab, lo, hi in STRATA:
            m = ok & (count >= lo) & (count < hi)
            sums[lab] += [np.abs(res.depth - gt)[m].sum(), np.abs(lin - gt)[m].sum(), m.sum()]
    total = max(sum(v[2] for v in sums.values()), 1.0)
    return {lab: {"fraction": float(v[2] / total),
                  "spgeo_mm": float(1e3 * v[0] / max(v[2], 1.0)),
                  "linear_mm": float(1e3 * v[1] / max(v[2], 1.0))} for lab, v in sums.items()}


@dataclass
class StrataResult:
    """:func:`strata_errors` of several data sets with one front-end.

    Attributes:
        frontend: the front-end name.
        rows: data-set name -> :func:`strata_errors`' dict.
    """

    frontend: str
    rows: Dict[str, Dict[str, Dict[str, float]]]

    def table(self) -> str:
        """Markdown: per data set and stratum the pixel fraction and both MAEs (mm)."""
        return "\n".join(markdown_table(
            ["data set", "stratum", "pixels", f"spgeo {self.frontend} MAE mm", "linear MAE mm"],
            [[name, lab, cell(100 * r["fraction"], "{:.0f} %"), cell(r["spgeo_mm"], 1),
              cell(r["linear_mm"], 1)] for name, rows in self.rows.items()
             for lab, r in rows.items()]))


def run_strata(datasets: Sequence[str], frontend: str = "classical",
               root: Optional[Path] = None) -> StrataResult:
    """:func:`strata_errors` of each data set; raises as it does (an unknown front-end
    name is a ``ValueError``)."""
    rows: Dict[str, Dict[str, Dict[str, float]]] = {}
    for name in datasets:
        try:
            rows[name] = strata_errors(name, frontend, root)
        except KeyError as exc:
            raise ValueError(str(exc)) from exc
    return StrataResult(frontend, rows)


NAME = "completion_strata"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, __doc__, dataset=False)
    ap.add_argument("--datasets", nargs="+", default=["7scenes", "tum", "icl"])
    ap.add_argument("--frontend", default="classical")
    ap.add_argument("--root", type=Path, default=None)
    return ap


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_strata` and print its table."""
    print(run_strata(args.datasets, args.frontend, args.root).table())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The strata table (module docstring); exit 2 for a missing data set."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
