"""ScanNet few-view SfM protocol (docs/design.md §5): view-set selection, runner, table.

The scenes are read with :class:`spgeo.datasets.scannet.ScanNetScene` (the
SensReader export layout; :func:`write_synthetic_scannet` writes a synthetic
scene in it); those reader names are re-exported here.

Protocol (:func:`run_scannet_sfm`): a reference every ``stride``-th frame
(default 200), supporting views at the first available frame offsets of
``offsets`` (default +-10, +-20, +-30 frames), ``n = 1..max_views`` of them;
a set is discarded when a reference or view pose is invalid, fewer than
``max_views`` views exist, or it is *near-static* (some view moved less than
``min_translation`` AND rotated less than ``min_rotation_deg`` relative to the
reference).  :func:`spgeo.sfm.few_view_sfm` runs per set, per ``n`` and per
initialisation (the paper's ``"identity"`` and the library default
``"features"``); its depth is median-scaled to the ground truth (valid in
``[min_depth, max_depth]``, default 0.1-10 m) and scored with iMAE / iRMSE
(1/km), abs-rel, delta < 1.25 at the SfM working resolution (ground truth
resampled by nearest neighbour), beside a median-scaled constant-depth
baseline; poses with rotation and translation-direction errors (degrees).
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.datasets.files import PathLike
from spgeo.datasets.scannet import (ScanNetConfig, ScanNetScene, list_scenes,
                                    read_scannet_matrix, resize_depth_nearest,
                                    write_synthetic_scannet)
from spgeo.frontend import PrimitiveFrontEnd
from spgeo.geometry import relative_pose, rotation_angle_deg
from spgeo.sfm import SfMConfig, few_view_sfm

from spgeo.evaluation.pose_metrics import relative_pose_errors
from spgeo.evaluation.runner import protocol_parser, run_protocol, write_json
from spgeo.evaluation.tables import cell, markdown_table

__all__ = [
    "ScanNetConfig", "ScanNetScene", "list_scenes", "read_scannet_matrix",
    "ScanNetProtocolConfig", "ViewSet", "select_view_sets", "ScanNetSfMResult",
    "run_scannet_sfm", "evaluate_depth", "resize_depth_nearest", "write_synthetic_scannet",
    "build_parser", "run", "main",
]

log = logging.getLogger(__name__)


# ================================================================ protocol
@dataclass(frozen=True)
class ScanNetProtocolConfig:
    """Options of :func:`run_scannet_sfm` (docs/design.md §5).

    Attributes:
        stride: a reference every ``stride``-th frame number, default 200.
        start: first reference frame number, default 0.
        offsets: frame offsets of candidate supporting views, in order of
            preference; the first ``max_views`` that exist with a valid pose
            are used, default (10, -10, 20, -20, 30, -30) (ScanNet is 30 fps).
        max_views: evaluate ``n = 1..max_views`` supporting views (the first
            ``n`` of the set), default 3.
        min_translation: metres; with ``min_rotation_deg``: a set is
            near-static (discarded) when some view moved less than this AND
            rotated less than ``min_rotation_deg`` relative to the reference,
            default 0.03 m (about 1 % of a ScanNet median depth, the SfM's
            low-parallax level).
        min_rotation_deg: see ``min_translation``, default 1.5 degrees.
        min_depth, max_depth: ground-truth depths scored (metres, exclusive),
            default 0.1 and 10.
        inits: SfM initialisations to run: ``"identity"`` (the paper: poses
            at identity, log-scales 0) and ``"features"`` (the library default),
            default both.
        frontend: front-end name (``"classical"`` default, ``"depth"`` = oracle
            normals from the ground-truth depth, ``"onnx"``).
        working_size: ``(width, height)`` the front-end and SfM work at,
            default (320, 240) (the authors').
        sfm: base :class:`SfMConfig` (``init`` is replaced per run); default
            ``SfMConfig(marginals=False)`` (covariances are not scored).
        max_samples: stop after this many view sets (None: all).
        progress: tqdm progress bar over the view sets.
    """

    stride: int = 200
    start: int = 0
    offsets: Tuple[int, ...] = (10, -10, 20, -20, 30, -30)
    max_views: int = 3
    min_translation: float = 0.03
    min_rotation_deg: float = 1.5
    min_depth: float = 0.1
    max_depth: float = 10.0
    inits: Tuple[str, ...] = ("identity", "features")
    frontend: str = "classical"
    working_size: Tuple[int, int] = (320, 240)
    sfm: SfMConfig = field(default_factory=lambda: SfMConfig(marginals=False))
    max_samples: Optional[int] = None
    progress: bool = True

    def __post_init__(self) -> None:
        if int(self.stride) < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if int(self.max_views) < 1:
            raise ValueError(f"max_views must be >= 1, got {self.max_views}")
        offs = [int(o) for o in self.offsets]
        if not offs or 0 in offs or len(set(offs)) != len(offs):
            raise ValueError(f"offsets must be distinct non-zero frame offsets, got {self.offsets}")
        if len(offs) < int(self.max_views):
            raise ValueError(f"{len(offs)} offsets cannot give max_views={self.max_views} views")
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, "
                             f"{self.max_depth}")
        if self.min_translation < 0 or self.min_rotation_deg < 0:
            raise ValueError("min_translation and min_rotation_deg must be >= 0")
        if not self.inits or any(i not in ("identity", "features") for i in self.inits):
            raise ValueError(f"inits must be a non-empty subset of ('identity', 'features'), "
                             f"got {self.inits}")
        if self.max_samples is not None and int(self.max_samples) < 1:
            raise ValueError(f"max_samples must be >= 1 or None, got {self.max_samples}")
        if len(self.working_size) != 2 or min(self.working_size) < 16:
            raise ValueError(f"working_size must be (width, height) >= 16 px, "
                             f"got {self.working_size}")


@dataclass
class ViewSet:
    """One protocol sample: a reference frame and its ordered supporting views.

    Attributes:
        scene: scene id.
        ref: reference frame number.
        views: supporting frame numbers (``max_views`` of them, preference order).
        T_ref_view_gt: ground-truth ``T_ref_view`` (camera-to-reference) per view.
        gt_translation: metres moved by each view relative to the reference.
        gt_rotation_deg: rotation of each view relative to the reference.
    """

    scene: str
    ref: int
    views: Tuple[int, ...]
    T_ref_view_gt: List[np.ndarray]
    gt_translation: List[float]
    gt_rotation_deg: List[float]


def select_view_sets(frame_numbers: Sequence[int], poses: Mapping[int, Optional[np.ndarray]],
                     config: ScanNetProtocolConfig = ScanNetProtocolConfig(),
                     scene: str = "") -> Tuple[List[ViewSet], List[Dict[str, object]]]:
    """The protocol's view sets of one scene.

    Args:
        frame_numbers: frame numbers that exist.
        poses: frame number -> camera-to-world pose, None (or non-finite) = invalid.
        config: :class:`ScanNetProtocolConfig` (stride, start, offsets,
            max_views, near-static thresholds).
        scene: scene id stored in the sets.
    Returns:
        ``(sets, skipped)``; ``skipped`` holds one dict per discarded reference
        (``scene``, ``ref``, ``reason``).
    """
    available = set(int(n) for n in frame_numbers)

    def valid(n: int) -> bool:
        T = poses.get(n)
        return n in available and T is not None and bool(np.all(np.isfinite(T)))

    sets: List[ViewSet] = []
    skipped: List[Dict[str, object]] = []
    for ref in sorted(available):
        if ref < config.start or (ref - config.start) % config.stride:
            continue
        if not valid(ref):
            skipped.append({"scene": scene, "ref": ref, "reason": "invalid reference pose"})
            continue
        views = [ref + o for o in config.offsets if valid(ref + int(o))][:config.max_views]
        if len(views) < config.max_views:
            skipped.append({"scene": scene, "ref": ref,
                            "reason": f"only {len(views)} of {config.max_views} supporting "
                                      "views with a valid pose"})
            continue
        T_gt = [relative_pose(poses[ref], poses[v]) for v in views]
        trans = [float(np.linalg.norm(T[:3, 3])) for T in T_gt]
        rot = [rotation_angle_deg(T) for T in T_gt]
        static = [t < config.min_translation and r < config.min_rotation_deg
                  for t, r in zip(trans, rot)]
        if any(static):
            k = static.index(True)
            skipped.append({"scene": scene, "ref": ref,
                            "reason": f"near-static: view {views[k]} moved {trans[k]:.3f} m, "
                                      f"{rot[k]:.2f} deg"})
            continue
        sets.append(ViewSet(scene, ref, tuple(views), T_gt, trans, rot))
    return sets, skipped


def evaluate_depth(pred: np.ndarray, gt: np.ndarray, min_depth: float = 0.1,
                   max_depth: float = 10.0) -> Dict[str, float]:
    """Median-scale ``pred`` to ``gt`` and score it, unclipped:
    :func:`spgeo.evaluation.depth_eval.median_scaled_depth` (``abs_rel``,
    ``median_rel``, ``delta_1.25``, ``imae_per_km``, ``irmse_per_km``, ``scale``,
    ``coverage``, ``n_pixels``; NaN with ``coverage`` 0 when no pixel is valid)."""
    from spgeo.evaluation.depth_eval import median_scaled_depth

    return median_scaled_depth(pred, gt, min_depth, max_depth, clip=False)


_SUMMARY_KEYS = ("imae_per_km", "irmse_per_km", "abs_rel", "delta_1.25", "coverage",
                 "rot_err_mean_deg", "tdir_err_mean_deg", "seconds")
_CONST_KEYS = ("imae_per_km", "irmse_per_km", "abs_rel", "delta_1.25", "coverage")


def _nanmean(values) -> float:
    a = np.asarray([np.nan if v is None else v for v in values], float)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else float("nan")


@dataclass
class ScanNetSfMResult:
    """Output of :func:`run_scannet_sfm`.

    Attributes:
        rows: one dict per SfM run: ``scene``, ``ref``, ``views``, ``n_views``,
            ``init``, ``status`` (SfM status, or ``"error"`` with ``error``),
            ``view_status``, the :func:`evaluate_depth` metrics, the
            constant-depth baseline's ``const_imae_per_km``,
            ``const_irmse_per_km``, ``const_abs_rel``, per-view
            ``rot_err_deg`` / ``tdir_err_deg`` and their means
            ``rot_err_mean_deg`` / ``tdir_err_mean_deg``, ground-truth motion
            ``gt_translation`` / ``gt_rotation_deg``, ``seconds``.
        skipped: discarded references with the reason.
        config: the protocol configuration.
    """

    rows: List[Dict[str, object]]
    skipped: List[Dict[str, object]]
    config: ScanNetProtocolConfig

    @property
    def n_sets(self) -> int:
        return len({(r["scene"], r["ref"]) for r in self.rows})

    def summary(self) -> List[Dict[str, object]]:
        """Means per (init, number of supporting views), NaN-metrics of failed
        runs left out (``n_error`` counts them); ``n_ok`` counts SfM status ok.
        A row ``init = "constant depth"`` (n_views 0) gives the median-scaled
        constant-depth baseline on the same references."""
        out: List[Dict[str, object]] = []
        for init in self.config.inits:
            for n in range(1, self.config.max_views + 1):
                rs = [r for r in self.rows if r["init"] == init and r["n_views"] == n]
                if not rs:
                    continue
                row: Dict[str, object] = {"init": init, "n_views": n, "n_runs": len(rs),
                                          "n_ok": sum(r["status"] == "ok" for r in rs),
                                          "n_error": sum(r["status"] == "error" for r in rs)}
                for k in _SUMMARY_KEYS:
                    row[k] = _nanmean(r.get(k) for r in rs)
                out.append(row)
        refs: Dict[Tuple[str, int], Dict[str, object]] = {}
        for r in self.rows:
            refs.setdefault((r["scene"], r["ref"]), r)
        if refs:
            rs = list(refs.values())
            row = {"init": "constant depth", "n_views": 0, "n_runs": len(rs), "n_ok": len(rs),
                   "n_error": 0}
            for k in _SUMMARY_KEYS:
                row[k] = (_nanmean(r.get("const_" + k) for r in rs) if k in _CONST_KEYS
                          else float("nan"))
            out.append(row)
        return out

    def table(self) -> str:
        """Markdown table of :meth:`summary` (iMAE / iRMSE in 1/km, errors in degrees)."""
        c = self.config
        lines = [f"ScanNet few-view SfM: {self.n_sets} view sets (reference every {c.stride} "
                 f"frames, offsets {list(c.offsets)}), {len(self.skipped)} discarded, front-end "
                 f"{c.frontend} at {c.working_size[0]}x{c.working_size[1]}, depth median-scaled, "
                 f"GT in ({c.min_depth}, {c.max_depth}) m"]
        rows = [[r["init"], cell(r["n_views"] or None), cell(r["n_runs"]), cell(r["n_ok"]),
                 cell(r["imae_per_km"]), cell(r["irmse_per_km"]), cell(r["abs_rel"], 3),
                 cell(r["delta_1.25"], 3), cell(r["rot_err_mean_deg"]),
                 cell(r["tdir_err_mean_deg"]), cell(r["seconds"], 1)] for r in self.summary()]
        lines += markdown_table(["init", "views", "runs", "ok", "iMAE [1/km]", "iRMSE [1/km]",
                                 "abs-rel", "d<1.25", "rot err [deg]", "t-dir err [deg]",
                                 "s/run"], rows, "l" + "r" * 10)
        return "\n".join(lines)

    def to_dict(self) -> Dict[str, object]:
        """JSON-friendly dict (config, summary, rows, skipped)."""
        cfg = dataclasses.asdict(self.config)
        cfg["sfm"] = repr(self.config.sfm)
        return {"config": cfg, "summary": self.summary(), "rows": self.rows,
                "skipped": self.skipped}


def _pose_errors(T_est: Sequence[np.ndarray], T_gt: Sequence[np.ndarray]):
    rot, tdir = [], []
    for Te, Tg in zip(T_est, T_gt):
        if not np.all(np.isfinite(Te)):
            rot.append(float("nan"))
            tdir.append(float("nan"))
            continue
        e = relative_pose_errors(Te, Tg)
        rot.append(float(e["rotation_error_deg"]))
        tdir.append(float(e["translation_direction_error_deg"]))
    return rot, tdir


def run_scannet_sfm(root: PathLike, scenes: Optional[Sequence[str]] = None,
                    config: ScanNetProtocolConfig = ScanNetProtocolConfig(),
                    frontend: Optional[PrimitiveFrontEnd] = None,
                    scene_config: Optional[ScanNetConfig] = None
                    ) -> ScanNetSfMResult:
    """Run the few-view SfM protocol on exported ScanNet scenes.

    Args:
        root: folder holding ``<scene_id>/`` folders (or one scene folder).
        scenes: scene ids to evaluate (default: every scene under ``root``).
        config: :class:`ScanNetProtocolConfig`.
        frontend: a ready :class:`~spgeo.frontend.PrimitiveFrontEnd` to use
            instead of ``config.frontend`` at ``config.working_size``.
        scene_config: reader options (:class:`ScanNetConfig`), default: images
            at the depth resolution with the colour intrinsics.
    Returns:
        :class:`ScanNetSfMResult` (``table()`` prints the protocol table).
    Raises:
        FileNotFoundError: a missing root, scene, or scene sub-folder (named).
    """
    from tqdm import tqdm

    from spgeo.frontend import FrontEndConfig, make_frontend

    scene_dirs = _scene_dirs(root, scenes)
    readers = [ScanNetScene(p, scene_config or ScanNetConfig()) for p in scene_dirs]
    all_sets, skipped = _all_view_sets(readers, config)
    if not all_sets:
        raise ValueError(f"no usable view set in {[str(p) for p in scene_dirs]} "
                         f"(stride {config.stride}, offsets {config.offsets}); discarded: "
                         f"{skipped[:5]}")

    fe = frontend or make_frontend(config.frontend,
                                   FrontEndConfig(working_size=tuple(config.working_size)))
    rows: List[Dict[str, object]] = []
    for rd, vs in tqdm(all_sets, desc="ScanNet SfM", disable=not config.progress):
        ref = rd[rd.frame_position(vs.ref)]
        views = [rd[rd.frame_position(v)] for v in vs.views]
        if ref.depth is None:
            raise ValueError(f"scene {vs.scene}: the protocol needs depth (load_depth=True)")
        const_done: Dict[Tuple[int, int], Dict[str, float]] = {}
        for n in range(1, config.max_views + 1):
            for init in config.inits:
                rows.append(_sfm_row(vs, ref, views, n, init, fe, config, const_done))
    return ScanNetSfMResult(rows, skipped, config)


def _scene_dirs(root: PathLike, scenes: Optional[Sequence[str]]) -> List[Path]:
    """The folders of ``scenes`` under ``root`` (default: every scene there);
    ``FileNotFoundError`` names a missing one."""
    root = Path(root).expanduser()
    if scenes:
        if not root.is_dir():
            raise FileNotFoundError(f"ScanNet root folder not found: {root}")
        scene_dirs = []
        for s in scenes:
            p = root / s
            if not p.is_dir():
                raise FileNotFoundError(f"ScanNet scene folder not found: {p}")
            scene_dirs.append(p)
    else:
        scene_dirs = list_scenes(root)
    return scene_dirs


def _all_view_sets(readers: Sequence[ScanNetScene], config: ScanNetProtocolConfig
                   ) -> Tuple[List[Tuple[ScanNetScene, ViewSet]], List[Dict[str, object]]]:
    """:func:`select_view_sets` of every scene (at most ``config.max_samples``
    sets) and the discarded references."""
    all_sets: List[Tuple[ScanNetScene, ViewSet]] = []
    skipped: List[Dict[str, object]] = []
    for rd in readers:
        poses = dict(zip(rd.frame_numbers, rd.ground_truth()))
        sets, skip = select_view_sets(rd.frame_numbers, poses, config, rd.scene_id)
        all_sets += [(rd, s) for s in sets]
        skipped += skip
    if config.max_samples is not None:
        all_sets = all_sets[:int(config.max_samples)]
    log.info("ScanNet protocol: %d view sets, %d references discarded", len(all_sets),
             len(skipped))
    return all_sets, skipped


def _sfm_row(vs: ViewSet, ref, views, n: int, init: str, fe: PrimitiveFrontEnd,
             config: ScanNetProtocolConfig,
             const_done: Dict[Tuple[int, int], Dict[str, float]]) -> Dict[str, object]:
    """One row of :class:`ScanNetSfMResult`: SfM with the first ``n`` views and
    initialisation ``init``, scored; ``const_done`` caches the constant-depth
    baseline per working size."""
    row: Dict[str, object] = {
        "scene": vs.scene, "ref": vs.ref, "views": list(vs.views[:n]), "n_views": n,
        "init": init, "gt_translation": vs.gt_translation[:n],
        "gt_rotation_deg": vs.gt_rotation_deg[:n]}
    t0 = time.perf_counter()
    try:
        res = few_view_sfm(ref.image, [v.image for v in views[:n]], ref.camera, fe,
                           dataclasses.replace(config.sfm, init=init),
                           ref_depth=ref.depth)
    except (ValueError, RuntimeError) as exc:
        log.warning("SfM failed on %s ref %d (%d views, %s): %s", vs.scene, vs.ref,
                    n, init, exc)
        row.update(status="error", error=str(exc),
                   seconds=time.perf_counter() - t0)
        return row
    row["seconds"] = time.perf_counter() - t0
    row["status"] = res.status
    row["view_status"] = list(res.view_status)
    gt = resize_depth_nearest(ref.depth, res.camera.size)
    row.update(evaluate_depth(res.depth, gt, config.min_depth, config.max_depth))
    key = res.camera.size
    if key not in const_done:
        ok = np.isfinite(gt) & (gt > config.min_depth) & (gt < config.max_depth)
        const = np.full(gt.shape, float(np.median(gt[ok])) if ok.any() else np.nan)
        const_done[key] = evaluate_depth(const, gt, config.min_depth,
                                         config.max_depth)
    for k in _CONST_KEYS:
        row["const_" + k] = const_done[key][k]
    rot, tdir = _pose_errors(res.T_ref_view, vs.T_ref_view_gt[:n])
    row["rot_err_deg"], row["tdir_err_deg"] = rot, tdir
    row["rot_err_mean_deg"] = _nanmean(rot)
    row["tdir_err_mean_deg"] = _nanmean(tdir)
    log.debug("%s ref %d n=%d %s: %s iMAE %.2f rot %.2f deg", vs.scene, vs.ref, n,
              init, res.status, row["imae_per_km"], row["rot_err_mean_deg"])
    return row


# ================================================================= script
NAME = "scannet"


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = protocol_parser(None, "ScanNet few-view SfM protocol (SuperPrimitive)", dataset=False)
    ap.add_argument("root", help="folder of exported ScanNet scenes (<scene_id>/color, depth, "
                                 "pose, intrinsic)")
    ap.add_argument("--scenes", nargs="+", default=None, help="scene ids (default: all)")
    ap.add_argument("--max-views", type=int, default=3)
    ap.add_argument("--stride", type=int, default=200)
    ap.add_argument("--offsets", type=int, nargs="+", default=[10, -10, 20, -20, 30, -30])
    ap.add_argument("--frontend", default="classical", choices=("classical", "depth", "onnx"))
    ap.add_argument("--working-size", type=int, nargs=2, default=[320, 240],
                    metavar=("W", "H"))
    ap.add_argument("--inits", nargs="+", default=["identity", "features"],
                    choices=("identity", "features"))
    ap.add_argument("--max-samples", type=int, default=None)
    ap.add_argument("--json", default=None, help="also write rows and summary to this file")
    return ap


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_scannet_sfm`, print its table, write ``--json``."""
    cfg = ScanNetProtocolConfig(stride=args.stride, offsets=tuple(args.offsets),
                                max_views=args.max_views, frontend=args.frontend,
                                working_size=tuple(args.working_size),
                                inits=tuple(args.inits), max_samples=args.max_samples)
    res = run_scannet_sfm(args.root, args.scenes, cfg)
    print(res.table())
    if args.json:
        write_json(args.json, res.to_dict(), indent=1)
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.sfm.scannet ROOT [--scenes ...] [--max-views 3]
    [--stride 200] [--frontend classical] [--max-samples N]``: print the table
    (exit 2 for a missing folder or an unusable configuration)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
