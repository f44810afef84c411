"""pycolmap helpers shared by the few-view (:mod:`.colmap`) and the VO
(:mod:`.colmap_vo`) references: the common SIFT / matching / mapper options,
image conversion, CPU SIFT extraction into one fixed PINHOLE camera, matching
and verification options, the incremental-mapper options and pose conversion.

COLMAP stores world-to-camera ``cam_from_world``; :func:`cam_from_world`
returns it as a 4x4 matrix (spgeo's ``T_world_cam`` is its inverse).
Everything is deterministic with one thread and fixed seeds (CPU SIFT,
brute-force matching).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.twoview import quiet_colmap

__all__ = ["ColmapOptions", "ImageInput", "workspace", "quiet", "load_images",
           "pose_from_rigid", "cam_from_world", "mapper_options", "extract_sift",
           "sift_matching_options", "verification_options", "incremental_mapping",
           "quiet_colmap"]

ImageInput = Union[np.ndarray, str, os.PathLike]


@dataclass(frozen=True)
class ColmapOptions:
    """SIFT, matching and mapper options common to both COLMAP references
    (COLMAP's own defaults in brackets; each reference sets its own defaults).

    Attributes:
        max_num_features: SIFT features per image [8192].
        max_ratio: descriptor ratio test [0.8].
        ransac_max_error_px: epipolar RANSAC threshold of the geometric
            verification of the matches, in pixels [4.0].
        min_num_matches: verified matches for a pair to be used [15].
        init_min_num_inliers: inliers of the mapper's initial pair [100].
        init_min_tri_angle_deg: triangulation angle of the initial pair in degrees [16].
        filter_min_tri_angle_deg: minimum triangulation angle of kept 3-D
            points in degrees [1.5].
        abs_pose_min_num_inliers: 2D-3D inliers to register an image [30].
        num_threads: threads of every stage, default 1 (deterministic); -1 = all cores.
        random_seed: seed of RANSAC and of the mapper, default 0.
        quiet: silence COLMAP's INFO logging while running, default True.
    Raises ``ValueError`` for out-of-range values.
    """

    max_num_features: int = 8192
    max_ratio: float = 0.8
    ransac_max_error_px: float = 2.0
    min_num_matches: int = 15
    init_min_num_inliers: int = 50
    init_min_tri_angle_deg: float = 1.0
    filter_min_tri_angle_deg: float = 0.5
    abs_pose_min_num_inliers: int = 15
    num_threads: int = 1
    random_seed: int = 0
    quiet: bool = True

    def __post_init__(self) -> None:
        name = type(self).__name__
        if int(self.max_num_features) < 8:
            raise ValueError(f"{name}.max_num_features must be >= 8, "
                             f"got {self.max_num_features}")
        if not 0 < float(self.max_ratio) <= 1:
            raise ValueError(f"{name}.max_ratio must be in (0, 1], got {self.max_ratio}")
        if not float(self.ransac_max_error_px) > 0:
            raise ValueError(f"{name}.ransac_max_error_px must be > 0")
        if int(self.num_threads) == 0 or int(self.num_threads) < -1:
            raise ValueError(f"{name}.num_threads must be >= 1 or -1 (all cores)")


@contextlib.contextmanager
def workspace(workdir: Optional[Union[str, os.PathLike]], prefix: str,
              clear_sparse: bool = False) -> Iterator[Tuple[Path, Path, Path]]:
    """COLMAP's folders ``(images/, sparse/, database.db)`` under ``workdir``
    (created, kept afterwards; an existing ``database.db`` is replaced, an
    existing ``sparse/`` too with ``clear_sparse``) or, when ``workdir`` is
    None, under a temporary folder named ``prefix...`` removed on exit."""
    with contextlib.ExitStack() as stack:
        if workdir is None:
            root = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=prefix)))
        else:
            root = Path(workdir)
            root.mkdir(parents=True, exist_ok=True)
        image_dir, sparse_dir, db_path = root / "images", root / "sparse", root / "database.db"
        if db_path.exists():
            db_path.unlink()
        if clear_sparse and sparse_dir.exists():
            shutil.rmtree(sparse_dir)
        image_dir.mkdir(exist_ok=True)
        sparse_dir.mkdir(exist_ok=True)
        yield image_dir, sparse_dir, db_path


def quiet(config: ColmapOptions):
    """:func:`spgeo.twoview.quiet_colmap` when ``config.quiet``, else a no-op context."""
    return quiet_colmap() if config.quiet else contextlib.nullcontext()


def load_images(images: Sequence[ImageInput], camera: PinholeCamera) -> List[np.ndarray]:
    """uint8 RGB (H, W, 3) images from arrays (uint8 / uint16 / float [0, 1])
    or file paths of ``camera``'s size, undistorted when ``camera`` has
    distortion.  Raises ``ValueError`` for a malformed image."""
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


def pose_from_rigid(rigid) -> np.ndarray:
    """4x4 of a ``pycolmap.Rigid3d`` (``x_b = R x_a + t`` for ``b_from_a``)."""
    M = np.eye(4)
    M[:3] = np.asarray(rigid.matrix(), np.float64)
    return M


def cam_from_world(image) -> np.ndarray:
    """4x4 world-to-camera pose of a registered ``pycolmap.Image``."""
    cfw = image.cam_from_world
    return pose_from_rigid(cfw() if callable(cfw) else cfw)


def mapper_options(config: ColmapOptions):
    """``pycolmap.IncrementalPipelineOptions``: intrinsics never refined, one
    model of at least 2 images, thresholds and seeds from ``config``."""
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


def verification_options(config: ColmapOptions):
    """``pycolmap.TwoViewGeometryOptions`` of the geometric verification of the
    matches (``min_num_matches`` inliers, ``ransac_max_error_px``, seeded)."""
    import pycolmap

    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = int(config.min_num_matches)
    vo.ransac.max_error = float(config.ransac_max_error_px)
    vo.ransac.random_seed = int(config.random_seed)
    vo.detect_watermark = False
    return vo


def incremental_mapping(db_path, image_dir, sparse_dir, options,
                        timings: Dict[str, float]) -> Tuple[Dict[int, object], str]:
    """``pycolmap.incremental_mapping``: (reconstructions by id, "" or why it
    failed: COLMAP raises on hopeless inputs, reported here instead); the
    seconds go into ``timings["map"]``."""
    import pycolmap

    t = time.perf_counter()
    recs: Dict[int, object] = {}
    error = ""
    try:
        recs = pycolmap.incremental_mapping(db_path, image_dir, sparse_dir, options=options)
    except Exception as exc:  # COLMAP raises on hopeless inputs
        error = f"incremental mapping failed: {exc}"
    timings["map"] = time.perf_counter() - t
    return recs, error
