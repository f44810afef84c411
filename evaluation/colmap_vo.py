"""COLMAP (pycolmap) incremental-SfM reference trajectory on a VO sequence.

:func:`run_colmap_vo` gives the frames a VO run sees to COLMAP's standard
sparse pipeline and returns one camera-to-world pose per frame:

1. **Frames**: each frame is undistorted (if its camera has distortion), resized
   like the VO input (``cv2.INTER_AREA``, default 160x120; the camera via
   :meth:`~spgeo.camera.PinholeCamera.resized`) and written as
   ``000000.png, 000001.png, ...`` into a temporary folder.
2. **Features**: CPU SIFT into **one shared PINHOLE camera with known, fixed
   intrinsics** (the frames' camera, resized; COLMAP's pixel centres are at
   half-integers, so ``cx + 0.5``, ``cy + 0.5``).
3. **Matching**: sequential (each frame against the next ``overlap`` frames,
   plus quadratic overlap by default), geometric verification; vocabulary-tree
   loop detection is off by default.
4. **Mapping**: incremental mapper, intrinsics never refined, several models
   allowed; the **largest model** (most registered frames) gives the poses,
   the sizes of the others are reported.

COLMAP stores world-to-camera ``cam_from_world``; here
``T_world_cam = inv(cam_from_world)``, re-expressed so that the first
registered frame of the largest model is the identity (arbitrary scale:
evaluate with Sim(3)-aligned ATE, :meth:`ColmapVOResult.ate`).

Determinism: one thread (default), fixed RANSAC / mapper seeds, CPU SIFT and
brute-force matching.  The helpers of :mod:`.colmap` (image conversion,
mapper options, pose conversion) are reused.

Command line (prints registration and the Sim(3) ATE, writes the trajectory)::

    python -m spgeo.evaluation.colmap_vo --dataset 7scenes PATH --frames 0:300 \
        --resolution 160x120 --out DIR
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np
from tqdm import tqdm

from spgeo.camera import PinholeCamera
from spgeo.cli_args import add_dataset_arguments, add_verbose_argument, setup_logging
from spgeo.cli_args import parse_resolution as _parse_resolution
from spgeo.frame import Frame, resize_frame
from spgeo.geometry import invert_pose
from spgeo.jsonio import json_default

from .colmap import (ColmapConfig, _cam_from_world, _load_images, _mapper_options, extract_sift,
                     sift_matching_options)
from .trajectory import (AteResult, TrajectoryLike, ate_sim3, status_path_for, write_status,
                         write_tum)

__all__ = ["ColmapVOConfig", "ColmapVOResult", "COLMAP_VO_STATUSES", "run_colmap_vo",
           "resize_frame", "default_max_time_diff", "parse_resolution", "main"]

logger = logging.getLogger(__name__)

#: Per-frame statuses of :class:`ColmapVOResult`.
COLMAP_VO_STATUSES = ("registered", "unregistered")

ImageOrFrame = Union[Frame, np.ndarray]


# ==================================================================== config
@dataclass(frozen=True)
class ColmapVOConfig:
    """Options of :func:`run_colmap_vo` (COLMAP's own defaults in brackets).

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
        max_ratio: descriptor ratio test, default 0.8 [0.8].
        ransac_max_error_px: epipolar RANSAC threshold of the geometric
            verification, in pixels of the resized images, default 1.0 [4.0]
            (1 px at 160x120 is 4 px at 640x480).
        min_num_matches: verified matches for a pair to be used, default 15 [15].
        init_min_num_inliers: inliers of the mapper's initial pair, default 50 [100]
            (low-resolution frames have a few hundred features).
        init_min_tri_angle_deg: triangulation angle of the initial pair in
            degrees, default 2.0 [16]: hand-held sequences have small baselines
            (same ATE as 4.0 on 7-Scenes frames 0-299; 4.0 found no initial pair
            on a 20-frame synthetic sequence).
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
            bundle adjustment, default 1e-6 [0.0]: with COLMAP's 0.0 every
            global adjustment ran to its iteration limit on 7-Scenes frames at
            160x120 (ill-conditioned steps), mapping 300 frames took 270 s
            instead of 28 s for the same ATE (2.77 vs 2.74 cm).
        num_threads: threads of every stage, default 1 (deterministic); -1 = all cores.
        random_seed: seed of RANSAC and of the mapper, default 0.
        quiet: silence COLMAP's INFO logging while running, default True.
        show_progress: tqdm bar while the frames are prepared, default False.
    """

    resolution: Optional[Tuple[int, int]] = (160, 120)
    overlap: int = 10
    quadratic_overlap: bool = True
    loop_detection: bool = False
    vocab_tree_path: Optional[str] = None
    max_num_features: int = 4096
    max_ratio: float = 0.8
    ransac_max_error_px: float = 1.0
    min_num_matches: int = 15
    init_min_num_inliers: int = 50
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
    num_threads: int = 1
    random_seed: int = 0
    quiet: bool = True
    show_progress: bool = False

    def __post_init__(self) -> None:
        if self.resolution is not None:
            w, h = (int(v) for v in self.resolution)
            if w <= 0 or h <= 0:
                raise ValueError(f"ColmapVOConfig.resolution must be positive, "
                                 f"got {self.resolution}")
            object.__setattr__(self, "resolution", (w, h))
        if int(self.overlap) < 1:
            raise ValueError(f"ColmapVOConfig.overlap must be >= 1, got {self.overlap}")
        if self.loop_detection and not self.vocab_tree_path:
            raise ValueError("ColmapVOConfig.loop_detection needs vocab_tree_path (a COLMAP "
                             "vocabulary tree file)")
        if int(self.min_model_size) < 2:
            raise ValueError("ColmapVOConfig.min_model_size must be >= 2")
        # the remaining checks are ColmapConfig's
        self.to_colmap_config()

    def to_colmap_config(self) -> ColmapConfig:
        """The matching / mapper options as a :class:`~.colmap.ColmapConfig`
        (used with :func:`.colmap._mapper_options`)."""
        return ColmapConfig(
            max_num_features=int(self.max_num_features), max_ratio=float(self.max_ratio),
            ransac_max_error_px=float(self.ransac_max_error_px),
            min_num_matches=int(self.min_num_matches),
            init_min_num_inliers=int(self.init_min_num_inliers),
            init_min_tri_angle_deg=float(self.init_min_tri_angle_deg),
            filter_min_tri_angle_deg=float(self.filter_min_tri_angle_deg),
            abs_pose_min_num_inliers=int(self.abs_pose_min_num_inliers),
            fallback_two_view=False, check_two_view=False,
            num_threads=int(self.num_threads), random_seed=int(self.random_seed),
            quiet=bool(self.quiet))


# ==================================================================== result
@dataclass
class ColmapVOResult:
    """Output of :func:`run_colmap_vo`.

    Attributes:
        timestamps: (n,) frame timestamps (seconds, or frame numbers for data
            sets without time).
        T_world_cam: per frame its 4x4 camera-to-world pose in the largest
            model (first registered frame = identity, arbitrary scale), None
            when the frame is not registered in that model.
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

    timestamps: np.ndarray
    T_world_cam: List[Optional[np.ndarray]]
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
    def n_frames(self) -> int:
        return len(self.T_world_cam)

    @property
    def registered(self) -> np.ndarray:
        """(n,) bool: frames with a pose in the largest model."""
        return np.array([T is not None for T in self.T_world_cam], dtype=bool)

    @property
    def num_registered(self) -> int:
        return int(self.registered.sum())

    @property
    def registered_fraction(self) -> float:
        return self.num_registered / self.n_frames if self.n_frames else float("nan")

    @property
    def poses(self) -> np.ndarray:
        """(n, 4, 4) camera-to-world, NaN for unregistered frames."""
        out = np.full((self.n_frames, 4, 4), np.nan)
        for i, T in enumerate(self.T_world_cam):
            if T is not None:
                out[i] = T
        return out

    @property
    def status(self) -> List[str]:
        """Per frame ``"registered"`` / ``"unregistered"``."""
        return [COLMAP_VO_STATUSES[0] if T is not None else COLMAP_VO_STATUSES[1]
                for T in self.T_world_cam]

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
                :class:`~.trajectory.TumTrajectory` is accepted too.
            gt_timestamps: see ``gt_poses``.
            max_time_diff: association tolerance, default
                :func:`default_max_time_diff` of the timestamps.
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
        path = Path(path)
        header = ["COLMAP incremental SfM reference (pycolmap, SIFT, sequential matching, "
                  "fixed PINHOLE intrinsics); largest model; monocular: scale arbitrary",
                  f"frames {self.n_frames}, registered {self.num_registered}, "
                  f"models {self.num_models} {self.model_sizes}; camera {self.camera}"]
        write_tum(path, self.timestamps, self.T_world_cam, header=header)
        write_status(status_path_for(path), self.timestamps, self.status)
        return path

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
def default_max_time_diff(timestamps: Sequence[float]) -> float:
    """ATE association tolerance: 0.1 for frame-number timestamps (all
    integral, e.g. 7-Scenes), else 0.02 s (TUM)."""
    stamps = np.asarray(timestamps, dtype=np.float64)
    if stamps.size and np.all(np.isfinite(stamps)) and np.allclose(stamps, np.round(stamps)):
        return 0.1
    return 0.02


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
    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = int(config.min_num_matches)
    vo.ransac.max_error = float(config.ransac_max_error_px)
    vo.ransac.random_seed = int(config.random_seed)
    vo.detect_watermark = False
    t = time.perf_counter()
    pycolmap.match_sequential(db_path, matching_options=mo, pairing_options=po,
                              verification_options=vo, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t


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
        :class:`ColmapVOResult`; frames COLMAP cannot register are None, a
        failed mapping is reported in ``message`` (never raised).
    Raises:
        ValueError for no frames, raw images without a camera, or frames of
        different cameras / sizes.
    """
    import pycolmap

    from spgeo.twoview import _quiet_colmap

    cfg = config or ColmapVOConfig()
    t0 = time.perf_counter()
    timings: Dict[str, float] = {}
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="spgeo_colmap_vo_")
        root = Path(tmp.name)
    else:
        root = Path(workdir)
        root.mkdir(parents=True, exist_ok=True)
    try:
        image_dir, sparse_dir, db_path = root / "images", root / "sparse", root / "database.db"
        if db_path.exists():
            db_path.unlink()
        image_dir.mkdir(exist_ok=True)
        sparse_dir.mkdir(exist_ok=True)
        names: List[str] = []
        frame_names: List[str] = []
        stamps: List[float] = []
        cam: Optional[PinholeCamera] = None
        first_cam: Optional[PinholeCamera] = None
        it = _as_frames(frames, camera, timestamps)
        for i, f in enumerate(tqdm(it, disable=not cfg.show_progress, desc="colmap frames",
                                   unit="frame")):
            if first_cam is None:
                first_cam = f.camera
            elif f.camera != first_cam:
                raise ValueError(f"run_colmap_vo: frame {i} ({f.name!r}) has camera {f.camera}, "
                                 f"the first frame {first_cam}: one shared camera is required")
            small = resize_frame(f, cfg.resolution)
            cam = small.camera
            arr = _load_images([small.image], cam)[0]
            name = f"{i:06d}.png"
            if not cv2.imwrite(str(image_dir / name), cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)):
                raise OSError(f"cannot write {image_dir / name}")
            names.append(name)
            frame_names.append(f.name or f"{i:06d}")
            stamps.append(float(f.timestamp))
        if not names or cam is None:
            raise ValueError("run_colmap_vo: no frames")
        n = len(names)
        timings["prepare"] = time.perf_counter() - t0
        result = ColmapVOResult(timestamps=np.asarray(stamps, np.float64),
                                T_world_cam=[None] * n, names=frame_names, camera=cam,
                                config=cfg)
        quiet = _quiet_colmap() if cfg.quiet else contextlib.nullcontext()
        with quiet:
            _extract_and_match(db_path, image_dir, names, cam, cfg, timings)
            with pycolmap.Database.open(db_path) as db:
                db_images = {im.name: im for im in db.read_all_images()}
                result.num_keypoints = [int(db.num_keypoints_for_image(db_images[nm].image_id))
                                        if nm in db_images else 0 for nm in names]
            po = _mapper_options(cfg.to_colmap_config())
            po.multiple_models = True
            po.max_num_models = int(cfg.max_num_models)
            po.min_model_size = int(cfg.min_model_size)
            po.triangulation.ignore_two_view_tracks = bool(cfg.ignore_two_view_tracks)
            po.ba_global_frames_ratio = float(cfg.ba_global_frames_ratio)
            po.ba_global_points_ratio = float(cfg.ba_global_frames_ratio)
            po.ba_global_max_refinements = int(cfg.ba_global_max_refinements)
            po.ba_global_max_num_iterations = int(cfg.ba_global_max_num_iterations)
            po.ba_global_function_tolerance = float(cfg.ba_global_function_tolerance)
            t = time.perf_counter()
            recs: Dict[int, object] = {}
            try:
                recs = pycolmap.incremental_mapping(db_path, image_dir, sparse_dir, options=po)
            except Exception as exc:  # COLMAP raises on hopeless inputs
                result.message = f"incremental mapping failed: {exc}"
            timings["map"] = time.perf_counter() - t
        models = []
        for rec in (recs or {}).values():
            posed = {im.name: im for im in rec.images.values() if im.has_pose}
            models.append((len(posed), rec, posed))
        models.sort(key=lambda m: -m[0])
        result.num_models = len(models)
        result.model_sizes = [m[0] for m in models]
        if models:
            _, best, posed = models[0]
            index = {nm: i for i, nm in enumerate(names)}
            T_first_inv: Optional[np.ndarray] = None
            for nm in names:
                im = posed.get(nm)
                if im is None:
                    continue
                T_world_cam = invert_pose(_cam_from_world(im))
                if T_first_inv is None:
                    T_first_inv = invert_pose(T_world_cam)
                result.T_world_cam[index[nm]] = T_first_inv @ T_world_cam
            result.num_points3D = int(best.num_points3D())
            result.mean_reprojection_error = float(best.compute_mean_reprojection_error())
            if result.num_registered < n:
                msg = (f"{n - result.num_registered} of {n} frames not in the largest model"
                       + (f" (other models: {result.model_sizes[1:]})"
                          if len(models) > 1 else ""))
                result.message = "; ".join(m for m in (result.message, msg) if m)
        elif not result.message:
            result.message = "COLMAP built no model (no initial pair found)"
        timings["total"] = time.perf_counter() - t0
        result.timings = timings
        logger.info("COLMAP VO reference: %d/%d frames registered, %d model(s) %s, %d points, "
                    "%.1f s", result.num_registered, n, result.num_models, result.model_sizes,
                    result.num_points3D, timings["total"])
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()


# ======================================================================= CLI
def parse_resolution(text: str) -> Optional[Tuple[int, int]]:
    """``"160x120"`` -> (160, 120) (width, height in pixels); ``"native"`` ->
    None (keep the frames' size).  Raises ``ValueError``."""
    return _parse_resolution(text, allow_native=True, min_size=1)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.colmap_vo``: COLMAP reference trajectory of a
    data-set range; prints registration and Sim(3) ATE, writes ``trajectory.txt``
    (+ status) and ``report.json`` to ``--out``.  Returns 0, 1 when nothing was
    registered, 2 for bad arguments / unreadable data."""
    parser = argparse.ArgumentParser(
        prog="python -m spgeo.evaluation.colmap_vo",
        description="COLMAP incremental SfM reference on the frames a VO run sees "
                    "(SIFT, sequential matching, fixed PINHOLE intrinsics).")
    add_dataset_arguments(parser)
    parser.add_argument("--resolution", default="160x120",
                        help="WIDTHxHEIGHT (default 160x120) or 'native'")
    parser.add_argument("--overlap", type=int, default=10, help="sequential overlap (default 10)")
    parser.add_argument("--threads", type=int, default=1, help="COLMAP threads (default 1)")
    parser.add_argument("--out", default=None, help="output folder")
    parser.add_argument("--workdir", default=None, help="keep COLMAP's files in this folder")
    add_verbose_argument(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    from spgeo.datasets import open_dataset

    kind, path = args.dataset
    try:
        config = ColmapVOConfig(resolution=parse_resolution(args.resolution),
                                overlap=args.overlap, num_threads=args.threads,
                                show_progress=True)
        seq = open_dataset(kind, path, frames=args.frames, load_depth=False)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    gt = []

    def frames_with_gt():
        for f in seq:
            gt.append(f.T_world_cam)
            yield f

    res = run_colmap_vo(frames_with_gt(), config, workdir=args.workdir)
    print(f"COLMAP reference: {res.num_registered}/{res.n_frames} frames registered, "
          f"{res.num_models} model(s) {res.model_sizes}, {res.num_points3D} points, "
          f"{res.timings['total']:.1f} s ({res.fps:.1f} FPS)"
          + (f"; {res.message}" if res.message else ""))
    report: Dict[str, object] = {"dataset": kind, "path": str(path), "frames": args.frames,
                                 **res.summary()}
    if sum(T is not None for T in gt) >= 3 and res.num_registered >= 3:
        try:
            a = res.ate(gt)
            print(a)
            report["ate"] = {"per-frame": a.summary()}
        except ValueError as exc:
            print(f"ATE not available: {exc}")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        res.save_tum(out / "trajectory.txt")
        with open(out / "report.json", "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2, default=json_default)
        print(f"wrote {out / 'trajectory.txt'}")
    return 0 if res.num_registered else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
