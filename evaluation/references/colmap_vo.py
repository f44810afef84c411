"""COLMAP (pycolmap) incremental-SfM reference trajectory on a VO sequence.

:func:`run_colmap_vo` gives the frames a VO run sees to COLMAP's standard
sparse pipeline and returns one camera-to-world pose per frame:

1. **Frames**: undistorted if needed, resized like the VO input
   (:func:`spgeo.frame.resize_frame`, default 160x120), written as PNGs.
2. **Features**: CPU SIFT, one shared PINHOLE camera with the frames' known,
   fixed intrinsics (COLMAP's pixel centres are at half-integers: ``cx + 0.5``).
3. **Matching**: sequential (next ``overlap`` frames, plus quadratic overlap),
   geometric verification; no vocabulary-tree loop detection by default.
4. **Mapping**: incremental, intrinsics fixed, several models allowed; the
   largest model gives the poses, the sizes of the others are reported.

Poses are ``T_world_cam = inv(cam_from_world)`` with the first registered
frame of the largest model as the identity, at an arbitrary scale (use
Sim(3)-aligned ATE, :meth:`ColmapVOResult.ate`); registered frames are
``ok``, the others ``lost`` (:class:`~spgeo.trajectory.FrameStatus`).

Deterministic: one thread, fixed seeds, CPU SIFT, brute-force matching
(:mod:`.colmap_common`).  Command line: ``spgeo eval colmap_vo --dataset
7scenes PATH --frames 0:300 --resolution 160x120 --out DIR``.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np
from tqdm import tqdm

from spgeo.camera import PinholeCamera
from spgeo.apps.args import add_verbose_argument, parse_resolution
from spgeo.frame import Frame, resize_frame
from spgeo.geometry import invert_pose
from spgeo.trajectory import FrameStatus, Trajectory

from spgeo.evaluation.trajectory import (AteResult, TrajectoryLike, TrajectoryResult, ate_sim3,
                                         default_max_time_diff)
from spgeo.evaluation.runner import open_sequence, protocol_parser, run_protocol, write_json
from .colmap_common import (ColmapOptions, cam_from_world, extract_sift, incremental_mapping,
                            load_images, mapper_options, quiet, sift_matching_options,
                            verification_options, workspace)

__all__ = ["ColmapVOConfig", "ColmapVOResult", "COLMAP_VO_STATUSES", "run_colmap_vo", "with_ground_truth",
           "check_resolution", "build_parser", "run", "main"]

logger = logging.getLogger(__name__)

#: Per-frame statuses of :class:`ColmapVOResult` (registered, unregistered).
COLMAP_VO_STATUSES = (FrameStatus.OK.value, FrameStatus.LOST.value)

ImageOrFrame = Union[Frame, np.ndarray]


# ==================================================================== config
def check_resolution(resolution: Optional[Tuple[int, int]],
                     name: str) -> Optional[Tuple[int, int]]:
    """``(width, height)`` as ints, or None; raises ``ValueError`` (naming
    ``name``) unless both are positive."""
    if resolution is None:
        return None
    w, h = (int(v) for v in resolution)
    if w <= 0 or h <= 0:
        raise ValueError(f"{name} must be positive, got {resolution}")
    return (w, h)


@dataclass(frozen=True)
class ColmapVOConfig(ColmapOptions):
    """Options of :func:`run_colmap_vo` (COLMAP's own defaults in brackets; the
    fields shared with the few-view reference are
    :class:`~.colmap_common.ColmapOptions`; ``max_ratio``, ``min_num_matches``,
    ``init_min_num_inliers``, ``num_threads``, ``random_seed`` and ``quiet``
    keep its defaults).

    Attributes:
        resolution: ``(width, height)`` in pixels the frames are resized to
            (``cv2.INTER_AREA``), default (160, 120) like the VO; None keeps the
            frames' size.
        overlap: sequential matching: each frame is matched with the next
            ``overlap`` frames, default 10 [10].
        quadratic_overlap: also match frame ``i`` with ``i + 2^k`` for
            ``k < overlap``, default True [True].
        loop_detection: vocabulary-tree loop detection, default False [False];
            needs ``vocab_tree_path``.
        vocab_tree_path: COLMAP vocabulary tree file for ``loop_detection``.
        max_num_features: SIFT features per image, default 4096 [8192].
        ransac_max_error_px: epipolar RANSAC threshold of the geometric
            verification, in pixels of the resized images, default 1.0 [4.0].
        init_min_tri_angle_deg: triangulation angle of the initial pair in
            degrees, default 2.0 [16]: hand-held sequences have small baselines.
        filter_min_tri_angle_deg: minimum triangulation angle of kept 3-D
            points in degrees, default 1.5 [1.5].
        abs_pose_min_num_inliers: 2D-3D inliers to register a frame, default 20 [30].
        ignore_two_view_tracks: do not triangulate tracks seen by two frames
            only, default True [True].
        min_model_size: smallest model COLMAP keeps, in frames, default 3 [10].
        max_num_models: most models COLMAP builds, default 50 [50].
        ba_global_frames_ratio: global bundle adjustment each time the model
            grew by this factor, default 1.1 [1.1].
        ba_global_max_refinements: global bundle-adjustment / retriangulation
            rounds, default 5 [5].
        ba_global_max_num_iterations: solver iterations of a global bundle
            adjustment, default 50 [-1 = COLMAP's internal default].
        ba_global_function_tolerance: relative cost change that stops a global
            bundle adjustment, default 1e-6 [0.0].
        show_progress: tqdm bar while the frames are prepared, default False.
    """

    resolution: Optional[Tuple[int, int]] = (160, 120)
    overlap: int = 10
    quadratic_overlap: bool = True
    loop_detection: bool = False
    vocab_tree_path: Optional[str] = None
    max_num_features: int = 4096
    ransac_max_error_px: float = 1.0
    init_min_tri_angle_deg: float = 2.0
    filter_min_tri_angle_deg: float = 1.5
    abs_pose_min_num_inliers: int = 20
    ignore_two_view_tracks: bool = True
    min_model_size: int = 3
    max_num_models: int = 50
    ba_global_frames_ratio: float = 1.1
    ba_global_max_refinements: int = 5
    ba_global_max_num_iterations: int = 50
    ba_global_function_tolerance: float = 1e-6
    show_progress: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "resolution",
                           check_resolution(self.resolution, "ColmapVOConfig.resolution"))
        if int(self.overlap) < 1:
            raise ValueError(f"ColmapVOConfig.overlap must be >= 1, got {self.overlap}")
        if self.loop_detection and not self.vocab_tree_path:
            raise ValueError("ColmapVOConfig.loop_detection needs vocab_tree_path (a COLMAP "
                             "vocabulary tree file)")
        if int(self.min_model_size) < 2:
            raise ValueError("ColmapVOConfig.min_model_size must be >= 2")
        super().__post_init__()


# ==================================================================== result
@dataclass
class ColmapVOResult(TrajectoryResult):
    """Output of :func:`run_colmap_vo`.

    Attributes:
        trajectory: one entry per frame: camera-to-world pose in the largest
            model (first registered frame = identity, arbitrary scale), NaN and
            status ``lost`` when the frame is not registered in that model.
        names: frame names.
        camera: the (resized, undistorted) camera given to COLMAP, fixed.
        num_models: models COLMAP built (0 when mapping failed).
        model_sizes: registered frames per model, largest first.
        num_points3D: 3-D points of the largest model.
        mean_reprojection_error: of the largest model, in pixels of the resized
            images (NaN without a model).
        num_keypoints: SIFT features per frame.
        timings: seconds per stage (``prepare``, ``extract``, ``match``,
            ``map``, ``total``).
        message: why frames stay unregistered / mapping failed ("" if none).
        config: the options used.
    """

    trajectory: Trajectory
    names: List[str]
    camera: PinholeCamera
    num_models: int = 0
    model_sizes: List[int] = field(default_factory=list)
    num_points3D: int = 0
    mean_reprojection_error: float = float("nan")
    num_keypoints: List[int] = field(default_factory=list)
    timings: Dict[str, float] = field(default_factory=dict)
    message: str = ""
    config: ColmapVOConfig = field(default_factory=ColmapVOConfig)

    @property
    def registered(self) -> np.ndarray:
        """(n,) bool: frames with a pose in the largest model."""
        return self.trajectory.tracked

    @property
    def T_world_cam(self) -> List[Optional[np.ndarray]]:
        """Per frame its 4x4 camera-to-world pose, None when unregistered."""
        return [T.copy() if ok else None for T, ok in zip(self.poses, self.registered)]

    @property
    def num_registered(self) -> int:
        return int(self.registered.sum())

    @property
    def registered_fraction(self) -> float:
        return self.num_registered / self.n_frames if self.n_frames else float("nan")

    @property
    def fps(self) -> float:
        """Frames per second over the whole pipeline (preparation included)."""
        total = self.timings.get("total", 0.0)
        return self.n_frames / total if total > 0 else float("nan")

    def ate(self, gt_poses: Union[Sequence[Optional[np.ndarray]], TrajectoryLike],
            gt_timestamps: Optional[Sequence[float]] = None,
            max_time_diff: Optional[float] = None) -> AteResult:
        """Per-frame Sim(3)-aligned ATE (metres) over the registered frames.

        Args:
            gt_poses: one ground-truth camera-to-world pose per frame of this
                result (None where unknown) when ``gt_timestamps`` is None, else
                the ground-truth poses at ``gt_timestamps``; a
                :class:`~spgeo.trajectory.Trajectory` is accepted too.
            gt_timestamps: see ``gt_poses``.
            max_time_diff: association tolerance, default
                :func:`~spgeo.evaluation.trajectory.default_max_time_diff` of the timestamps.
        Raises ``ValueError`` when fewer than 3 registered frames have ground truth.
        """
        if hasattr(gt_poses, "timestamps") and hasattr(gt_poses, "poses"):
            gt: TrajectoryLike = gt_poses  # type: ignore[assignment]
        elif gt_timestamps is None:
            gt_list = list(gt_poses)  # type: ignore[arg-type]
            if len(gt_list) != self.n_frames:
                raise ValueError(f"ColmapVOResult.ate: {len(gt_list)} ground-truth poses for "
                                 f"{self.n_frames} frames (pass gt_timestamps for other lists)")
            keep = [i for i, T in enumerate(gt_list) if T is not None]
            gt = (self.timestamps[keep], [np.asarray(gt_list[i], np.float64) for i in keep])
        else:
            gt = (gt_timestamps, gt_poses)  # type: ignore[assignment]
        tol = default_max_time_diff(self.timestamps) if max_time_diff is None else max_time_diff
        return ate_sim3((self.timestamps, self.poses), gt, max_time_diff=tol, label="per-frame")

    def save_tum(self, path: Union[str, Path]) -> Path:
        """Write the registered frames as a TUM file (camera-to-world) and every
        frame's status into ``<stem>.status.txt`` beside it.  Returns ``path``."""
        header = ["COLMAP incremental SfM reference (pycolmap, SIFT, sequential matching, "
                  "fixed PINHOLE intrinsics); largest model; monocular: scale arbitrary",
                  f"frames {self.n_frames}, registered {self.num_registered}, "
                  f"models {self.num_models} {self.model_sizes}; camera {self.camera}"]
        return self.trajectory.save(path, header=header)

    def table(self) -> str:
        """One line: frames registered, models, points, time."""
        return (f"COLMAP reference: {self.num_registered}/{self.n_frames} frames registered, "
                f"{self.num_models} model(s) {self.model_sizes}, {self.num_points3D} points, "
                f"{self.timings['total']:.1f} s ({self.fps:.1f} FPS)"
                + (f"; {self.message}" if self.message else ""))

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no poses)."""
        return {"n_frames": self.n_frames, "n_registered": self.num_registered,
                "registered_fraction": self.registered_fraction, "num_models": self.num_models,
                "model_sizes": list(self.model_sizes), "num_points3D": self.num_points3D,
                "mean_reprojection_error_px": self.mean_reprojection_error,
                "mean_keypoints": float(np.mean(self.num_keypoints)) if self.num_keypoints
                else 0.0, "fps": self.fps, "timings_s": dict(self.timings),
                "camera": self.camera.to_dict(), "message": self.message,
                "config": asdict(self.config)}


# ================================================================== helpers
def _as_frames(frames: Iterable[ImageOrFrame], camera: Optional[PinholeCamera],
               timestamps: Optional[Sequence[float]]) -> Iterable[Frame]:
    """Frames from Frame objects or raw images (+ camera, timestamps)."""
    for i, f in enumerate(frames):
        if isinstance(f, Frame):
            yield f
            continue
        if camera is None:
            raise ValueError("run_colmap_vo: camera is required for raw images")
        ts = float(timestamps[i]) if timestamps is not None else float(i)
        from spgeo.images import to_float_image

        yield Frame(image=to_float_image(f), camera=camera, timestamp=ts, name=f"{i:06d}")


def _write_frames(frames: Iterable[Frame], image_dir: Path, resolution, show_progress: bool):
    """Resize and write the frames as ``000000.png, ...``; returns (file names,
    frame names, timestamps, the resized camera).  Raises ``ValueError`` for
    frames of different cameras."""
    names: List[str] = []
    frame_names: List[str] = []
    stamps: List[float] = []
    cam: Optional[PinholeCamera] = None
    first_cam: Optional[PinholeCamera] = None
    for i, f in enumerate(tqdm(frames, disable=not show_progress, desc="colmap frames",
                               unit="frame")):
        if first_cam is None:
            first_cam = f.camera
        elif f.camera != first_cam:
            raise ValueError(f"run_colmap_vo: frame {i} ({f.name!r}) has camera {f.camera}, "
                             f"the first frame {first_cam}: one shared camera is required")
        small = resize_frame(f, resolution)
        cam = small.camera
        arr = load_images([small.image], cam)[0]
        name = f"{i:06d}.png"
        if not cv2.imwrite(str(image_dir / name), cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)):
            raise OSError(f"cannot write {image_dir / name}")
        names.append(name)
        frame_names.append(f.name or f"{i:06d}")
        stamps.append(float(f.timestamp))
    return names, frame_names, stamps, cam


def _extract_and_match(db_path: Path, image_dir: Path, names: List[str], cam: PinholeCamera,
                       config: ColmapVOConfig, timings: Dict[str, float]) -> None:
    import pycolmap

    pycolmap.set_random_seed(int(config.random_seed))
    timings["extract"] = extract_sift(db_path, image_dir, names, cam, config.num_threads,
                                      config.max_num_features)
    mo = sift_matching_options(config.num_threads, config.max_ratio)
    po = pycolmap.SequentialPairingOptions()
    po.overlap = int(config.overlap)
    po.quadratic_overlap = bool(config.quadratic_overlap)
    po.loop_detection = bool(config.loop_detection)
    if config.loop_detection:
        po.vocab_tree_path = str(config.vocab_tree_path)
    po.num_threads = int(config.num_threads)
    t = time.perf_counter()
    pycolmap.match_sequential(db_path, matching_options=mo, pairing_options=po,
                              verification_options=verification_options(config),
                              device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t


def _vo_mapper_options(config: ColmapVOConfig):
    """:func:`~.colmap_common.mapper_options` with several models and the VO's
    bundle-adjustment schedule."""
    po = mapper_options(config)
    po.multiple_models = True
    po.max_num_models = int(config.max_num_models)
    po.min_model_size = int(config.min_model_size)
    po.triangulation.ignore_two_view_tracks = bool(config.ignore_two_view_tracks)
    po.ba_global_frames_ratio = float(config.ba_global_frames_ratio)
    po.ba_global_points_ratio = float(config.ba_global_frames_ratio)
    po.ba_global_max_refinements = int(config.ba_global_max_refinements)
    po.ba_global_max_num_iterations = int(config.ba_global_max_num_iterations)
    po.ba_global_function_tolerance = float(config.ba_global_function_tolerance)
    return po


def _largest_model_poses(recs, names: List[str]) -> Tuple[np.ndarray, List[int], object]:
    """(n, 4, 4) camera-to-world poses in the largest model (first registered
    frame = identity, NaN elsewhere), the model sizes (largest first) and the
    largest ``pycolmap.Reconstruction`` (None without a model)."""
    models = []
    for rec in (recs or {}).values():
        posed = {im.name: im for im in rec.images.values() if im.has_pose}
        models.append((len(posed), rec, posed))
    models.sort(key=lambda m: -m[0])
    poses = np.full((len(names), 4, 4), np.nan)
    if not models:
        return poses, [], None
    _, best, posed = models[0]
    T_first_inv: Optional[np.ndarray] = None
    for i, nm in enumerate(names):
        im = posed.get(nm)
        if im is None:
            continue
        T_world_cam = invert_pose(cam_from_world(im))
        if T_first_inv is None:
            T_first_inv = invert_pose(T_world_cam)
        poses[i] = T_first_inv @ T_world_cam
    return poses, [m[0] for m in models], best


# ===================================================================== runner
def run_colmap_vo(frames: Iterable[ImageOrFrame], config: Optional[ColmapVOConfig] = None,
                  camera: Optional[PinholeCamera] = None,
                  timestamps: Optional[Sequence[float]] = None,
                  workdir: Optional[Union[str, Path]] = None) -> ColmapVOResult:
    """COLMAP incremental SfM on the frames of a VO sequence (module docstring).

    Args:
        frames: :class:`~spgeo.frame.Frame` objects in time order (only
            ``image``, ``camera``, ``timestamp``, ``name`` are read: never depth
            or ground truth; all frames must share the first frame's camera) or
            raw images (H, W[, 3]) with ``camera``.  Consumed once (a lazy data
            set reader is fine: frames are resized and written one at a time).
        config: :class:`ColmapVOConfig` (default options if None).
        camera: intrinsics for raw images (ignored for Frames).
        timestamps: for raw images (default: the index).
        workdir: keep COLMAP's files (``images/``, ``database.db``,
            ``sparse/``) here; None (default) uses a temporary folder.
    Returns:
        :class:`ColmapVOResult`; frames COLMAP cannot register are ``lost``, a
        failed mapping is reported in ``message`` (never raised).
    Raises:
        ValueError for no frames, raw images without a camera, or frames of
        different cameras / sizes.
    """
    import pycolmap

    cfg = config or ColmapVOConfig()
    t0 = time.perf_counter()
    timings: Dict[str, float] = {}
    with workspace(workdir, "spgeo_colmap_vo_") as (image_dir, sparse_dir, db_path):
        names, frame_names, stamps, cam = _write_frames(
            _as_frames(frames, camera, timestamps), image_dir, cfg.resolution, cfg.show_progress)
        if not names or cam is None:
            raise ValueError("run_colmap_vo: no frames")
        n = len(names)
        timings["prepare"] = time.perf_counter() - t0
        with quiet(cfg):
            _extract_and_match(db_path, image_dir, names, cam, cfg, timings)
            with pycolmap.Database.open(db_path) as db:
                db_images = {im.name: im for im in db.read_all_images()}
                num_keypoints = [int(db.num_keypoints_for_image(db_images[nm].image_id))
                                 if nm in db_images else 0 for nm in names]
            recs, message = incremental_mapping(db_path, image_dir, sparse_dir,
                                                _vo_mapper_options(cfg), timings)
        poses, sizes, best = _largest_model_poses(recs, names)
        registered = np.all(np.isfinite(poses.reshape(n, -1)), axis=1)
        traj = Trajectory(np.asarray(stamps, np.float64), poses,
                          [FrameStatus.OK if r else FrameStatus.LOST for r in registered])
        result = ColmapVOResult(trajectory=traj, names=frame_names, camera=cam,
                                num_models=len(sizes), model_sizes=sizes,
                                num_keypoints=num_keypoints, message=message, config=cfg)
        if best is not None:
            result.num_points3D = int(best.num_points3D())
            result.mean_reprojection_error = float(best.compute_mean_reprojection_error())
            if result.num_registered < n:
                msg = (f"{n - result.num_registered} of {n} frames not in the largest model"
                       + (f" (other models: {sizes[1:]})" if len(sizes) > 1 else ""))
                result.message = "; ".join(m for m in (result.message, msg) if m)
        elif not result.message:
            result.message = "COLMAP built no model (no initial pair found)"
        timings["total"] = time.perf_counter() - t0
        result.timings = timings
        logger.info("COLMAP VO reference: %d/%d frames registered, %d model(s) %s, %d points, "
                    "%.1f s", result.num_registered, n, result.num_models, result.model_sizes,
                    result.num_points3D, timings["total"])
        return result


# ======================================================================= CLI
NAME = "colmap_vo"


def with_ground_truth(frames: Iterable[Frame], gt: List[Optional[np.ndarray]]) -> Iterable[Frame]:
    """``frames`` unchanged, appending each one's ``T_world_cam`` to ``gt`` as it passes."""
    for f in frames:
        gt.append(f.T_world_cam)
        yield f


def _print_ate(res: ColmapVOResult, gt: List[Optional[np.ndarray]],
               report: Dict[str, object]) -> None:
    """Print the per-frame Sim(3) ATE (into ``report["ate"]``) when at least 3 frames
    have ground truth and 3 are registered."""
    if sum(T is not None for T in gt) >= 3 and res.num_registered >= 3:
        try:
            a = res.ate(gt)
            print(a)
            report["ate"] = {"per-frame": a.summary()}
        except ValueError as exc:
            print(f"ATE not available: {exc}")


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = protocol_parser(
        "python -m spgeo.evaluation.references.colmap_vo",
        "COLMAP incremental SfM reference on the frames a VO run sees "
        "(SIFT, sequential matching, fixed PINHOLE intrinsics).", verbose=False)
    parser.add_argument("--resolution", default="160x120",
                        help="WIDTHxHEIGHT (default 160x120) or 'native'")
    parser.add_argument("--overlap", type=int, default=10, help="sequential overlap (default 10)")
    parser.add_argument("--threads", type=int, default=1, help="COLMAP threads (default 1)")
    parser.add_argument("--out", default=None, help="output folder")
    parser.add_argument("--workdir", default=None, help="keep COLMAP's files in this folder")
    add_verbose_argument(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run :func:`run_colmap_vo` on ``--dataset`` / ``--frames``, print its line and
    the ATE, write ``--out``; 0, or 1 when nothing was registered."""
    kind, path = args.dataset
    resolution = parse_resolution(args.resolution, allow_native=True, min_size=1)
    config = ColmapVOConfig(resolution=resolution,
                            overlap=args.overlap, num_threads=args.threads,
                            show_progress=True)
    seq = open_sequence(args)
    gt: List[Optional[np.ndarray]] = []
    res = run_colmap_vo(with_ground_truth(seq, gt), config, workdir=args.workdir)
    print(res.table())
    report: Dict[str, object] = {"dataset": kind, "path": str(path), "frames": args.frames,
                                 **res.summary()}
    _print_ate(res, gt, report)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        res.save_tum(out / "trajectory.txt")
        write_json(out / "report.json", report)
        print(f"wrote {out / 'trajectory.txt'}")
    return 0 if res.num_registered else 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.references.colmap_vo``: COLMAP reference trajectory of a
    data-set range; prints registration and Sim(3) ATE, writes ``trajectory.txt``
    (+ status) and ``report.json`` to ``--out``.  Returns 0, 1 when nothing was
    registered, 2 for bad arguments / unreadable data."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
