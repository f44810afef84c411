"""VOID depth-completion protocol: methods, runner, table, and a writer of
synthetic sets in the release layout.

The data are read with :class:`spgeo.datasets.void.VOIDDataset` (layout and
encodings described there), the metrics are :func:`spgeo.metrics.depth.void_metrics`
(the demo reports them too) and the sparse points of the synthetic sets
:func:`spgeo.completion.sparse_points.keypoint_sparse_depth`; these names
(and the ground truth's range ``MIN_DEPTH``, ``MAX_DEPTH`` and the metric
names ``METRIC_KEYS``) are re-exported here.

Protocol (docs/design.md §5; the evaluation code of the VOID authors' KBNet /
VOICED): per image, pixels with ground truth ``0.2 < gt < 5.0`` m; MAE and RMSE
in millimetres, iMAE and iRMSE in 1/km; each metric averaged over the images.
The test set is 800 images per density.  The paper's zero-shot SuperPrimitive
result on VOID-150 is :data:`PAPER_VOID150`.
"""
from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.completion import CompletionConfig, complete_depth
from spgeo.completion.sparse_points import keypoint_sparse_depth, uniform_sparse_depth
from spgeo.datasets.files import PathLike
from spgeo.datasets.void import (VOID_LIST_KINDS, VOID_SPLITS, VOIDDataset, VOIDSample,
                                 check_void_split, read_void_depth, write_void_depth)
from spgeo.metrics.depth import (VOID_MAX_DEPTH as MAX_DEPTH, VOID_METRIC_KEYS as METRIC_KEYS,
                                 VOID_MIN_DEPTH as MIN_DEPTH, void_metrics)

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.references.depth_completion import (IPBasicConfig, ip_basic_completion,
                                                          linear_interpolation_completion)
from spgeo.evaluation.tables import cell, markdown_table

__all__ = [
    "VOID_SPLITS", "PAPER_VOID150", "VOIDSample", "VOIDDataset", "read_void_depth",
    "write_void_depth", "void_metrics", "VOIDResult", "run_void", "keypoint_sparse_depth",
    "uniform_sparse_depth",
    "write_synthetic_void", "METHOD_NAMES", "make_method", "build_parser", "run", "main",
]

log = logging.getLogger(__name__)

#: Paper (Mazur et al. CVPR 2024, zero-shot) on the VOID-150 test set.
PAPER_VOID150 = {"mae_mm": 109.0, "rmse_mm": 204.15, "imae_per_km": 47.32, "irmse_per_km": 83.40}


# ----------------------------------------------------------------- methods
#: Built-in method names of :func:`run_void` / :func:`make_method`.
METHOD_NAMES = ("spgeo", "spgeo-joint", "spgeo-onnx", "linear", "ip_basic")

Method = Callable[[np.ndarray, np.ndarray, PinholeCamera], np.ndarray]


def make_method(name: str, config: CompletionConfig = CompletionConfig()) -> Method:
    """A completion function ``f(image, sparse_depth, camera) -> depth`` by name:

    * ``"spgeo"``: :func:`spgeo.completion.complete_depth`, classical front-end;
    * ``"spgeo-joint"``: the same with ``method="joint"`` (GTSAM);
    * ``"spgeo-onnx"``: the ONNX front-end (needs ``spgeo models fetch``);
    * ``"linear"``: :func:`linear_interpolation_completion`;
    * ``"ip_basic"``: :func:`ip_basic_completion`.

    Front-ends are built once per image size and reused.
    """
    import dataclasses

    from spgeo.completion import working_size_for
    from spgeo.frontend import FrontEndConfig, make_frontend

    if name == "linear":
        return lambda image, sparse, camera: linear_interpolation_completion(sparse)
    if name == "ip_basic":
        return lambda image, sparse, camera: ip_basic_completion(sparse, IPBasicConfig())
    if name not in ("spgeo", "spgeo-joint", "spgeo-onnx"):
        raise ValueError(f"unknown completion method {name!r}; choose from {METHOD_NAMES}")
    fe_name = "onnx" if name == "spgeo-onnx" else "classical"
    cfg = dataclasses.replace(config, method="joint") if name == "spgeo-joint" else config
    cache: Dict[Tuple[int, int], object] = {}

    def run(image, sparse, camera):
        fe = cache.get(camera.size)
        if fe is None:
            fe = make_frontend(fe_name, FrontEndConfig(
                working_size=working_size_for(camera, cfg.working_width)))
            cache[camera.size] = fe
        return complete_depth(image, sparse, camera, fe, cfg).depth

    return run


# ----------------------------------------------------------------- runner
@dataclass
class VOIDResult:
    """Per-image metrics of every method on a VOID split.

    Attributes:
        split, subset: what was evaluated.
        names: evaluated sample names.
        per_image: method -> metric -> (n_images,) array.
        seconds: method -> (n_images,) run time per image.
    """

    split: str
    subset: str
    names: List[str]
    per_image: Dict[str, Dict[str, np.ndarray]]
    seconds: Dict[str, np.ndarray]

    def mean(self) -> Dict[str, Dict[str, float]]:
        """method -> metric -> mean over images (the protocol's number)."""
        return {m: {k: float(np.nanmean(v[k])) for k in METRIC_KEYS}
                | {"seconds": float(np.mean(self.seconds[m]))}
                for m, v in self.per_image.items()}

    def table(self, with_paper: bool = True) -> str:
        """Markdown table (MAE, RMSE in mm; iMAE, iRMSE in 1/km)."""
        rows = [[m, cell(v["mae_mm"], 1), cell(v["rmse_mm"], 1), cell(v["imae_per_km"], 2),
                 cell(v["irmse_per_km"], 2), cell(v["seconds"], 2)]
                for m, v in self.mean().items()]
        if with_paper and self.split == "150":
            p = PAPER_VOID150
            rows.append(["paper (SuperPrimitive, zero-shot, 800 images)", cell(p["mae_mm"], 1),
                         cell(p["rmse_mm"], 2), cell(p["imae_per_km"], 2),
                         cell(p["irmse_per_km"], 2), ""])
        return "\n".join([f"VOID-{self.split} {self.subset}, {len(self.names)} images, GT in "
                          f"({MIN_DEPTH}, {MAX_DEPTH}) m"]
                         + markdown_table(["method", "MAE [mm]", "RMSE [mm]", "iMAE [1/km]",
                                           "iRMSE [1/km]", "s/image"], rows, align="lrrrrr"))


def run_void(root: PathLike, split: Union[str, int] = "150",
             methods: Union[Sequence[str], Dict[str, Method]] = ("spgeo", "linear", "ip_basic"),
             max_images: Optional[int] = None, subset: str = "test",
             config: CompletionConfig = CompletionConfig(), progress: bool = True) -> VOIDResult:
    """Run completion methods on a VOID split and collect the protocol's metrics.

    Args:
        root: ``void_release`` (or ``void_<split>``) folder.
        split: ``"150"`` (the paper's), ``"500"`` or ``"1500"``.
        methods: built-in names (:data:`METHOD_NAMES`) or a dict name ->
            ``f(image, sparse_depth, camera) -> depth``.
        max_images: evaluate only the first N images (None: all, 800 for test).
        config: :class:`CompletionConfig` of the spgeo methods.
        progress: show a tqdm progress bar.
    """
    from tqdm import tqdm

    ds = VOIDDataset(root, split, subset)
    n = len(ds) if max_images is None else min(len(ds), int(max_images))
    if n <= 0:
        raise ValueError(f"nothing to evaluate in {ds.name} (max_images={max_images})")
    if isinstance(methods, dict):
        fns = dict(methods)
    else:
        if isinstance(methods, str):
            methods = [methods]
        fns = {m: make_method(m, config) for m in methods}
    if not fns:
        raise ValueError("run_void: no method given")
    per = {m: {k: np.full(n, np.nan) for k in METRIC_KEYS} for m in fns}
    secs = {m: np.zeros(n) for m in fns}
    names: List[str] = []
    for i in tqdm(range(n), desc=ds.name, disable=not progress):
        s = ds[i]
        names.append(s.name)
        for m, fn in fns.items():
            t0 = time.perf_counter()
            pred = fn(s.image, s.sparse_depth, s.camera)
            secs[m][i] = time.perf_counter() - t0
            met = void_metrics(pred, s.ground_truth)
            for k in METRIC_KEYS:
                per[m][k][i] = met[k]
    return VOIDResult(str(split), subset, names, per, secs)


# ----------------------------------------------------------------- synthetic writer
def write_synthetic_void(root: PathLike, splits: Sequence[Union[str, int]] = ("150",),
                         n_sequences: int = 2, frames_per_sequence: int = 2,
                         width: int = 640, height: int = 480, rel_noise: float = 0.01,
                         seed: int = 0, subset: str = "test") -> Path:
    """Write a small synthetic data set in the VOID release layout under
    ``root`` (which plays ``void_release``) and return ``root``.

    Each sequence is a procedural room (:mod:`spgeo.synthetic`, seed
    ``seed + i``) seen along a hand-held trajectory; every density folder
    gets the same images and ground truth and its own sparse points
    (:func:`keypoint_sparse_depth`: ``int(split)`` FAST keypoints, 1 %
    multiplicative noise by default).  Depths are stored as uint16 metres*256,
    validity maps as {0, 256}, intrinsics as ``K.txt``, poses (camera-to-world
    4x4) in ``absolute_pose/``, and ``<subset>_*.txt`` lists with paths
    relative to ``root`` — the official layout, so :class:`VOIDDataset` and
    :func:`run_void` read it unchanged.
    """
    from spgeo import synthetic

    root = Path(root)
    splits = [check_void_split(s) for s in splits]
    if n_sequences < 1 or frames_per_sequence < 1:
        raise ValueError("n_sequences and frames_per_sequence must be >= 1")
    cam = synthetic.default_camera(width, height)
    lists = {s: {k: [] for k in VOID_LIST_KINDS + ("absolute_pose",)} for s in splits}
    for q in range(n_sequences):
        scene = synthetic.SyntheticScene.generate(seed=seed + q)
        poses = synthetic.make_trajectory(10 * frames_per_sequence, seed=seed + q)[::10]
        seq = f"synthetic{q}"
        for f, T in enumerate(poses):
            view = scene.render(cam, T)
            stamp = f"{1552625653.0 + q * 1000 + f / 3.0:.4f}"
            rgb8 = np.rint(255 * view.rgb).astype(np.uint8)
            gt = np.where(np.isfinite(view.depth), view.depth, 0.0)
            for s in splits:
                base = root / f"void_{s}" / "data" / seq
                for sub in ("image", "sparse_depth", "validity_map", "ground_truth",
                            "absolute_pose"):
                    (base / sub).mkdir(parents=True, exist_ok=True)
                sparse = keypoint_sparse_depth(view.rgb, view.depth, int(s), rel_noise,
                                               seed=seed * 7919 + q * 101 + f)
                # quantise like the files, so validity and stored depth agree
                sparse = np.where(np.rint(sparse * 256) > 0, sparse, 0.0)
                if not cv2.imwrite(str(base / "image" / f"{stamp}.png"),
                                   cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR)):
                    raise OSError(f"could not write {base / 'image' / stamp}.png")
                write_void_depth(base / "sparse_depth" / f"{stamp}.png", sparse)
                cv2.imwrite(str(base / "validity_map" / f"{stamp}.png"),
                            np.where(sparse > 0, 256, 0).astype(np.uint16))
                write_void_depth(base / "ground_truth" / f"{stamp}.png", gt)
                np.savetxt(base / "absolute_pose" / f"{stamp}.txt", T)
                np.savetxt(base / "K.txt", cam.K)
                rel = f"void_{s}/data/{seq}"
                L = lists[s]
                L["image"].append(f"{rel}/image/{stamp}.png")
                L["sparse_depth"].append(f"{rel}/sparse_depth/{stamp}.png")
                L["validity_map"].append(f"{rel}/validity_map/{stamp}.png")
                L["ground_truth"].append(f"{rel}/ground_truth/{stamp}.png")
                L["absolute_pose"].append(f"{rel}/absolute_pose/{stamp}.txt")
                L["intrinsics"].append(f"{rel}/K.txt")
    for s in splits:
        for kind, entries in lists[s].items():
            (root / f"void_{s}" / f"{subset}_{kind}.txt").write_text(
                "\n".join(entries) + "\n", encoding="utf-8")
    log.info("wrote synthetic VOID set (%d sequences x %d frames, splits %s) to %s",
             n_sequences, frames_per_sequence, splits, root)
    return root


# ----------------------------------------------------------------- script
NAME = "void"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, "VOID depth-completion protocol", dataset=False)
    ap.add_argument("root", help="void_release folder (or void_<split>)")
    ap.add_argument("--split", default="150", choices=VOID_SPLITS)
    ap.add_argument("--subset", default="test", choices=("test", "train"))
    ap.add_argument("--max-images", type=int, default=None)
    ap.add_argument("--methods", nargs="+", default=["spgeo", "linear", "ip_basic"],
                    choices=METHOD_NAMES)
    return ap


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_void` and print its table."""
    res = run_void(args.root, args.split, args.methods, args.max_images, args.subset)
    print(res.table())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.completion.void VOID_RELEASE [--split 150] [--max-images N]
    [--methods spgeo linear ip_basic]``: print the protocol table (exit 2 for a
    missing or malformed data set)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
