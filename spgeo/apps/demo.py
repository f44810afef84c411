"""The ``spgeo demo`` application: primify embedded data (a synthetic scene and the bundled TUM
fr1_desk frames), integrate, and report shape accuracy against ground truth
after one scale per primitive; writes a picture and a point cloud.  Optional
parts: few-view SfM, depth completion and visual odometry
(:func:`run_vo_demo`: a rendered hand-held synthetic sequence and the 9
bundled TUM frames, Sim(3) ATE against ground truth).

Everything here is offline: no model download, no data outside the package.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..frame import Frame, resize_frame
from ..io.outputs import FileInfo
from ..frontend import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd, make_frontend
from ..frontend.oracle import OracleNormals
from ..metrics.depth import primitive_fit_errors

log = logging.getLogger(__name__)

__all__ = ["DemoConfig", "DemoRow", "DemoResult", "VORow", "VODemoResult", "run_demo",
           "run_vo_demo"]


@config_class
@dataclass(frozen=True)
class DemoConfig:
    """Options of :func:`run_demo`.

    Attributes:
        out_dir: where the PNG / PLY files go.
        synthetic_seed: seed of the synthetic room.
        synthetic_size: ``(width, height)`` of the synthetic render (pixels).
        tum_frame: index of the bundled TUM fr1_desk frame (0..8).
        working_size: integration grid (the authors used 320x240).
        sfm: also run few-view SfM (synthetic view set and bundled TUM frames).
        completion: also run zero-shot depth completion.
        vo: also run the visual odometry (:func:`run_vo_demo`; default True).
        vo_frames: frames of the rendered synthetic VO sequence (default 60,
            i.e. 2 s at 30 fps of hand-held motion).
        vo_size: ``(width, height)`` of the VO input frames and front-end
            working size (pixels; default 160x120).
        vo_frontends: front-ends run on the synthetic VO sequence (default
            ``("classical", "depth")``: monocular, and normals/initial scales
            from the rendered depth as an oracle).
        vo_tum: also run VO on the 9 bundled TUM fr1_desk frames (default True).
        vo_tum_frontends: front-ends run on those frames (default
            ``("classical",)``).
    """

    out_dir: str = "spgeo-demo"
    synthetic_seed: int = 0
    synthetic_size: Tuple[int, int] = (320, 240)
    tum_frame: int = 4
    working_size: Tuple[int, int] = (320, 240)
    sfm: bool = True
    completion: bool = True
    vo: bool = True
    vo_frames: int = 60
    vo_size: Tuple[int, int] = (160, 120)
    vo_frontends: Tuple[str, ...] = ("classical", "depth")
    vo_tum: bool = True
    vo_tum_frontends: Tuple[str, ...] = ("classical",)


@dataclass
class DemoRow:
    scene: str
    frontend: str
    uses_depth: bool
    n_primitives: int
    coverage: float
    median_rel_error: float
    seconds: float


@dataclass
class SfMRow:
    scene: str
    frontend: str
    status: str
    rotation_errors_deg: List[float]
    twoview_rotation_errors_deg: List[float]
    median_scaled_depth_error: float
    seconds: float


_PRIMITIVE_PICTURE = ("{what}: the image, its primitives ({frontend} front-end), their "
                      "normals, the depth integrated from them with one scale per primitive "
                      "fitted to {reference}, and {reference} (PNG)")

#: what the demo's own files are (an output manifest's ``"what"`` and ``"units"``), by
#: their key in :attr:`DemoResult.files`; a VO folder's files are its
#: :meth:`~spgeo.apps.vo_outcome.VORun.describe_files`
DEMO_FILES: Dict[str, Tuple[str, Optional[str]]] = {
    "synthetic_png": (_PRIMITIVE_PICTURE.format(what="the synthetic room", frontend="depth",
                                                reference="the rendered depth"), "metres"),
    "tum_png": (_PRIMITIVE_PICTURE.format(what="the bundled TUM fr1/desk frame",
                                          frontend="depth", reference="the Kinect depth"),
                "metres"),
    "tum_manhattan_png": (_PRIMITIVE_PICTURE.format(
        what="the bundled TUM fr1/desk frame", frontend="manhattan (vanishing-point normals)",
        reference="the Kinect depth"), "metres"),
    "tum_ply": ("the TUM frame's primitives (depth front-end) at the scales fitted to the "
                "Kinect depth, coloured points in the ground truth's world frame (PLY)",
                "metres"),
    "synthetic_sfm_png": ("few-view SfM on the synthetic room (classical front-end): the "
                          "reference, its depth median-scaled to the ground truth, the ground "
                          "truth (PNG)", "metres"),
    "tum_fr1_desk_sfm_png": ("few-view SfM on the TUM frames (classical front-end): the "
                             "reference, its depth median-scaled to the Kinect depth, the "
                             "Kinect depth (PNG)", "metres"),
}


@dataclass
class DemoResult:
    """The demo's tables and files: ``files`` by key (:data:`DEMO_FILES`, and
    ``vo_<sequence>_<front-end>`` folders), ``described`` what every file is (the
    manifest's ``"files"``, :meth:`spgeo.io.outputs.StagedFolder.commit`)."""

    rows: List[DemoRow]
    files: Dict[str, str] = field(default_factory=dict)
    described: Dict[Path, FileInfo] = field(default_factory=dict)
    sfm_rows: List[SfMRow] = field(default_factory=list)
    extra_tables: Dict[str, str] = field(default_factory=dict)
    vo_rows: List["VORow"] = field(default_factory=list)

    def sfm_table(self) -> str:
        lines = [f"{'scene':12s} {'front-end':22s} {'status':8s} {'rot.err deg (spgeo)':>22s} "
                 f"{'rot.err deg (SIFT 2-view)':>26s} {'depth err':>9s} {'time s':>7s}"]
        for r in self.sfm_rows:
            fmt = lambda xs: ", ".join(f"{x:.2f}" for x in xs)  # noqa: E731
            lines.append(f"{r.scene:12s} {r.frontend:22s} {r.status:8s} "
                         f"{fmt(r.rotation_errors_deg):>22s} "
                         f"{fmt(r.twoview_rotation_errors_deg):>26s} "
                         f"{r.median_scaled_depth_error:9.4f} {r.seconds:7.1f}")
        return "\n".join(lines)

    def table(self) -> str:
        lines = [f"{'scene':12s} {'front-end':24s} {'depth?':6s} {'prims':>5s} {'cover':>6s} "
                 f"{'med.rel.err':>11s} {'time s':>7s}"]
        for r in self.rows:
            lines.append(f"{r.scene:12s} {r.frontend:24s} {'yes' if r.uses_depth else 'no':6s} "
                         f"{r.n_primitives:5d} {r.coverage:6.2f} {r.median_rel_error:11.2e} "
                         f"{r.seconds:7.2f}")
        return "\n".join(lines)


def _evaluate(scene: str, fe: PrimitiveFrontEnd, image, camera, depth_in, depth_gt,
              rows: List[DemoRow]):
    import cv2

    t0 = time.perf_counter()
    prims = fe.primify(image, camera, depth_in if fe.uses_depth else None)
    dt = time.perf_counter() - t0
    cam = prims.camera
    gt = depth_gt
    if gt.shape != cam.shape:
        gt = cv2.resize(gt, cam.size, interpolation=cv2.INTER_NEAREST)
    m = primitive_fit_errors(prims, gt)
    rows.append(DemoRow(scene, fe.name, fe.uses_depth, len(prims), prims.coverage_fraction(),
                        m.get("median_rel", float("nan")), dt))
    log.info("%s / %s: %d primitives, median rel. error %.4f", scene, fe.name, len(prims),
             m.get("median_rel", float("nan")))
    return prims, gt


def _picture(image, prims, gt, path: Path) -> None:
    import cv2

    from ..viz import colorize_depth, colorize_labels, colorize_normals, save_png, side_by_side

    cam = prims.camera
    img = cv2.resize(np.asarray(image, np.float32), cam.size, interpolation=cv2.INTER_AREA)
    normals = np.full(cam.shape + (3,), np.nan)
    if prims.normals is not None:
        normals.reshape(-1, 3)[prims.pixels] = prims.normals
    s, _ = prims.fit_log_scales(gt)
    s = np.where(np.isfinite(s), s, 0.0)
    depth = prims.with_log_scales(s).depth_map()
    ok = np.isfinite(gt) & (gt > 0)
    lo, hi = (np.percentile(gt[ok], 2), np.percentile(gt[ok], 98)) if ok.any() else (None, None)
    pic = side_by_side([img, colorize_labels(prims.label_image()), colorize_normals(normals),
                        colorize_depth(depth, lo, hi), colorize_depth(gt, lo, hi)],
                       ["image", f"{len(prims)} primitives", "normals", "integrated depth",
                        "ground truth"])
    save_png(path, pic)


def run_demo(config: DemoConfig = DemoConfig()) -> DemoResult:
    """Run the demo; returns the accuracy table and the written files."""
    from .. import synthetic
    from ..datasets import load_bundled_tum

    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: List[DemoRow] = []
    files: Dict[str, str] = {}
    fe_cfg = FrontEndConfig(working_size=config.working_size)

    # 1. synthetic room: ground truth for everything
    scene = synthetic.SyntheticScene.generate(config.synthetic_seed)
    cam = synthetic.default_camera(*config.synthetic_size)
    poses = synthetic.make_trajectory(1, config.synthetic_seed)
    view = scene.render(cam, poses[0])
    # offline (classical, manhattan: vanishing-point normals), sensor depth, oracle
    frontends = [make_frontend("classical", fe_cfg), make_frontend("manhattan", fe_cfg),
                 make_frontend("depth", fe_cfg),
                 PrimitiveFrontEnd(LabelSegmenter(view.surface_ids), OracleNormals(view.normals),
                                   fe_cfg, name="oracle (GT ids+normals)")]
    best = None
    for fe in frontends:
        prims, gt = _evaluate("synthetic", fe, view.rgb, cam, view.depth, view.depth, rows)
        if fe.name.startswith("depth"):
            best = (prims, gt)
    _picture(view.rgb, best[0], best[1], out / "synthetic_primitives.png")
    files["synthetic_png"] = str(out / "synthetic_primitives.png")

    # 2. real data: the bundled TUM fr1_desk frames (sensor depth as reference)
    seq = load_bundled_tum()
    frame = seq[config.tum_frame]
    for fe in frontends[:3]:
        prims, gt = _evaluate("tum_fr1_desk", fe, frame.image, frame.camera, frame.depth,
                              frame.depth, rows)
        if fe.name.startswith("depth"):
            best = (prims, gt)
        elif fe.name == "manhattan":    # the offline shape prior beside the depth one
            _picture(frame.image, prims, gt, out / "tum_manhattan_primitives.png")
            files["tum_manhattan_png"] = str(out / "tum_manhattan_primitives.png")
    _picture(frame.image, best[0], best[1], out / "tum_primitives.png")
    files["tum_png"] = str(out / "tum_primitives.png")
    prims, gt = best
    s, _ = prims.fit_log_scales(gt)
    keep = np.flatnonzero(np.isfinite(s))
    cloud = prims.subset(keep).with_log_scales(s[keep]).point_cloud(
        resize_frame(frame, prims.camera.size).image)
    if frame.T_world_cam is not None:
        cloud = cloud.transformed(frame.T_world_cam)
    cloud.save_ply(out / "tum_primitives.ply")
    files["tum_ply"] = str(out / "tum_primitives.ply")
    result = DemoResult(rows, files)
    if config.completion:
        _demo_completion(config, view, cam, seq, result)
    if config.sfm:
        _demo_sfm(config, scene, cam, seq, result)
    if config.vo:
        vo = run_vo_demo(config, scene=scene, tum=seq)
        result.vo_rows = vo.rows
        result.files.update(vo.files)
        result.described.update(vo.described)
        result.extra_tables[VO_TABLE_TITLE] = vo.table()
    result.described.update({Path(p): FileInfo(*DEMO_FILES[k])
                             for k, p in result.files.items() if k in DEMO_FILES})
    return result


def _demo_completion(config: DemoConfig, view, cam: PinholeCamera, seq, result: DemoResult) -> None:
    """Zero-shot depth completion from 150 sparse points at FAST keypoints (1% noise)
    against the two baselines, on the synthetic view and a bundled TUM frame."""
    from ..completion import CompletionConfig, complete_depth
    from ..completion.baselines import ip_basic_completion, linear_interpolation_completion
    from ..completion.sparse_points import keypoint_sparse_depth
    from ..frontend.oracle import oracle_frontend
    from ..metrics.depth import void_metrics

    lines = [f"{'scene':12s} {'method':28s} {'MAE mm':>8s} {'RMSE mm':>8s} {'iMAE':>7s} "
             f"{'iRMSE':>7s}"]
    frame = seq[config.tum_frame]
    cases = [("synthetic", view.rgb, view.depth.astype(np.float64), cam,
              oracle_frontend(view.surface_ids, view.normals)),
             ("tum_fr1_desk", frame.image, np.nan_to_num(frame.depth.astype(np.float64)),
              frame.camera, None)]
    for name, image, gt, camera, oracle in cases:
        sparse = keypoint_sparse_depth(image, gt, 150, rel_noise=0.01, seed=0)
        shapes_only = CompletionConfig(choose="none")
        preds = {"spgeo (default: held-out)": complete_depth(image, sparse, camera).depth,
                 "spgeo classical primitives": complete_depth(image, sparse, camera,
                                                              config=shapes_only).depth,
                 "spgeo manhattan primitives": complete_depth(image, sparse, camera, "manhattan",
                                                              config=shapes_only).depth}
        if oracle is not None:
            preds["spgeo ORACLE segments+normals"] = complete_depth(
                image, sparse, camera, oracle, frontend_depth=gt).depth
        preds["linear interpolation"] = linear_interpolation_completion(sparse)
        preds["IP-Basic"] = ip_basic_completion(sparse)
        for method, pred in preds.items():
            m = void_metrics(pred, gt)
            lines.append(f"{name:12s} {method:28s} {m['mae_mm']:8.1f} {m['rmse_mm']:8.1f} "
                         f"{m['imae_per_km']:7.2f} {m['irmse_per_km']:7.2f}")
    result.extra_tables["Depth completion from 150 sparse points (1% noise), GT in [0.2, 5] m; "
                        "iMAE/iRMSE in 1/km"] = "\n".join(lines)


def _rotation_errors(T_est: List[np.ndarray], T_gt: List[np.ndarray]) -> List[float]:
    from ..geometry import rotation_angle_deg

    return [rotation_angle_deg(a[:3, :3].T @ b[:3, :3]) for a, b in zip(T_est, T_gt)]


def _demo_sfm(config: DemoConfig, scene, cam: PinholeCamera, seq, result: DemoResult) -> None:
    """Few-view SfM: a synthetic view set (7.5 deg, 5% baseline) and the bundled
    TUM frames 0 (reference), 4 and 8, against ground truth and SIFT two-view."""
    from .. import synthetic
    from ..geometry import relative_pose
    from ..sfm import SfMConfig, few_view_sfm
    from ..twoview import estimate_relative_pose
    from ..viz import colorize_depth, save_png, side_by_side

    T_ref, T_views = synthetic.make_view_set(scene, cam, 2, 7.5, 0.05, config.synthetic_seed)
    ref = scene.render(cam, T_ref, supersample=2)
    views = [scene.render(cam, T, supersample=2) for T in T_views]
    cases = [("synthetic", ref.rgb, [v.rgb for v in views], cam, ref.depth,
              [relative_pose(T_ref, T) for T in T_views])]
    tum_ref, tum_views = seq[0], [seq[4], seq[8]]
    cases.append(("tum_fr1_desk", tum_ref.image, [v.image for v in tum_views], tum_ref.camera,
                  tum_ref.depth, [relative_pose(tum_ref.T_world_cam, v.T_world_cam)
                                  for v in tum_views]))
    fe_cfg = FrontEndConfig(working_size=config.working_size)
    for scene_name, ref_img, view_imgs, camera, ref_depth, gt in cases:
        twoview = [estimate_relative_pose(ref_img, v, camera) for v in view_imgs]
        tv_err = _rotation_errors([r.T_ref_tgt if r.T_ref_tgt is not None else np.eye(4)
                                   for r in twoview], gt)
        for fe in (make_frontend("classical", fe_cfg), make_frontend("depth", fe_cfg)):
            t0 = time.perf_counter()
            res = few_view_sfm(ref_img, view_imgs, camera, fe, SfMConfig(marginals=False),
                               ref_depth=ref_depth if fe.uses_depth else None)
            dt = time.perf_counter() - t0
            small = resize_frame(Frame(ref_img, camera, 0.0, depth=ref_depth), res.camera.size,
                                 keep_depth=True)
            gt_d = small.depth
            ok = np.isfinite(res.depth) & np.isfinite(gt_d) & (gt_d > 0)
            med = float("nan")
            if ok.any():
                k = np.median(gt_d[ok] / res.depth[ok])
                med = float(np.median(np.abs(res.depth[ok] * k / gt_d[ok] - 1)))
            result.sfm_rows.append(SfMRow(scene_name, fe.name, res.status,
                                          _rotation_errors(res.T_ref_view, gt), tv_err, med, dt))
            if fe.name == "classical":
                k = np.nanmedian(gt_d[ok] / res.depth[ok]) if ok.any() else 1.0
                lo, hi = np.nanpercentile(gt_d[gt_d > 0], [2, 98]) if np.any(gt_d > 0) else (None, None)
                pic = side_by_side([small.image,
                                    colorize_depth(res.depth * k, lo, hi), colorize_depth(gt_d, lo, hi)],
                                   ["reference", "SfM depth (median-scaled)", "ground truth"])
                path = Path(config.out_dir) / f"{scene_name}_sfm.png"
                save_png(path, pic)
                result.files[f"{scene_name}_sfm_png"] = str(path)


VO_TABLE_TITLE = "Visual odometry (spgeo.odometry): per-frame Sim(3) ATE against ground truth"


@dataclass
class VORow:
    """One VO run of :func:`run_vo_demo`.

    Attributes:
        sequence: ``"synthetic"`` or ``"tum_fr1_desk"``.
        frontend: the front-end's name.
        n_frames: frames given to :meth:`Odometry.track`.
        duration_s: last minus first timestamp (seconds).
        init_frame: frame that became keyframe 1 (end of the two-view
            initialisation; with sensor depth, which has none, the keyframe policy's
            first keyframe); None if the run made no keyframe 1.
        n_tracked: frames whose final status is not ``"lost"``.
        n_keyframes: keyframes created (keyframe 0 included).
        n_lost: frames whose final status is ``"lost"``.
        ate_rmse_m: per-frame ATE RMSE (metres) over the tracked frames after
            Sim(3) alignment to ground truth; NaN when it cannot be computed.
        ate_percent: that RMSE in % of the ground-truth path length.
        trajectory_length_m: ground-truth path length of the evaluated frames (m).
        sim3_scale: scale of the alignment (1 = metric estimate).
        fps: frames per wall-clock second of the VO loop (resizing included;
            rendering / loading excluded).
        seconds: wall time of that loop (s).
        out_dir: folder written by :meth:`spgeo.apps.vo_outcome.VORun.save`
            (trajectory, keyframes, status, report with the ATE, keyframe
            clouds, ``groundtruth.txt`` of the frames not lost).
    """

    sequence: str
    frontend: str
    n_frames: int
    duration_s: float
    init_frame: Optional[int]
    n_tracked: int
    n_keyframes: int
    n_lost: int
    ate_rmse_m: float
    ate_percent: float
    trajectory_length_m: float
    sim3_scale: float
    fps: float
    seconds: float
    out_dir: str


@dataclass
class VODemoResult:
    """Rows and written folders of :func:`run_vo_demo`."""

    rows: List[VORow] = field(default_factory=list)
    files: Dict[str, str] = field(default_factory=dict)
    described: Dict[Path, FileInfo] = field(default_factory=dict)

    def table(self) -> str:
        lines = [f"{'sequence':12s} {'front-end':20s} {'frames':>6s} {'secs':>5s} {'init@':>5s} "
                 f"{'tracked':>7s} {'kfs':>4s} {'lost':>4s} {'path m':>6s} {'ATE m':>7s} "
                 f"{'ATE %':>6s} {'scale':>6s} {'FPS':>5s}"]
        for r in self.rows:
            init = "-" if r.init_frame is None else str(r.init_frame)
            lines.append(f"{r.sequence:12s} {r.frontend:20s} {r.n_frames:6d} {r.duration_s:5.2f} "
                         f"{init:>5s} {r.n_tracked:7d} {r.n_keyframes:4d} {r.n_lost:4d} "
                         f"{r.trajectory_length_m:6.3f} {r.ate_rmse_m:7.4f} "
                         f"{r.ate_percent:6.2f} {r.sim3_scale:6.3f} {r.fps:5.1f}")
        lines.append("ATE: RMSE of the camera centres of the frames not lost after Sim(3) "
                     "alignment (evo); ATE % = of the ground-truth path length ('path m')\n"
                     "init@: frame that became keyframe 1 (two-view initialisation; with "
                     "sensor depth the policy's first keyframe); scale: Sim(3) scale (1 = "
                     "metric); FPS excludes rendering/loading")
        return "\n".join(lines)


def _run_vo(sequence: str, frames: list, frontend: str, config: DemoConfig,
            out_root: Path) -> Tuple[VORow, Dict[Path, FileInfo]]:
    """One :func:`spgeo.apps.vo_run.run_odometry` run, saved to
    ``out_root/<sequence>_<frontend>``: its row and what its files are."""
    from ..vo import OdometryConfig
    from .vo_run import VORunConfig, run_odometry

    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=tuple(config.vo_size)),
                                           frontend=frontend, progress=False))
    res = run.result()
    good = np.array([s != "lost" for s in res.statuses])
    ate = run.ate()
    per_frame = None if ate is None else ate.get("per-frame")
    nan = float("nan")
    out = out_root / f"{sequence}_{frontend}"
    paths = run.save(out, ate=ate)      # with groundtruth.txt: the frames the ATE evaluates
    init = next((i for i, k in enumerate(np.cumsum(res.is_keyframe)) if k == 2), None)
    row = VORow(sequence, run.frontend_name, run.n_frames,
                float(run.timestamps[-1] - run.timestamps[0]), init, int(good.sum()),
                int(res.is_keyframe.sum()), int((~good).sum()),
                per_frame.rmse if per_frame else nan,
                per_frame.rmse_percent_of_length if per_frame else nan,
                per_frame.trajectory_length if per_frame else nan,
                per_frame.scale if per_frame else nan, run.fps, run.wall_seconds, str(out))
    log.info("VO %s / %s: %d frames, %d keyframes, %d lost, ATE %.4f m (%.2f%%), %.1f FPS",
             sequence, row.frontend, row.n_frames, row.n_keyframes, row.n_lost, row.ate_rmse_m,
             row.ate_percent, row.fps)
    return row, run.describe_files(paths)


def _add_vo(result: VODemoResult, run: Tuple[VORow, Dict[Path, FileInfo]]) -> None:
    result.rows.append(run[0])
    result.described.update(run[1])


def run_vo_demo(config: DemoConfig = DemoConfig(), scene=None, tum=None) -> VODemoResult:
    """Monocular VO on embedded data; trajectories go to ``<out_dir>/vo/<sequence>_<front-end>/``.

    * ``synthetic``: ``config.vo_frames`` frames of the hand-held trajectory
      :func:`spgeo.synthetic.make_trajectory` (seed ``config.synthetic_seed``)
      rendered at ``config.vo_size`` (2x supersampled) in the room of the same
      seed, with each front-end of ``config.vo_frontends``.
    * ``tum_fr1_desk`` (if ``config.vo_tum``): the 9 bundled TUM frames resized
      to ``config.vo_size``, with each front-end of ``config.vo_tum_frontends``.
      So few frames mostly exercise the initialisation (see ``init@``).

    Args:
        config: :class:`DemoConfig` (its ``vo_*`` fields, ``out_dir`` and
            ``synthetic_seed``).
        scene: the :class:`~spgeo.synthetic.SyntheticScene` to render (default:
            generated from ``config.synthetic_seed``).
        tum: the bundled TUM sequence if already loaded.
    """
    from .. import synthetic

    if config.vo_frames < 3:
        raise ValueError(f"DemoConfig.vo_frames must be >= 3, got {config.vo_frames}")
    out_root = Path(config.out_dir) / "vo"
    result = VODemoResult()
    if config.vo_frontends:
        if scene is None:
            scene = synthetic.SyntheticScene.generate(config.synthetic_seed)
        cam = synthetic.default_camera(*config.vo_size)
        poses = synthetic.make_trajectory(config.vo_frames, config.synthetic_seed)
        frames = synthetic.render_frames(scene, cam, poses, supersample=2)
        for fe in config.vo_frontends:
            _add_vo(result, _run_vo("synthetic", frames, fe, config, out_root))
    if config.vo_tum and config.vo_tum_frontends:
        if tum is None:
            from ..datasets import load_bundled_tum

            tum = load_bundled_tum()
        frames = list(tum)
        for fe in config.vo_tum_frontends:
            _add_vo(result, _run_vo("tum_fr1_desk", frames, fe, config, out_root))
    for r in result.rows:
        result.files[f"vo_{Path(r.out_dir).name}"] = r.out_dir
    return result

