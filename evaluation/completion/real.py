"""Depth completion on the real sample frames: 7-Scenes, TUM fr1_desk and ICL-NUIM.

For every frame, ``n_points`` (150) sparse depths are taken from the sensor
depth at FAST keypoints of the colour image spread by a grid
(:func:`spgeo.completion.sparse_points.keypoint_sparse_depth`, no added noise,
seed = frame index; ``--regime corners``: the strongest corners, clustered on
texture as a SLAM front-end's points are; ``--regime uniform``: uniform random pixels
with depth; ``--regime tracks``: corners a KLT tracker keeps through the next four
frames, on 7-Scenes and TUM only, whose frames are consecutive), completed by each
method and scored against the same depth with the VOID protocol (ground truth in
(0.2, 5.0) m; MAE / RMSE in mm, iMAE / iRMSE in 1/km, means over frames).  Data sets
(``/work/shared/data`` layout): 7-Scenes redkitchen frames 0-299 every 10th (depth not
registered to colour: approximate), the 9 TUM fr1_desk frames (undistorted), the 5
ICL-NUIM frames.

Rows:

* ``spgeo <front-end> <method>/<shape model>``:
  :func:`spgeo.completion.complete_depth` for each front-end of
  ``classical``, ``manhattan`` (when :data:`spgeo.frontend.FRONTENDS` has it)
  and the ORACLE ``depth`` (normals from the dense sensor depth: not
  monocular, an upper bound), with the scale ``method`` ``median`` (the paper)
  or ``graph`` (coupled, robust) and ``shape_model`` ``scale`` or ``plane``;
  the front-end runs once per frame and its time is included in every row
  that uses it; these rows run the primitive completion alone
  (``choose="none"``);
* ``spgeo classical choose=heldout``: the held-out choice of
  :mod:`spgeo.completion.choose` over ``config.candidates`` without a network
  (classical front-end), and with ``depth_model`` (``--depth-model``) also
  ``spgeo classical choose=heldout + network`` (the ``network:*`` candidates
  included) and ``network alone (<alignment>)``: the network's metric depth
  aligned to all points by each alignment of
  :data:`spgeo.completion.network.ALIGNMENTS`; the regions each candidate won
  are summed over the frames (:meth:`RealCompletionResult.winner_table`);
* ``linear``, ``ip_basic``, ``colorization``: the baselines of
  :mod:`spgeo.evaluation.references.depth_completion`.

The last columns give the relative MAE / iMAE improvement of each row over the
best of the three baselines on that data set (positive: better).

Run::

    spgeo eval completion_real [--root DIR] [--datasets 7scenes,tum,icl] [--out DIR]
        [--depth-model NAME|PATH] [--no-choose] [--regime grid|corners|uniform|tracks]
        [--workers N | --address ADDR]      (one job per data set, on Ray)
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from spgeo.completion import CompletionConfig, complete_depth, working_size_for
from spgeo.completion.sparse_points import (keypoint_sparse_depth, track_sparse_depth,
                                           uniform_sparse_depth)

from spgeo.evaluation.jobs import Job, RunnerConfig, add_runner_arguments, run_jobs, runner_config
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_table
from spgeo.evaluation.references.depth_completion import (colorization_completion,
                                                          ip_basic_completion,
                                                          linear_interpolation_completion)

from .void import METRIC_KEYS, void_metrics

__all__ = ["DATASETS", "BASELINES", "default_root", "open_sample", "sparse_frames",
           "RealCompletionResult", "run_dataset", "run_completion_real", "build_parser", "run",
           "main"]

log = logging.getLogger(__name__)

#: name -> (reader kind, folder under the data root, frame selection or None = all).
DATASETS = {
    "7scenes": ("7scenes", "7scenes_redkitchen_dev", "0:300:10"),
    "tum": ("tum", "tum_fr1_desk_9", None),
    "icl": ("icl", "icl_nuim_lr_5", None),
}

#: Baseline rows: name -> f(image, sparse) -> depth.
BASELINES: Dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "linear": lambda im, sp: linear_interpolation_completion(sp),
    "ip_basic": lambda im, sp: ip_basic_completion(sp),
    "colorization": lambda im, sp: colorization_completion(im, sp),
}

SHAPE_MODELS = ("scale", "plane")
SCALE_METHODS = ("median", "graph")


def default_root() -> Path:
    """The shared sample data (:func:`spgeo.evaluation.shared_data.shared_data_root`)."""
    from spgeo.evaluation.shared_data import shared_data_root

    return shared_data_root()


@dataclass
class RealCompletionResult:
    """Per-frame metrics of every method on one data set."""

    dataset: str
    frames: List[str]
    per_frame: Dict[str, Dict[str, List[float]]]
    n_points: int = 150
    not_run: Dict[str, str] = field(default_factory=dict)
    winners: Dict[str, Dict[str, int]] = field(default_factory=dict)
    agreement: Dict[str, Dict[str, List[float]]] = field(default_factory=dict)
    regime: str = "grid"

    def mean(self) -> Dict[str, Dict[str, float]]:
        return {m: {k: float(np.nanmean(v[k])) for k in (*METRIC_KEYS, "seconds")}
                for m, v in self.per_frame.items()}

    def gains(self) -> Dict[str, Dict[str, float]]:
        """Relative MAE / iMAE improvement of each method over the best baseline."""
        mean = self.mean()
        base = [m for m in BASELINES if m in mean]
        out: Dict[str, Dict[str, float]] = {}
        for k in ("mae_mm", "imae_per_km"):
            best = min((mean[b][k] for b in base), default=float("nan"))
            for m, v in mean.items():
                out.setdefault(m, {})[k] = 1.0 - v[k] / best
        return out

    def table(self) -> str:
        """Markdown: per method the means over the frames and the gains over the best
        baseline, the methods not run, then :meth:`winner_table` and
        :meth:`agreement_table`."""
        mean, gains = self.mean(), self.gains()
        rows = [[m, cell(v["mae_mm"], 1), cell(v["rmse_mm"], 1), cell(v["imae_per_km"]),
                 cell(v["irmse_per_km"]), cell(v["seconds"]),
                 cell(100 * gains[m]["mae_mm"], "{:+.0f} %"),
                 cell(100 * gains[m]["imae_per_km"], "{:+.0f} %")] for m, v in mean.items()]
        rows += [[m, f"not run: {why}"] + [""] * 6 for m, why in self.not_run.items()]
        lines = [f"**{self.dataset}**: {len(self.frames)} frames, {self.n_points} sparse points "
                 f"(regime {self.regime!r}); reference = sensor depth in (0.2, 5.0) m", ""]
        lines += markdown_table(["method", "MAE [mm]", "RMSE [mm]", "iMAE [1/km]", "iRMSE [1/km]",
                                 "s/frame", "MAE gain", "iMAE gain"], rows, "l" + "r" * 7)
        return "\n".join(lines) + self.winner_table() + self.agreement_table()

    def agreement_table(self) -> str:
        """Markdown: per held-out-choice row, the means over the frames of
        :func:`spgeo.completion.choose.rank_agreement` (rank agreement of the
        held-out score with the dense error); empty when there is none."""
        if not self.agreement:
            return ""
        rows = [[m, cell(np.nanmean(a["spearman"])),
                 cell(100 * np.mean(a["region_agreement"]), "{:.0f} %"),
                 cell(1e3 * np.mean(a["chosen_log_error"]), 1),
                 cell(1e3 * np.mean(a["oracle_log_error"]), 1)] for m, a in self.agreement.items()]
        return "\n".join(
            ["", "", "held-out score vs dense error (means over frames; log errors x 1000):", ""]
            + markdown_table(["row", "Spearman (candidates)", "pixels whose region's dominant "
                              "candidate is its dense-best", "chosen dense log error",
                              "per-region dense-best (oracle)"], rows, "lrrrr"))

    def winner_table(self) -> str:
        """Markdown: regions (primitives / cells) each candidate won, summed over
        the frames, per held-out-choice row; empty when there is none."""
        if not self.winners:
            return ""
        names = sorted({c for w in self.winners.values() for c in w})
        rows = [[m] + [cell(w.get(c, 0)) for c in names] for m, w in self.winners.items()]
        return "\n".join(
            ["", "", "regions whose blend weighs each candidate most (summed over frames):", ""]
            + markdown_table(["row"] + names, rows, "l" + "r" * len(names)))

    def to_dict(self) -> dict:
        return {"dataset": self.dataset, "frames": self.frames, "n_points": self.n_points,
                "regime": self.regime,
                "mean": self.mean(), "gain_vs_best_baseline": self.gains(),
                "per_frame": self.per_frame, "not_run": self.not_run, "winners": self.winners,
                "agreement": self.agreement}


#: sparse regimes (``--regime``): ``grid``: FAST keypoints spread by a grid (the
#: strongest per cell); ``corners``: the strongest FAST corners, clustered on
#: texture; ``uniform``: pixels drawn uniformly among those with depth;
#: ``tracks``: corners a KLT tracker keeps over the next :data:`TRACK_FRAMES`
#: frames (data sets of consecutive frames only, :data:`CONSECUTIVE`).
REGIMES = ("grid", "corners", "uniform", "tracks")
#: frames a ``tracks`` point is tracked through.
TRACK_FRAMES = 4
#: data sets whose frames are consecutive video frames (``tracks`` runs on these).
CONSECUTIVE = ("7scenes", "tum")


def sparse_frames(ds, n_points: int = 150, seed: int = 0, desc: str = "completion",
                  progress: bool = True, regime: str = "grid", sequence=None
                  ) -> Iterator[Tuple[object, np.ndarray, np.ndarray]]:
    """``(frame, reference depth, sparse depth)`` for every frame of ``ds``: the
    reference is the frame's depth (NaN -> 0), the sparse input ``n_points``
    depths from it without added noise, seed ``seed + index``, at the pixels of
    ``regime`` (:data:`REGIMES`; ``ValueError`` for another).  ``tracks``
    needs ``sequence``: the consecutive frames ``ds`` was selected from (a
    ``FrameSequence`` with ``frame_numbers``); a frame's points are tracked
    through the :data:`TRACK_FRAMES` frames after it (before it at the end)."""
    from tqdm import tqdm

    if regime not in REGIMES:
        raise ValueError(f"unknown sparse regime {regime!r}; choose from {', '.join(REGIMES)}")
    if regime == "tracks" and sequence is None:
        raise ValueError("sparse regime 'tracks' needs the frames' sequence")
    for i in tqdm(range(len(ds)), desc=desc, disable=not progress):
        f = ds[i]
        gt = np.nan_to_num(f.depth, nan=0.0)
        if regime == "uniform":
            sparse = uniform_sparse_depth(gt, n_points, seed=seed + i)
        elif regime == "tracks":
            near = _neighbours(sequence, ds.frame_numbers[i], TRACK_FRAMES)
            sparse = track_sparse_depth([f.image] + [sequence[j].image for j in near], gt,
                                        n_points, seed=seed + i)
        else:
            sparse = keypoint_sparse_depth(f.image, gt, n_points, rel_noise=0.0, seed=seed + i,
                                           spread=regime == "grid")
        yield f, gt, sparse


def _neighbours(sequence, number: int, k: int) -> List[int]:
    """Positions in ``sequence`` of the ``k`` frames after frame ``number``
    (the ``k`` before it, nearest first, when fewer follow)."""
    nums = list(sequence.frame_numbers)
    if number not in nums:
        raise ValueError(f"frame {number} is not in the sequence {sequence!r}")
    p = nums.index(number)
    after = list(range(p + 1, min(p + 1 + k, len(nums))))
    return after if len(after) == k else list(range(p - 1, max(p - 1 - k, -1), -1))


def _frontend_names() -> List[str]:
    from spgeo.frontend import FRONTENDS

    return [f for f in ("classical", "manhattan", "depth") if f in FRONTENDS]


def _label(fe: str) -> str:
    return "ORACLE depth-normals" if fe == "depth" else fe


def open_sample(name: str, root: Optional[Path] = None, frames: Optional[str] = None):
    """The frames of data set ``name`` of :data:`DATASETS` under ``root`` (default
    :func:`default_root`); ``frames`` overrides its selection.  Raises
    ``ValueError`` for an unknown name and ``FileNotFoundError`` when its folder
    is missing."""
    from spgeo.datasets import open_dataset

    if name not in DATASETS:
        raise ValueError(f"unknown data set {name!r}; choose from {sorted(DATASETS)}")
    kind, folder, sel = DATASETS[name]
    path = Path(root if root is not None else default_root()) / folder
    if not path.is_dir():
        raise FileNotFoundError(f"{name} sample not found at {path}")
    sel = frames or sel
    return open_dataset(kind, path, **({"frames": sel} if sel else {}))


def run_dataset(name: str, root: Optional[Path] = None, frames: Optional[str] = None,
                n_points: int = 150, seed: int = 0,
                config: CompletionConfig = CompletionConfig(),
                frontends: Optional[Sequence[str]] = None,
                shape_models: Sequence[str] = SHAPE_MODELS,
                methods: Sequence[str] = SCALE_METHODS,
                baselines: Optional[Sequence[str]] = None,
                progress: bool = True, choose: bool = True,
                depth_model: Optional[str] = None, regime: str = "grid") -> RealCompletionResult:
    """Evaluate all methods on one data set of :data:`DATASETS`.

    ``frames`` overrides the data set's selection; ``regime`` places the
    sparse points (:data:`REGIMES`, :func:`sparse_frames`); ``choose`` adds the
    held-out-choice rows, ``depth_model`` (a name or path for
    :func:`spgeo.frontend.metric_depth_from_cache`) the network rows (module
    docstring).  Raises ``FileNotFoundError`` when its folder (or the model) is
    missing and ``ValueError`` for an unknown name or a model that does not fit.
    """
    from spgeo.frontend import FrontEndConfig, make_frontend, metric_depth_from_cache

    ds = open_sample(name, root, frames)
    sequence = None
    if regime == "tracks":
        if name not in CONSECUTIVE:
            raise ValueError(f"{name}: its frames are not consecutive; the 'tracks' regime runs "
                             f"on {', '.join(CONSECUTIVE)}")
        sequence = open_sample(name, root, "0:")
    fes = list(frontends) if frontends is not None else _frontend_names()
    fe_cfg = FrontEndConfig(working_size=working_size_for(ds.camera, config.working_width))
    built = {fe: make_frontend(fe, fe_cfg) for fe in fes}
    if choose and "classical" not in built:
        built["classical"] = make_frontend("classical", fe_cfg)
    model = metric_depth_from_cache(depth_model) if depth_model else None
    base = {b: BASELINES[b] for b in (baselines if baselines is not None else BASELINES)}
    per: Dict[str, Dict[str, List[float]]] = {}
    winners: Dict[str, Dict[str, int]] = {}
    agreement: Dict[str, Dict[str, List[float]]] = {}

    def add(method: str, pred: np.ndarray, gt: np.ndarray, secs: float) -> None:
        met = void_metrics(pred, gt)
        row = per.setdefault(method, {k: [] for k in (*METRIC_KEYS, "seconds")})
        for k in METRIC_KEYS:
            row[k].append(float(met[k]))
        row["seconds"].append(float(secs))

    names: List[str] = []
    for f, gt, sparse in sparse_frames(ds, n_points, seed, f"{name} completion", progress,
                                       regime, sequence):
        names.append(f.name)
        for fe, front in built.items():
            t0 = time.perf_counter()
            prims = front.primify(f.image, f.camera, f.depth if front.uses_depth else None)
            t_fe = time.perf_counter() - t0
            if fe in fes:
                _primitive_rows(f, gt, sparse, prims, fe, t_fe, config, methods, shape_models,
                                add)
            if fe == "classical" and choose:
                _choice_rows(f, gt, sparse, prims, t_fe, config, model, add,
                             (winners, agreement))
        for b, fn in base.items():
            t0 = time.perf_counter()
            pred = fn(f.image, sparse)
            add(b, pred, gt, time.perf_counter() - t0)
    not_run = {} if "manhattan" in fes or frontends is not None else {
        "spgeo manhattan": "front-end 'manhattan' not in spgeo.frontend.FRONTENDS"}
    return RealCompletionResult(name, names, per, n_points, not_run, winners, agreement, regime)


def _primitive_rows(f, gt, sparse, prims, fe, t_fe, config, methods, shape_models, add):
    """The ``spgeo <front-end> <method>/<shape model>`` rows of one frame
    (``choose="none"``)."""
    import dataclasses

    for meth in methods:
        for sm in shape_models:
            cfg = dataclasses.replace(config, method=meth, shape_model=sm, choose="none",
                                      depth_model=None)
            t1 = time.perf_counter()
            res = complete_depth(f.image, sparse, f.camera, prims, cfg)
            add(f"spgeo {_label(fe)} {meth}/{sm}", res.depth, gt,
                t_fe + time.perf_counter() - t1)


def _choice_rows(f, gt, sparse, prims, t_fe, config, model, add, tallies):
    """The held-out-choice rows and, with ``model``, the network rows of one
    frame; ``tallies`` = (winners, agreement): region wins summed into
    ``winners``, :func:`spgeo.completion.choose.rank_agreement` appended to
    ``agreement`` per row."""
    import dataclasses

    import cv2

    from spgeo.completion.choose import rank_agreement
    from spgeo.completion.network import ALIGNMENTS, align_network_depth, network_depth

    winners, agreement = tallies
    cfg = dataclasses.replace(config, choose="heldout", depth_model=None)
    runs = [("spgeo classical choose=heldout", None)]
    if model is not None:
        runs.append(("spgeo classical choose=heldout + network", model))
    for row, dm in runs:
        t1 = time.perf_counter()
        res = complete_depth(f.image, sparse, f.camera, prims, cfg, depth_model=dm)
        add(row, res.depth, gt, t_fe + time.perf_counter() - t1)
        if res.choice is not None:
            won = winners.setdefault(row, {})
            for c, k in res.choice.region_counts().items():
                won[c] = won.get(c, 0) + k
            agr = agreement.setdefault(row, {})
            for k, v in rank_agreement(res.choice, gt).items():
                agr.setdefault(k, []).append(v)
    if model is None:
        return
    t1 = time.perf_counter()
    net = network_depth(model, f.image)
    labels = cv2.resize(prims.label_image(), f.camera.size, interpolation=cv2.INTER_NEAREST)
    v, u = np.nonzero(sparse > 0)
    t_net = time.perf_counter() - t1
    for a in ALIGNMENTS:
        t2 = time.perf_counter()
        pred = align_network_depth(net, np.stack([u, v], 1), sparse[v, u], a, labels,
                                   config.network_min_points)
        add(f"network alone ({a})", pred, gt, t_net + time.perf_counter() - t2)


def _dataset_job(name: str, root: Optional[Path], kwargs: dict) -> dict:
    """Job of :func:`run_completion_real`: ``{"result": RealCompletionResult}``."""
    return {"result": run_dataset(name, root, **kwargs)}


def run_completion_real(root: Optional[Path] = None, datasets: Sequence[str] = tuple(DATASETS),
                        runner: Optional[RunnerConfig] = None,
                        **kwargs) -> Dict[str, RealCompletionResult]:
    """:func:`run_dataset` for each data set, one job each
    (:mod:`spgeo.evaluation.jobs`; ``runner`` default: sequentially here);
    a missing data set is skipped with a warning, a data set whose job
    fails is logged as an error and left out.  Raises ``ValueError`` for an
    unknown data set name."""
    unknown = [d for d in datasets if d not in DATASETS]
    if unknown:
        raise ValueError(f"unknown data set(s) {unknown}; choose from {sorted(DATASETS)}")
    if kwargs.get("regime") == "tracks":
        skipped = [d for d in datasets if d not in CONSECUTIVE]
        if skipped:
            log.warning("%s: frames not consecutive, no 'tracks' regime; skipped",
                        ", ".join(skipped))
        datasets = [d for d in datasets if d in CONSECUTIVE]
    jobs = [Job(name, _dataset_job, (name, root, kwargs)) for name in datasets]
    out: Dict[str, RealCompletionResult] = {}
    for row in run_jobs(jobs, runner or RunnerConfig(progress=False, desc="completion_real")):
        if row["error"] is None:
            out[row["job"]] = row["result"]
        elif row["error"].startswith("FileNotFoundError"):
            log.warning("%s: skipped (%s)", row["job"], row["error"])
        else:
            log.error("%s: failed (%s)", row["job"], row["error"])
    return out


NAME = "completion_real"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, "spgeo depth completion vs baselines on the real "
                               "samples (7-Scenes, TUM, ICL-NUIM)", dataset=False)
    ap.add_argument("--root", default=None, help=f"data root (default {default_root()})")
    ap.add_argument("--datasets", default=",".join(DATASETS),
                    help="comma-separated subset of " + ",".join(DATASETS))
    ap.add_argument("--frames", default=None, help="override the frame selection A:B:S")
    ap.add_argument("--points", type=int, default=150, help="sparse points per frame (150)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--regime", choices=REGIMES, default="grid",
                    help="where the sparse points are: grid-spread FAST keypoints (default), the "
                         "strongest FAST corners (clustered), uniform random pixels, or corners "
                         "KLT-tracked through the next frames (7scenes and tum only)")
    ap.add_argument("--frontends", default=None,
                    help="comma-separated front-ends (default: classical, manhattan if "
                         "present, depth oracle)")
    ap.add_argument("--baselines", default=",".join(BASELINES),
                    help="comma-separated baselines (default all)")
    ap.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                    help="CompletionConfig overrides (Python literals), e.g. plane_coupling=0.01; "
                         "the method / shape_model of each row still vary")
    ap.add_argument("--out", default=None, help="folder for completion_real.md / .json")
    ap.add_argument("--depth-model", default=None, metavar="NAME|PATH",
                    help="metric-depth network (registry name or .onnx path, preset "
                         "'fastdepth' for a path): adds the network rows")
    ap.add_argument("--no-choose", action="store_true",
                    help="leave out the held-out-choice rows")
    add_runner_arguments(ap)
    return ap


def _check_depth_model(depth_model: Optional[str]) -> None:
    """Load ``--depth-model`` once (when given) so that a missing or misfit model is one
    ``ValueError`` naming the option, not one failed job per data set."""
    if depth_model:
        from spgeo.frontend import metric_depth_from_cache

        try:
            metric_depth_from_cache(depth_model)
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"--depth-model: {exc}") from exc


def _completion_config(assignments: Sequence[str]) -> CompletionConfig:
    """:class:`CompletionConfig` with the ``--set FIELD=VALUE`` overrides; a bad one is a
    ``ValueError`` naming the option."""
    try:
        from spgeo.configs import apply_overrides, nest, parse_assignments

        over = nest(parse_assignments(assignments, strict=True))
        return apply_overrides(CompletionConfig(), over) if over else CompletionConfig()
    except (ValueError, TypeError) as exc:
        raise ValueError(f"--set: {exc}") from exc


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_completion_real`, print the tables, write ``--out``."""
    root = Path(args.root) if args.root else default_root()
    if not root.is_dir():
        raise FileNotFoundError(f"data root not found at {root} (give --root)")
    names = [d for d in args.datasets.split(",") if d]
    _check_depth_model(args.depth_model)
    fes = [f for f in args.frontends.split(",") if f] if args.frontends else None
    bls = [b for b in args.baselines.split(",") if b]
    try:
        runner = runner_config(args, desc="completion_real", progress=args.workers > 0
                               or args.address is not None)
    except ValueError as exc:
        build_parser().error(str(exc))
    config = _completion_config(args.set)
    res = run_completion_real(root, names, runner, frames=args.frames, n_points=args.points,
                              seed=args.seed, frontends=fes, baselines=bls, config=config,
                              choose=not args.no_choose, depth_model=args.depth_model,
                              progress=runner.backend == "local", regime=args.regime)
    text = "\n\n".join(r.table() for r in res.values())
    print(text)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "completion_real.md").write_text(text + "\n", encoding="utf-8")
        (out / "completion_real.json").write_text(
            json.dumps({k: r.to_dict() for k, r in res.items()}, indent=1), encoding="utf-8")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Depth completion on the real samples (module docstring): print the tables,
    write ``--out``; exit 2 for a missing data root, model or bad ``--set``."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
