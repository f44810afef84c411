"""Depth completion on real frames: Microsoft 7-Scenes ``redkitchen`` sample.

For every selected frame, ``n_points`` (150, VOID-150's density) sparse depths
are taken from the Kinect depth at FAST keypoints of the colour image
(:func:`spgeo.completion.sparse_points.keypoint_sparse_depth`, no added noise:
the sensor's own noise is there), completed by each method, and scored against
the same sensor depth with the VOID protocol (ground truth in (0.2, 5.0) m;
MAE/RMSE in mm, iMAE/iRMSE in 1/km, averaged over frames).

**Caveat**: 7-Scenes depth is *not registered* to the colour image (another
sensor, other intrinsics, a small baseline; the reader returns it as an
approximate depth in the colour view).  Both the sparse input and the
reference therefore carry misalignment of a few pixels at depth edges; the
numbers compare methods on equal terms but are not an accurate absolute
benchmark.

Methods (rows):

* ``spgeo classical`` — :func:`spgeo.completion.complete_depth` with the
  classical front-end (superpixels + fronto-parallel normals: monocular);
* ``spgeo classical joint`` — the same with the GTSAM joint solve;
* ``spgeo onnx`` — only when the ONNX models are in the cache
  (``spgeo models fetch``); otherwise listed as not run;
* ``ORACLE normals (sensor depth)`` — classical segments + normals computed
  from the *dense* sensor depth (``make_frontend("depth")``): not monocular,
  an upper bound for what better normals would give;
* ``linear`` and ``ip_basic`` — the sparse-only baselines; ``colorization``
  — the image-guided fill of the NYU toolbox.

:mod:`spgeo.evaluation.completion.real` runs the same protocol on all three
real samples with more spgeo variants.

The ``"depth"`` front-end as a monocular method is not applicable: it needs
dense depth.

Run::

    python -m spgeo.evaluation.completion.seven_scenes [PATH] [--frames 0:300:10] [--points 150]
"""
from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from spgeo.completion import CompletionConfig, complete_depth

from spgeo.evaluation.references.depth_completion import (IPBasicConfig, colorization_completion,
                                                          ip_basic_completion,
                                                          linear_interpolation_completion)

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_table

from .real import sparse_frames
from .void import METRIC_KEYS, void_metrics

__all__ = ["default_path", "SevenScenesCompletionResult", "run_7scenes", "build_parser", "run",
           "main"]

log = logging.getLogger(__name__)


def default_path() -> Path:
    """``7scenes_redkitchen_dev`` in the shared sample data
    (:func:`spgeo.evaluation.shared_data.shared_data_root`)."""
    from spgeo.evaluation.shared_data import shared_data_root

    return shared_data_root() / "7scenes_redkitchen_dev"


@dataclass
class SevenScenesCompletionResult:
    """Per-frame metrics per method; :meth:`table` formats the means."""

    frames: List[str]
    per_frame: Dict[str, Dict[str, np.ndarray]]
    seconds: Dict[str, np.ndarray]
    not_run: Dict[str, str] = field(default_factory=dict)
    n_points: int = 150

    def mean(self) -> Dict[str, Dict[str, float]]:
        return {m: {k: float(np.nanmean(v[k])) for k in METRIC_KEYS}
                | {"seconds": float(np.mean(self.seconds[m]))} for m, v in self.per_frame.items()}

    def table(self) -> str:
        """Markdown: per method the means over the frames, then the methods not run."""
        rows = [[m, cell(v["mae_mm"], 1), cell(v["rmse_mm"], 1), cell(v["imae_per_km"]),
                 cell(v["irmse_per_km"]), cell(v["seconds"])] for m, v in self.mean().items()]
        rows += [[m, f"not run: {why}"] + [""] * 4 for m, why in self.not_run.items()]
        return "\n".join(
            [f"7-Scenes redkitchen, {len(self.frames)} frames, {self.n_points} sparse points "
             "at FAST keypoints from the (unregistered, approximate) Kinect depth; reference = "
             "the same Kinect depth in (0.2, 5.0) m"]
            + markdown_table(["method", "MAE [mm]", "RMSE [mm]", "iMAE [1/km]", "iRMSE [1/km]",
                              "s/frame"], rows, "l" + "r" * 5))


def _methods(config: CompletionConfig, with_onnx: bool, camera):
    """name -> f(image, sparse, camera, sensor_depth) and a dict of methods not run."""
    import dataclasses

    from spgeo.completion import working_size_for
    from spgeo.frontend import FrontEndConfig, make_frontend

    not_run: Dict[str, str] = {}
    fe_cfg = FrontEndConfig(working_size=working_size_for(camera, config.working_width))
    classical = make_frontend("classical", fe_cfg)
    oracle = make_frontend("depth", fe_cfg)
    joint = dataclasses.replace(config, method="joint")
    fns: Dict[str, Callable] = {
        "spgeo classical": lambda im, sp, cam, dep: complete_depth(im, sp, cam, classical,
                                                                   config).depth,
        "spgeo classical joint": lambda im, sp, cam, dep: complete_depth(im, sp, cam, classical,
                                                                         joint).depth,
    }
    if with_onnx:
        try:
            onnx = make_frontend("onnx", fe_cfg)
        except (FileNotFoundError, ImportError, OSError, ValueError) as exc:
            not_run["spgeo onnx"] = f"ONNX models unavailable ({str(exc).splitlines()[0][:80]})"
        else:
            fns["spgeo onnx"] = lambda im, sp, cam, dep: complete_depth(im, sp, cam, onnx,
                                                                        config).depth
    fns["ORACLE normals (sensor depth)"] = lambda im, sp, cam, dep: complete_depth(
        im, sp, cam, oracle, config, frontend_depth=dep).depth
    fns["linear"] = lambda im, sp, cam, dep: linear_interpolation_completion(sp)
    fns["ip_basic"] = lambda im, sp, cam, dep: ip_basic_completion(sp, IPBasicConfig())
    fns["colorization"] = lambda im, sp, cam, dep: colorization_completion(im, sp)
    return fns, not_run


def run_7scenes(path=None, frames: str = "0:300:10", n_points: int = 150, seed: int = 0,
                config: CompletionConfig = CompletionConfig(), with_onnx: bool = True,
                progress: bool = True) -> SevenScenesCompletionResult:
    """Evaluate the completion methods on 7-Scenes frames (module docstring).

    Raises ``FileNotFoundError`` when the data are absent.
    """
    from spgeo.datasets import open_dataset

    path = Path(path) if path is not None else default_path()
    if not path.is_dir():
        raise FileNotFoundError(f"7-Scenes sample not found at {path}")
    ds = open_dataset("7scenes", path, frames=frames)
    fns, not_run = _methods(config, with_onnx, ds.camera)
    n = len(ds)
    per = {m: {k: np.full(n, np.nan) for k in METRIC_KEYS} for m in fns}
    secs = {m: np.zeros(n) for m in fns}
    names: List[str] = []
    for i, (f, gt, sparse) in enumerate(sparse_frames(ds, n_points, seed, "7-Scenes completion",
                                                      progress)):
        names.append(f.name)
        for m, fn in fns.items():
            t0 = time.perf_counter()
            pred = fn(f.image, sparse, f.camera, f.depth)
            secs[m][i] = time.perf_counter() - t0
            met = void_metrics(pred, gt)
            for k in METRIC_KEYS:
                per[m][k][i] = met[k]
    return SevenScenesCompletionResult(names, per, secs, not_run, n_points)


NAME = "completion_7scenes"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, "spgeo depth completion vs baselines on 7-Scenes", dataset=False)
    ap.add_argument("path", nargs="?", default=None,
                    help=f"7-Scenes sequence folder (default {default_path()})")
    ap.add_argument("--frames", default="0:300:10", help="frame selection A:B:S (default 0:300:10)")
    ap.add_argument("--points", type=int, default=150, help="sparse points per frame (default 150)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-onnx", action="store_true", help="do not try the ONNX front-end")
    return ap


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_7scenes` and print its table."""
    path = Path(args.path) if args.path else default_path()
    if not path.is_dir():
        raise FileNotFoundError(f"7-Scenes sample not found at {path} (give PATH)")
    res = run_7scenes(path, args.frames, args.points, args.seed, with_onnx=not args.no_onnx)
    print(res.table())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Depth completion on 7-Scenes (module docstring): print the table; exit 2 when
    the data are missing."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
