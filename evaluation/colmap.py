"""COLMAP (pycolmap) cross-check of few-view SfM poses.

:func:`run_colmap_fewview` runs COLMAP's standard sparse pipeline on a reference
image plus supporting views with **known, fixed** intrinsics: SIFT extraction
into one shared PINHOLE camera, exhaustive matching with geometric
verification, incremental mapping (thresholds relaxed for a handful of
small-baseline views, intrinsics never refined) and, for views the mapper does
not register, an optional fallback to calibrated two-view geometry against the
reference.  Poses come back in spgeo's convention: ``T_ref_view`` is the pose of
each supporting view in the reference camera (camera-to-reference, reference
at identity; DESIGN.md §1).  COLMAP stores world-to-camera ``cam_from_world``,
so ``T_world_cam = inv(cam_from_world)`` and
``T_ref_view = inv(T_world_ref) @ T_world_view``; the tests check this on
synthetic views with known poses.

:func:`compare_fewview` / :func:`compare_methods` report rotation and
translation-direction errors of several methods against ground truth and
against each other; :func:`compare_on_dataset` runs pluggable estimators
(``callable(ref_frame, view_frames) -> list of T_ref_view``) on data-set frames;
:func:`main` is the command line::

    python -m spgeo.evaluation.colmap --dataset tum PATH --frames 0 4 8

Everything is deterministic: one thread, fixed RANSAC / mapper seeds, CPU
SIFT and brute-force matching.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.cli_args import add_dataset_arguments, add_verbose_argument, setup_logging
from spgeo.geometry import invert_pose, relative_pose
from spgeo.jsonio import json_default

from .pose_metrics import compare_pose_lists, relative_pose_errors

__all__ = [
    "COLMAP_STATUSES", "ColmapConfig", "ColmapResult", "run_colmap_fewview", "compare_methods",
    "compare_fewview", "colmap_estimator", "compare_on_dataset", "format_comparison", "main",
]

logger = logging.getLogger(__name__)

#: Values of :attr:`ColmapResult.status`.
COLMAP_STATUSES = ("ok", "partial", "inconsistent", "failed")

ImageInput = Union[np.ndarray, str, os.PathLike]
PoseList = List[Optional[np.ndarray]]
Estimator = Callable[[object, Sequence[object]], Sequence[Optional[np.ndarray]]]


# ==================================================================== config
@dataclass(frozen=True)
class ColmapConfig:
    """Options of :func:`run_colmap_fewview` (COLMAP's own defaults in brackets).

    Attributes:
        max_num_features: SIFT features per image, default 8192 [8192].
        max_image_size: images larger than this are downscaled for extraction;
            0 (default) keeps the full resolution.
        max_ratio: descriptor ratio test, default 0.8 [0.8].
        ransac_max_error_px: epipolar RANSAC threshold of the geometric
            verification of the matches, default 2.0 [4.0] (the intrinsics
            are known and the images undistorted).
        two_view_max_error_px: RANSAC threshold of the two-view fallback and
            check, default 1.0.
        min_num_matches: verified matches for a pair to be used, default 15 [15].
        init_min_num_inliers: inliers of the mapper's initial pair, default 50 [100].
        init_min_tri_angle_deg: triangulation angle of the initial pair,
            default 1.0 [16]: few-view sets have small baselines.
        filter_min_tri_angle_deg: minimum triangulation angle of kept 3-D
            points, default 0.5 [1.5].
        abs_pose_min_num_inliers: 2D-3D inliers to register a view, default 15 [30].
        fallback_two_view: pose views that the incremental mapper leaves
            unregistered from the two-view geometry of their matches with the
            reference (unit translation, own scale), default True.
        fallback_min_inliers: inliers the fallback needs, default 30.
        fallback_min_parallax_deg: median rotation-compensated parallax the
            fallback needs (else the translation is unobservable and the view
            stays unregistered), default 0.5.
        check_two_view: compare every incrementally registered view with the
            two-view geometry of its matches with the reference, default True.
            Few small-baseline views can make bundle adjustment settle in a
            rotation/translation-ambiguous (bas-relief) minimum; a disagreement
            above ``max_rotation_disagreement_deg`` sets the status
            ``"inconsistent"`` (poses are still returned).
        max_rotation_disagreement_deg: see ``check_two_view``, default 2.0.
        num_threads: threads of every stage, default 1 (deterministic).
        random_seed: seed of RANSAC and of the mapper, default 0.
        quiet: silence COLMAP's INFO logging while running, default True.
    """

    max_num_features: int = 8192
    max_image_size: int = 0
    max_ratio: float = 0.8
    ransac_max_error_px: float = 2.0
    two_view_max_error_px: float = 1.0
    min_num_matches: int = 15
    init_min_num_inliers: int = 50
    init_min_tri_angle_deg: float = 1.0
    filter_min_tri_angle_deg: float = 0.5
    abs_pose_min_num_inliers: int = 15
    fallback_two_view: bool = True
    fallback_min_inliers: int = 30
    fallback_min_parallax_deg: float = 0.5
    check_two_view: bool = True
    max_rotation_disagreement_deg: float = 2.0
    num_threads: int = 1
    random_seed: int = 0
    quiet: bool = True

    def __post_init__(self) -> None:
        if int(self.max_num_features) < 8:
            raise ValueError(f"ColmapConfig.max_num_features must be >= 8, "
                             f"got {self.max_num_features}")
        if not 0 < float(self.max_ratio) <= 1:
            raise ValueError(f"ColmapConfig.max_ratio must be in (0, 1], got {self.max_ratio}")
        if not (float(self.ransac_max_error_px) > 0 and float(self.two_view_max_error_px) > 0):
            raise ValueError("ColmapConfig.ransac_max_error_px and two_view_max_error_px "
                             "must be > 0")
        if int(self.num_threads) == 0 or int(self.num_threads) < -1:
            raise ValueError("ColmapConfig.num_threads must be >= 1 or -1 (all cores)")


# ==================================================================== result
@dataclass
class ColmapResult:
    """Output of :func:`run_colmap_fewview`.

    Attributes:
        status: ``"ok"`` (every supporting view posed), ``"partial"`` (some),
            ``"inconsistent"`` (posed, but some incremental pose disagrees with
            the view's two-view geometry by more than
            ``ColmapConfig.max_rotation_disagreement_deg``: do not trust it) or
            ``"failed"`` (none).
        T_ref_view: one entry per supporting view (``images[1:]``): its 4x4
            pose in the reference camera (camera-to-reference), None when
            unregistered.  Views from the incremental model share one arbitrary
            scale; two-view fallback poses have unit-norm translations.
        view_method: per supporting view ``"incremental"``, ``"two_view"`` or None.
        num_images: images given (reference included).
        num_registered: images with a pose, reference included (0 if the
            reference itself could not be posed).
        num_points3D: 3-D points of the incremental model (0 without one).
        mean_reprojection_error: of the incremental model in pixels (NaN without).
        num_keypoints: SIFT features per image.
        num_verified_matches: geometrically verified matches between the
            reference and each supporting view.
        two_view_disagreement_deg: per supporting view, the rotation angle
            between its incremental pose and its two-view pose w.r.t. the
            reference (NaN when either is missing or the check is off).
        message: reasons for unregistered views / failure.
        timings: seconds per stage.
        workdir: the working folder when it was kept (``workdir`` given), else None.
    """

    status: str
    T_ref_view: PoseList = field(default_factory=list)
    view_method: List[Optional[str]] = field(default_factory=list)
    num_images: int = 0
    num_registered: int = 0
    num_points3D: int = 0
    mean_reprojection_error: float = float("nan")
    num_keypoints: List[int] = field(default_factory=list)
    num_verified_matches: List[int] = field(default_factory=list)
    two_view_disagreement_deg: List[float] = field(default_factory=list)
    message: str = ""
    timings: Dict[str, float] = field(default_factory=dict)
    workdir: Optional[str] = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def registered(self) -> List[bool]:
        """Per supporting view: has a pose."""
        return [T is not None for T in self.T_ref_view]

    @property
    def scale_consistent(self) -> bool:
        """True when all posed views come from one incremental model (one scale)."""
        return all(m in (None, "incremental") for m in self.view_method)

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary."""
        return {
            "status": self.status, "message": self.message,
            "T_ref_view": [None if T is None else np.asarray(T).tolist() for T in self.T_ref_view],
            "view_method": list(self.view_method), "num_images": self.num_images,
            "num_registered": self.num_registered, "num_points3D": self.num_points3D,
            "mean_reprojection_error": self.mean_reprojection_error,
            "num_keypoints": list(self.num_keypoints),
            "num_verified_matches": list(self.num_verified_matches),
            "two_view_disagreement_deg": list(self.two_view_disagreement_deg),
            "timings": dict(self.timings), "workdir": self.workdir,
        }


# ================================================================== helpers
def _load_images(images: Sequence[ImageInput], camera: PinholeCamera) -> List[np.ndarray]:
    """uint8 RGB (H, W, 3) images, undistorted when ``camera`` has distortion."""
    from spgeo.images import load_image, to_float_image

    out = []
    for i, im in enumerate(images):
        name = "reference image" if i == 0 else f"view {i}"
        if isinstance(im, (str, os.PathLike)):
            arr = load_image(im)
        else:
            try:
                arr = to_float_image(np.asarray(im))
            except ValueError as exc:
                raise ValueError(f"run_colmap_fewview: {name}: {exc}") from None
        camera.check_image(arr, f"run_colmap_fewview: {name}")
        if camera.distortion is not None:
            arr = camera.undistort_image(arr)
        if arr.ndim == 2:
            arr = np.repeat(arr[..., None], 3, axis=2)
        out.append(np.clip(np.round(arr * 255.0), 0, 255).astype(np.uint8))
    return out


def _pose_from_rigid(rigid) -> np.ndarray:
    """4x4 of a ``pycolmap.Rigid3d`` (``x_b = R x_a + t`` for ``b_from_a``)."""
    M = np.eye(4)
    M[:3] = np.asarray(rigid.matrix(), np.float64)
    return M


def _cam_from_world(image) -> np.ndarray:
    cfw = image.cam_from_world
    return _pose_from_rigid(cfw() if callable(cfw) else cfw)


def _mapper_options(config: ColmapConfig):
    import pycolmap

    po = pycolmap.IncrementalPipelineOptions()
    po.num_threads = int(config.num_threads)
    po.random_seed = int(config.random_seed)
    po.min_num_matches = int(config.min_num_matches)
    po.ba_refine_focal_length = False
    po.ba_refine_principal_point = False
    po.ba_refine_extra_params = False
    po.multiple_models = False
    po.min_model_size = 2
    po.extract_colors = False
    m = po.mapper
    m.init_min_num_inliers = int(config.init_min_num_inliers)
    m.init_min_tri_angle = float(config.init_min_tri_angle_deg)
    m.filter_min_tri_angle = float(config.filter_min_tri_angle_deg)
    m.ba_local_min_tri_angle = max(float(config.filter_min_tri_angle_deg), 1.0)
    m.abs_pose_min_num_inliers = int(config.abs_pose_min_num_inliers)
    m.abs_pose_refine_focal_length = False
    m.abs_pose_refine_extra_params = False
    m.num_threads = int(config.num_threads)
    m.random_seed = int(config.random_seed)
    tri = po.triangulation
    tri.min_angle = float(config.filter_min_tri_angle_deg)
    tri.ignore_two_view_tracks = False  # with 2-4 images most tracks have two views
    tri.random_seed = int(config.random_seed)
    return po


def _two_view_pose(db, cam, id_ref: int, id_view: int, config: ColmapConfig,
                       spg_camera: PinholeCamera) -> Tuple[Optional[np.ndarray], str]:
    """``T_ref_view`` (unit translation) from the calibrated two-view geometry of
    the raw matches between the reference and a view, or ``(None, reason)``."""
    import pycolmap
    from spgeo.twoview import parallax_angles_deg

    try:
        kp1 = np.asarray(db.read_keypoints(id_ref), np.float64)[:, :2]
        kp2 = np.asarray(db.read_keypoints(id_view), np.float64)[:, :2]
        matches = np.asarray(db.read_matches(id_ref, id_view), np.uint32).reshape(-1, 2)
    except Exception as exc:  # pragma: no cover - database API differences
        return None, f"cannot read matches ({exc})"
    if len(matches) < config.fallback_min_inliers:
        return None, f"{len(matches)} raw matches with the reference"
    opts = pycolmap.TwoViewGeometryOptions()
    opts.compute_relative_pose = True
    opts.min_num_inliers = int(config.fallback_min_inliers)
    opts.ransac.max_error = float(config.two_view_max_error_px)
    opts.ransac.random_seed = int(config.random_seed)
    opts.ransac.num_threads = 1
    opts.detect_watermark = False
    geom = pycolmap.estimate_calibrated_two_view_geometry(cam, kp1, cam, kp2, matches, opts)
    Cfg = pycolmap.TwoViewGeometryConfiguration
    inl = np.asarray(geom.inlier_matches, np.int64).reshape(-1, 2)
    if geom.config not in (Cfg.CALIBRATED, Cfg.PLANAR) or geom.cam2_from_cam1 is None:
        return None, f"two-view configuration {getattr(geom.config, 'name', geom.config)}"
    if len(inl) < config.fallback_min_inliers:
        return None, f"{len(inl)} two-view inliers < {config.fallback_min_inliers}"
    T_view_ref = _pose_from_rigid(geom.cam2_from_cam1)
    t = T_view_ref[:3, 3]
    if not np.all(np.isfinite(T_view_ref)) or np.linalg.norm(t) < 1e-12:
        return None, "no translation (pure rotation)"
    par = parallax_angles_deg(spg_camera, kp1[inl[:, 0]] - 0.5, kp2[inl[:, 1]] - 0.5,
                              T_view_ref[:3, :3])
    if float(np.median(par)) < config.fallback_min_parallax_deg:
        return None, f"median parallax {float(np.median(par)):.2f} deg too low"
    T_ref_view = invert_pose(T_view_ref)
    T_ref_view[:3, 3] /= np.linalg.norm(T_ref_view[:3, 3])
    return T_ref_view, ""


# ===================================================================== runner
def run_colmap_fewview(images: Sequence[ImageInput], camera: PinholeCamera,
                       workdir: Optional[Union[str, os.PathLike]] = None,
                       config: Optional[ColmapConfig] = None) -> ColmapResult:
    """Poses of supporting views relative to a reference with COLMAP.

    Args:
        images: reference first, then the supporting views: arrays (H, W[, 3],
            uint8 / uint16 / float in [0, 1]) or image file paths, all of
            ``camera``'s size.  At least two.
        camera: the shared intrinsics (kept fixed).  With distortion, images
            are undistorted first and the undistorted camera is used.
        workdir: folder for COLMAP's files (``database.db``, ``images/``,
            ``sparse/``), kept afterwards; an existing ``database.db`` there is
            replaced.  None (default): a temporary folder, removed on return.
        config: :class:`ColmapConfig`.
    Returns:
        :class:`ColmapResult` (check ``status``; unregistered views are None).
    Raises:
        ValueError / TypeError for malformed input, FileNotFoundError for
        missing files.
    """
    import cv2

    from spgeo.twoview import _quiet_colmap

    config = config or ColmapConfig()
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    images = list(images)
    if len(images) < 2:
        raise ValueError(f"run_colmap_fewview needs a reference and at least one view, "
                         f"got {len(images)} image(s)")
    t0 = time.perf_counter()
    arrays = _load_images(images, camera)
    cam = camera.undistorted()
    n = len(arrays)
    timings: Dict[str, float] = {}

    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="spgeo_colmap_")
        root = Path(tmp.name)
    else:
        root = Path(workdir)
        root.mkdir(parents=True, exist_ok=True)
    try:
        image_dir = root / "images"
        sparse_dir = root / "sparse"
        db_path = root / "database.db"
        if db_path.exists():
            db_path.unlink()
        if sparse_dir.exists():
            shutil.rmtree(sparse_dir)
        image_dir.mkdir(exist_ok=True)
        sparse_dir.mkdir()
        names = [f"{i:03d}_ref.png" if i == 0 else f"{i:03d}.png" for i in range(n)]
        for name, arr in zip(names, arrays):
            if not cv2.imwrite(str(image_dir / name), cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)):
                raise OSError(f"cannot write {image_dir / name}")
        timings["prepare"] = time.perf_counter() - t0
        quiet = _quiet_colmap() if config.quiet else contextlib.nullcontext()
        with quiet:
            result = _run_pipeline(db_path, image_dir, sparse_dir, names, cam, config, timings)
        result.workdir = None if tmp is not None else str(root)
        timings["total"] = time.perf_counter() - t0
        result.timings = timings
        logger.info("COLMAP few-view: %s, %d/%d images posed, %d points (%s)", result.status,
                    result.num_registered, result.num_images, result.num_points3D,
                    result.message or "all views registered")
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()


def extract_sift(db_path, image_dir, names: List[str], cam: PinholeCamera, num_threads: int,
                 max_num_features: int, max_image_size: int = 0) -> float:
    """SIFT features of ``names`` into the database with one shared, known
    PINHOLE camera (CPU); ``max_image_size`` 0 = the image size.  Returns seconds."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    # COLMAP pixel centres are at half-integers: shift the principal point by +0.5
    reader.camera_params = f"{cam.fx!r},{cam.fy!r},{cam.cx + 0.5!r},{cam.cy + 0.5!r}"
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = int(num_threads)
    ext.use_gpu = False
    ext.max_image_size = int(max_image_size) if max_image_size > 0 else max(cam.width, cam.height)
    ext.sift.max_num_features = int(max_num_features)
    t = time.perf_counter()
    pycolmap.extract_features(db_path, image_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    return time.perf_counter() - t


def sift_matching_options(num_threads: int, max_ratio: float):
    """CPU brute-force SIFT matching options."""
    import pycolmap

    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = int(num_threads)
    mo.use_gpu = False
    mo.sift.max_ratio = float(max_ratio)
    mo.sift.cpu_brute_force_matcher = True
    return mo


def _run_pipeline(db_path: Path, image_dir: Path, sparse_dir: Path, names: List[str],
                  cam: PinholeCamera, config: ColmapConfig,
                  timings: Dict[str, float]) -> ColmapResult:
    import pycolmap

    n = len(names)
    pycolmap.set_random_seed(int(config.random_seed))
    max_size = int(config.max_image_size) if config.max_image_size > 0 else 0
    timings["extract"] = extract_sift(db_path, image_dir, names, cam, config.num_threads,
                                      config.max_num_features, max_size)
    mo = sift_matching_options(config.num_threads, config.max_ratio)
    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = int(config.min_num_matches)
    vo.ransac.max_error = float(config.ransac_max_error_px)
    vo.ransac.random_seed = int(config.random_seed)
    vo.detect_watermark = False
    t = time.perf_counter()
    pycolmap.match_exhaustive(db_path, matching_options=mo, verification_options=vo,
                              device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t

    # ---- database bookkeeping
    with pycolmap.Database.open(db_path) as db:
        db_images = {im.name: im for im in db.read_all_images()}
        missing = [nm for nm in names if nm not in db_images]
        if missing:
            raise RuntimeError(f"COLMAP did not import images {missing}")
        ids = [int(db_images[nm].image_id) for nm in names]
        num_kp = [int(db.num_keypoints_for_image(i)) for i in ids]
        verified = []
        for j in range(1, n):
            try:
                verified.append(int(len(db.read_two_view_geometry(ids[0], ids[j]).inlier_matches)))
            except Exception:
                verified.append(0)
        colmap_cam = db.read_camera(int(db_images[names[0]].camera_id))

    result = ColmapResult(status="failed", T_ref_view=[None] * (n - 1),
                          view_method=[None] * (n - 1), num_images=n, num_keypoints=num_kp,
                          num_verified_matches=verified)
    reasons: List[str] = []

    # ---- incremental mapping
    t = time.perf_counter()
    recs: Dict[int, object] = {}
    try:
        recs = pycolmap.incremental_mapping(db_path, image_dir, sparse_dir,
                                            options=_mapper_options(config))
    except Exception as exc:  # COLMAP raises on hopeless inputs
        reasons.append(f"incremental mapping failed: {exc}")
    timings["map"] = time.perf_counter() - t
    best, best_count = None, 0
    for rec in (recs or {}).values():
        reg = {im.name for im in rec.images.values() if im.has_pose}
        if names[0] in reg and len(reg) > best_count:
            best, best_count = rec, len(reg)
    if best is None and recs:
        reasons.append("the reference is in no reconstruction")
    if best is not None:
        posed = {im.name: im for im in best.images.values() if im.has_pose}
        T_world_ref = invert_pose(_cam_from_world(posed[names[0]]))
        for j in range(1, n):
            im = posed.get(names[j])
            if im is not None:
                result.T_ref_view[j - 1] = relative_pose(T_world_ref, invert_pose(_cam_from_world(im)))
                result.view_method[j - 1] = "incremental"
        result.num_points3D = int(best.num_points3D())
        result.mean_reprojection_error = float(best.compute_mean_reprojection_error())

    # ---- two-view geometry: fallback for unregistered views, check for the others
    result.two_view_disagreement_deg = [float("nan")] * (n - 1)
    need_fallback = config.fallback_two_view and any(T is None for T in result.T_ref_view)
    inconsistent = []
    if need_fallback or config.check_two_view:
        from .pose_metrics import rotation_error_deg

        t = time.perf_counter()
        with pycolmap.Database.open(db_path) as db:
            for j in range(1, n):
                T_inc = result.T_ref_view[j - 1]
                if T_inc is None and not config.fallback_two_view:
                    continue
                if T_inc is not None and not config.check_two_view:
                    continue
                T2, why = _two_view_pose(db, colmap_cam, ids[0], ids[j], config, cam)
                if T_inc is None:
                    if T2 is None:
                        reasons.append(f"view {j} unregistered: {why}")
                    else:
                        result.T_ref_view[j - 1] = T2
                        result.view_method[j - 1] = "two_view"
                elif T2 is not None:
                    d = rotation_error_deg(T_inc, T2)
                    result.two_view_disagreement_deg[j - 1] = d
                    if d > config.max_rotation_disagreement_deg:
                        inconsistent.append(j)
                        reasons.append(f"view {j}: incremental and two-view rotations differ by "
                                       f"{d:.2f} deg (ambiguous geometry)")
        timings["two_view"] = time.perf_counter() - t
    for j in range(1, n):
        if result.T_ref_view[j - 1] is None and not config.fallback_two_view:
            reasons.append(f"view {j} not registered by the incremental mapper")

    n_posed = sum(T is not None for T in result.T_ref_view)
    result.num_registered = n_posed + 1 if n_posed else (1 if best is not None else 0)
    if n_posed == 0:
        result.status = "failed"
    elif inconsistent:
        result.status = "inconsistent"
    else:
        result.status = "ok" if n_posed == n - 1 else "partial"
    result.message = "; ".join(reasons)
    return result


# ================================================================ comparison
def compare_methods(estimates: Mapping[str, Sequence[Optional[np.ndarray]]],
                    T_ref_view_gt: Optional[Sequence[Optional[np.ndarray]]] = None,
                    view_names: Optional[Sequence[str]] = None) -> Dict[str, object]:
    """Rotation / translation-direction errors of several methods' relative poses.

    Args:
        estimates: method name -> list of ``T_ref_view`` (None = not posed), all
            of the same length (one per supporting view).
        T_ref_view_gt: optional ground truth, same length.
        view_names: optional names of the views.
    Returns:
        dict with ``"views"`` (names), ``"vs_gt"`` (method -> per-view rows and
        summary of :func:`~spgeo.evaluation.pose_metrics.compare_pose_lists`;
        empty without ground truth), ``"pairwise"`` (``"a_vs_b"`` -> the same
        between each pair of methods) and ``"gt_motion"`` (per view rotation
        angle in degrees and translation norm of the ground truth, if given).
    """
    names = list(estimates)
    lengths = {len(list(v)) for v in estimates.values()}
    if T_ref_view_gt is not None:
        lengths.add(len(list(T_ref_view_gt)))
    if len(lengths) > 1:
        raise ValueError(f"compare_methods: pose lists of different lengths {sorted(lengths)}")
    n = lengths.pop() if lengths else 0
    vnames = [f"view{j + 1}" for j in range(n)] if view_names is None else list(view_names)
    out: Dict[str, object] = {"views": vnames, "vs_gt": {}, "pairwise": {}, "gt_motion": []}
    if T_ref_view_gt is not None:
        gt = list(T_ref_view_gt)
        for name in names:
            out["vs_gt"][name] = compare_pose_lists(list(estimates[name]), gt, vnames).to_dict()
        out["gt_motion"] = [
            None if T is None else {
                "rotation_deg": relative_pose_errors(np.eye(4), T)["gt_rotation_deg"],
                "translation_norm": float(np.linalg.norm(np.asarray(T)[:3, 3]))}
            for T in gt]
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            out["pairwise"][f"{a}_vs_{b}"] = compare_pose_lists(
                list(estimates[a]), list(estimates[b]), vnames).to_dict()
    return out


def compare_fewview(T_ref_view_spgeo: Sequence[Optional[np.ndarray]],
                    T_ref_view_colmap: Sequence[Optional[np.ndarray]],
                    T_ref_view_gt: Optional[Sequence[Optional[np.ndarray]]] = None,
                    view_names: Optional[Sequence[str]] = None) -> Dict[str, object]:
    """spgeo vs COLMAP (vs ground truth when given): :func:`compare_methods` with
    the methods ``"spgeo"`` and ``"colmap"``; the pairwise entry is
    ``result["pairwise"]["spgeo_vs_colmap"]``."""
    return compare_methods({"spgeo": T_ref_view_spgeo, "colmap": T_ref_view_colmap},
                           T_ref_view_gt, view_names)


def _fmt(x: object, digits: int = 2) -> str:
    if x is None:
        return "-"
    try:
        v = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(x)
    return "nan" if not math.isfinite(v) else f"{v:.{digits}f}"


def format_comparison(comparison: Mapping[str, object]) -> str:
    """Plain-text table of a :func:`compare_methods` / :func:`compare_on_dataset`
    result: one row per view, rotation error / translation-direction error in
    degrees for each method vs ground truth and for each pair of methods."""
    views = list(comparison.get("views", []))
    blocks = [("vs GT", k, v) for k, v in dict(comparison.get("vs_gt", {})).items()]
    blocks += [("pair", k, v) for k, v in dict(comparison.get("pairwise", {})).items()]
    gt_motion = list(comparison.get("gt_motion", []) or [])
    header = ["view"] + (["gt rot", "gt |t|"] if gt_motion else [])
    for kind, name, _ in blocks:
        label = name if kind == "pair" else f"{name} vs gt"
        header += [f"{label} rot", f"{label} tdir"]
    rows = [header]
    for j, v in enumerate(views):
        row = [str(v)]
        if gt_motion:
            g = gt_motion[j] if j < len(gt_motion) else None
            row += [_fmt(None if g is None else g["rotation_deg"]),
                    _fmt(None if g is None else g["translation_norm"], 3)]
        for _, _, block in blocks:
            r = block["rows"][j]
            if not r.get("available", False):
                row += ["-", "-"]
            else:
                row += [_fmt(r["rotation_error_deg"], 3), _fmt(r["translation_direction_error_deg"])]
        rows.append(row)
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append("(errors in degrees: rotation angle, translation-direction angle; "
                 "'-' = not posed)")
    return "\n".join(lines)


# ================================================================ data sets
def colmap_estimator(config: Optional[ColmapConfig] = None,
                     workdir: Optional[Union[str, os.PathLike]] = None) -> Estimator:
    """An estimator for :func:`compare_on_dataset`: runs :func:`run_colmap_fewview`
    on ``[ref_frame.image] + [f.image for f in view_frames]`` with the reference's
    camera and returns its ``T_ref_view`` list.  The last :class:`ColmapResult`
    is available as the callable's ``last_result`` attribute."""

    def estimate(ref_frame, view_frames):
        res = run_colmap_fewview([ref_frame.image] + [f.image for f in view_frames],
                                 ref_frame.camera, workdir=workdir, config=config)
        estimate.last_result = res  # type: ignore[attr-defined]
        return res.T_ref_view

    estimate.last_result = None  # type: ignore[attr-defined]
    return estimate


def compare_on_dataset(frames: Sequence[object],
                       estimators: Mapping[str, Estimator]) -> Dict[str, object]:
    """Run pose estimators on a reference frame plus supporting frames and
    compare them with the frames' ground truth and with each other.

    Args:
        frames: :class:`spgeo.frame.Frame` objects, reference first (at least
            two); ground truth comes from their ``T_world_cam`` (views without
            one are skipped in the ground-truth comparison).
        estimators: name -> ``callable(ref_frame, view_frames)`` returning one
            ``T_ref_view`` (4x4 or None) per supporting view.  An estimator that
            raises is recorded (``"error"``) and counted as posing nothing.
    Returns:
        :func:`compare_methods`'s dict plus ``"frames"`` (frame names),
        ``"estimates"`` (name -> poses as nested lists or None), ``"errors"``
        (name -> message or None) and ``"time_s"`` (name -> seconds).
    """
    frames = list(frames)
    if len(frames) < 2:
        raise ValueError("compare_on_dataset needs a reference and at least one view")
    ref, views = frames[0], frames[1:]
    gt: Optional[PoseList] = None
    if ref.T_world_cam is not None:
        gt = [None if f.T_world_cam is None else relative_pose(ref.T_world_cam, f.T_world_cam)
              for f in views]
    estimates: Dict[str, PoseList] = {}
    errors: Dict[str, Optional[str]] = {}
    times: Dict[str, float] = {}
    for name, fn in estimators.items():
        t = time.perf_counter()
        try:
            poses = list(fn(ref, views))
            if len(poses) != len(views):
                raise ValueError(f"returned {len(poses)} poses for {len(views)} views")
            estimates[name] = [None if T is None else np.asarray(T, np.float64) for T in poses]
            errors[name] = None
        except Exception as exc:  # an evaluation must report, not die
            logger.exception("estimator %r failed", name)
            estimates[name] = [None] * len(views)
            errors[name] = f"{type(exc).__name__}: {exc}"
        times[name] = time.perf_counter() - t
    names = [getattr(f, "name", "") or f"view{j + 1}" for j, f in enumerate(views)]
    out = compare_methods(estimates, gt, names)
    out["frames"] = [getattr(f, "name", "") for f in frames]
    out["estimates"] = {k: [None if T is None else T.tolist() for T in v]
                        for k, v in estimates.items()}
    out["errors"] = errors
    out["time_s"] = times
    return out


# ====================================================================== CLI
def _parse_frames(values: Optional[List[str]]):
    if not values:
        return None
    if len(values) == 1 and ":" in values[0]:
        return values[0]
    try:
        return [int(v) for v in values]
    except ValueError:
        raise SystemExit(f"--frames: expected frame numbers or 'A:B[:S]', got {values}")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: COLMAP (and any registered estimators) vs ground truth on
    a reference + supporting frames of a data set; prints a table and optionally
    writes JSON.  Returns the exit status (0 on success, 1 if COLMAP posed no view)."""
    parser = argparse.ArgumentParser(
        prog="python -m spgeo.evaluation.colmap",
        description="Relative-pose errors of COLMAP (pycolmap, SIFT, fixed intrinsics) on a "
                    "reference frame plus supporting frames, against ground truth.")
    add_dataset_arguments(parser, frames_nargs="+",
                          frames_help="frame numbers, reference first (e.g. 0 4 8), or "
                                      "'A:B[:S]' (default: all frames of the data set)")
    parser.add_argument("--json", default=None, help="write the full comparison as JSON here")
    parser.add_argument("--workdir", default=None, help="keep COLMAP's files in this folder")
    parser.add_argument("--threads", type=int, default=1, help="COLMAP threads (default 1)")
    parser.add_argument("--no-fallback", action="store_true",
                        help="do not pose unregistered views by two-view geometry")
    add_verbose_argument(parser)
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    from spgeo.datasets import open_dataset

    kind, path = args.dataset
    selection = _parse_frames(args.frames)
    try:
        seq = open_dataset(kind, path, frames=selection, load_depth=False)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    frames = list(seq)
    if len(frames) < 2:
        print("error: need a reference and at least one supporting frame", file=sys.stderr)
        return 2
    config = ColmapConfig(num_threads=args.threads, fallback_two_view=not args.no_fallback)
    est = colmap_estimator(config, workdir=args.workdir)
    comparison = compare_on_dataset(frames, {"colmap": est})
    res: Optional[ColmapResult] = est.last_result  # type: ignore[attr-defined]
    print(f"{seq.name}: reference {frames[0].name}, views "
          f"{', '.join(f.name for f in frames[1:])}; camera {seq.camera}")
    if res is not None:
        print(f"COLMAP: status {res.status}, {res.num_registered}/{res.num_images} images posed "
              f"({', '.join(str(m) for m in res.view_method)}), {res.num_points3D} points, "
              f"{res.timings.get('total', float('nan')):.1f} s"
              + (f"; {res.message}" if res.message else ""))
    print(format_comparison(comparison))
    if args.json:
        payload = dict(comparison)
        if res is not None:
            payload["colmap_result"] = res.summary()
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(payload, fh, indent=2, default=json_default)
    return 0 if res is not None and res.status != "failed" else 1




if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
