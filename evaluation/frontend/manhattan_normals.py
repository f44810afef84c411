"""Vanishing-point (Manhattan) normals vs reference normals: angular error and coverage.

* synthetic: :mod:`spgeo.synthetic` rooms, reference = rendered normals,
  errors per surface type (room planes / box faces / other);
* real: TUM fr1_desk (9 frames), ICL-NUIM (5), 7-Scenes redkitchen (every
  ``--step``-th of 300), reference = :class:`DepthNormalEstimator` normals of
  the ground-truth depth (oracle).

Per data set: coverage (fraction of pixels with a known VP normal), the median
angular error on covered pixels that have a reference normal, and the
fronto-parallel normal's median error on the same pixels.  Normals are
per region of the classical segmentation (``ManhattanNormals`` with a
``SharedSegmenter``), at ``--width`` x 3/4 width.  Also the run time of the
VP normals relative to ``ClassicalSegmenter().segment`` on the same images.

    python -m spgeo.evaluation.frontend.manhattan_normals [--step 30] [--width 320]
"""
from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from spgeo.frontend.classical import ClassicalSegmenter
from spgeo.frontend.depth_normals import DepthNormalEstimator
from spgeo.frontend.manhattan import ManhattanNormals

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_row, markdown_table

log = logging.getLogger(__name__)

_FRONTO = np.array([0.0, 0.0, -1.0])


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


#: The columns of the table (:meth:`ManhattanNormalsResult.table`).
_HEADER = ("data", "coverage [%]", "median err VP [deg]",
           "median err fronto-parallel, same pixels [deg]", "VP err < 15 deg [%]")


class _Acc:
    """Pooled pixel errors of one data set (or surface type)."""

    def __init__(self) -> None:
        self.err: List[np.ndarray] = []
        self.fp: List[np.ndarray] = []
        self.covered = 0
        self.total = 0

    def add(self, normals, known, ref, select=None) -> None:
        ok = np.isfinite(ref).all(axis=-1)
        if select is not None:
            ok &= select
        self.total += int(ok.sum())
        use = ok & known
        self.covered += int(use.sum())
        self.err.append(_angles(normals[use], ref[use]))
        self.fp.append(_angles(np.broadcast_to(_FRONTO, ref[use].shape), ref[use]))

    def row(self, name: str) -> str:
        """The Markdown row of :data:`_HEADER` (``-`` without pixels)."""
        e = np.concatenate(self.err) if self.err else np.zeros(0)
        f = np.concatenate(self.fp) if self.fp else np.zeros(0)
        cov = self.covered / max(self.total, 1)
        return markdown_row([name, cell(100 * cov, 1), cell(np.median(e) if e.size else None, 1),
                             cell(np.median(f) if f.size else None, 1),
                             cell(100 * np.mean(e < 15) if e.size else None, 0)])


def _real_frames(step: int, root: Optional[Path] = None):
    from spgeo.datasets import open_dataset

    from spgeo.evaluation.shared_data import shared_data_root

    root = shared_data_root() if root is None else Path(root)
    sets = [("TUM fr1_desk", "tum", root / "tum_fr1_desk_9", None),
            ("ICL-NUIM", "icl", root / "icl_nuim_lr_5", None),
            ("7-Scenes", "7scenes", root / "7scenes_redkitchen_dev", f"0:300:{step}")]
    for name, kind, path, frames in sets:
        if not path.is_dir():
            log.warning("%s: %s not found, skipped", name, path)
            continue
        ds = open_dataset(kind, path, **({"frames": frames} if frames else {}))
        yield name, [ds[i] for i in range(len(ds))]


@dataclass
class ManhattanNormalsResult:
    """Output of :func:`evaluate`.

    Attributes:
        rows: Markdown table rows, one per data set (or synthetic surface type).
        ratio: median time of the VP normals / median time of
            ``ClassicalSegmenter().segment`` on the same images.
        ms_manhattan, ms_segment: those median times in milliseconds.
    """

    rows: List[str]
    ratio: float
    ms_manhattan: float
    ms_segment: float

    def table(self) -> str:
        """The Markdown table and the timing line."""
        return "\n".join(markdown_table(_HEADER, [], "lrrrr") + [
            "\n".join(self.rows),
            f"time: VP normals {self.ms_manhattan:.1f} ms = {self.ratio:.2f} x "
            f"ClassicalSegmenter.segment ({self.ms_segment:.1f} ms), median per image"])


def evaluate(step: int = 30, width: int = 320, synthetic_seeds: Sequence[int] = (0, 1, 2),
             root: Optional[Path] = None) -> ManhattanNormalsResult:
    """Run the evaluation; returns the table rows and the timing ratio."""
    from spgeo.frame import resize_frame
    from spgeo.frontend.manhattan import SharedSegmenter
    from spgeo.images import to_float_image

    height = width * 3 // 4
    segmenter = ClassicalSegmenter()
    mh = ManhattanNormals(segmenter=SharedSegmenter(segmenter))
    oracle = DepthNormalEstimator()
    rows: List[str] = []
    t_seg, t_mh = [], []

    def run(image, cam):
        t0 = time.perf_counter()
        seg = segmenter.segment(image, cam)
        t1 = time.perf_counter()
        est = mh.analyse(image, cam, seg)
        t2 = time.perf_counter()
        t_seg.append(t1 - t0)
        t_mh.append(t2 - t1)
        return est

    # synthetic
    from spgeo.synthetic import SyntheticScene, camera_rotation, default_camera

    cam = default_camera(width, height)
    acc = {k: _Acc() for k in ("synthetic: all", "synthetic: room", "synthetic: box faces",
                                "synthetic: other")}
    for seed in synthetic_seeds:
        scene = SyntheticScene.generate(seed)
        kinds = np.array([0 if s.object_index < 0 else
                          (1 if s.name.startswith("box") else 2) for s in scene.surfaces])
        for yaw in (0.3, 1.9, 3.5):
            T = np.eye(4)
            T[:3, :3] = camera_rotation(yaw + seed, -0.2, 0.03)
            T[:3, 3] = [0.2, -0.1, 1.4]
            view = scene.render(cam, T)
            est = run(view.rgb, cam)
            sid = view.surface_ids
            st = np.where(sid >= 0, kinds[np.maximum(sid, 0)], -1)
            acc["synthetic: all"].add(est.normals, est.known, view.normals)
            for k, key in enumerate(("synthetic: room", "synthetic: box faces",
                                     "synthetic: other")):
                acc[key].add(est.normals, est.known, view.normals, st == k)
    rows += [a.row(k) for k, a in acc.items()]
    for name, frames in _real_frames(step, root):
        a = _Acc()
        for f in frames:
            f = resize_frame(f, (width, height), keep_depth=True)
            img = to_float_image(f.image)
            ref = oracle.estimate(None, f.camera, f.depth)
            est = run(img, f.camera)
            a.add(est.normals, est.known, ref)
        rows.append(a.row(f"{name} ({len(frames)} frames)"))
    ratio = float(np.median(t_mh) / np.median(t_seg))
    return ManhattanNormalsResult(rows, ratio, 1e3 * float(np.median(t_mh)),
                                  1e3 * float(np.median(t_seg)))


NAME = "manhattan_normals"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, main.__doc__, dataset=False)
    ap.add_argument("--step", type=int, default=30, help="7-Scenes frame step (default 30)")
    ap.add_argument("--width", type=int, default=320, help="working width (default 320)")
    ap.add_argument("--root", default=None,
                    help="shared data folder (default $SPGEO_SHARED_DATA or ../shared/data)")
    return ap


def run(args: argparse.Namespace) -> int:
    """Run :func:`evaluate` and print its table."""
    print(evaluate(args.step, args.width, root=args.root).table())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Angular error and coverage of the vanishing-point normals (synthetic and real frames)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
