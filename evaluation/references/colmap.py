"""COLMAP (pycolmap) cross-check of few-view SfM poses.

:func:`run_colmap_fewview` runs COLMAP's standard sparse pipeline on a reference
image plus supporting views with **known, fixed** intrinsics: SIFT extraction
into one shared PINHOLE camera, exhaustive matching with geometric
verification, incremental mapping (thresholds relaxed for a handful of
small-baseline views, intrinsics never refined) and, for views the mapper does
not register, an optional fallback to calibrated two-view geometry against the
reference.  Poses come back in spgeo's convention: ``T_ref_view`` is the pose of
each supporting view in the reference camera (camera-to-reference, reference
at identity; docs/design.md §1).  COLMAP stores world-to-camera ``cam_from_world``,
so ``T_world_cam = inv(cam_from_world)`` and
``T_ref_view = inv(T_world_ref) @ T_world_view``.

:func:`colmap_estimator` wraps it as an estimator for
:func:`~spgeo.evaluation.pose_compare.compare_on_dataset` (the comparison tables live in
:mod:`spgeo.evaluation.pose_compare`); :func:`main` is the command line::

    python -m spgeo.evaluation.references.colmap --dataset tum PATH --frames 0 4 8

Everything is deterministic: one thread, fixed RANSAC / mapper seeds, CPU
SIFT and brute-force matching (shared helpers: :mod:`.colmap_common`).
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.apps.args import add_dataset_arguments, add_verbose_argument
from spgeo.geometry import invert_pose, relative_pose

from spgeo.evaluation.pose_compare import Estimator, compare_on_dataset, format_comparison
from spgeo.evaluation.runner import open_sequence, protocol_parser, run_protocol, write_json

from .colmap_common import (ColmapOptions, ImageInput, cam_from_world, extract_sift,
                            incremental_mapping, load_images, mapper_options, pose_from_rigid,
                            quiet, sift_matching_options, verification_options, workspace)

__all__ = ["COLMAP_STATUSES", "ColmapConfig", "ColmapResult", "run_colmap_fewview",
           "colmap_estimator", "ColmapComparison", "compare_colmap", "build_parser", "run",
           "main"]

logger = logging.getLogger(__name__)

#: Values of :attr:`ColmapResult.status`.
COLMAP_STATUSES = ("ok", "partial", "inconsistent", "failed")

PoseList = List[Optional[np.ndarray]]


# ==================================================================== config
@dataclass(frozen=True)
class ColmapConfig(ColmapOptions):
    """Options of :func:`run_colmap_fewview` (COLMAP's own defaults in brackets;
    the common ones are :class:`~.colmap_common.ColmapOptions`).

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

    max_image_size: int = 0
    two_view_max_error_px: float = 1.0
    fallback_two_view: bool = True
    fallback_min_inliers: int = 30
    fallback_min_parallax_deg: float = 0.5
    check_two_view: bool = True
    max_rotation_disagreement_deg: float = 2.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not float(self.two_view_max_error_px) > 0:
            raise ValueError("ColmapConfig.two_view_max_error_px must be > 0")


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
    T_view_ref = pose_from_rigid(geom.cam2_from_cam1)
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

    config = config or ColmapConfig()
    if not isinstance(camera, PinholeCamera):
        raise TypeError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    images = list(images)
    if len(images) < 2:
        raise ValueError(f"run_colmap_fewview needs a reference and at least one view, "
                         f"got {len(images)} image(s)")
    t0 = time.perf_counter()
    arrays = load_images(images, camera)
    cam = camera.undistorted()
    n = len(arrays)
    timings: Dict[str, float] = {}
    with workspace(workdir, "spgeo_colmap_", clear_sparse=True) as (image_dir, sparse_dir,
                                                                     db_path):
        names = [f"{i:03d}_ref.png" if i == 0 else f"{i:03d}.png" for i in range(n)]
        for name, arr in zip(names, arrays):
            if not cv2.imwrite(str(image_dir / name), cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)):
                raise OSError(f"cannot write {image_dir / name}")
        timings["prepare"] = time.perf_counter() - t0
        with quiet(config):
            result = _run_pipeline(db_path, image_dir, sparse_dir, names, cam, config, timings)
        result.workdir = None if workdir is None else str(Path(workdir))
        timings["total"] = time.perf_counter() - t0
        result.timings = timings
        logger.info("COLMAP few-view: %s, %d/%d images posed, %d points (%s)", result.status,
                    result.num_registered, result.num_images, result.num_points3D,
                    result.message or "all views registered")
        return result


def _run_pipeline(db_path: Path, image_dir: Path, sparse_dir: Path, names: List[str],
                  cam: PinholeCamera, config: ColmapConfig,
                  timings: Dict[str, float]) -> ColmapResult:
    """SIFT, exhaustive matching, incremental mapping and the two-view pass on the
    images ``names`` already written to ``image_dir``; ``timings`` gets each stage."""
    import pycolmap

    n = len(names)
    pycolmap.set_random_seed(int(config.random_seed))
    _extract_and_match(db_path, image_dir, names, cam, config, timings)
    ids, num_kp, verified, colmap_cam = _read_database(db_path, names)
    result = ColmapResult(status="failed", T_ref_view=[None] * (n - 1),
                          view_method=[None] * (n - 1), num_images=n, num_keypoints=num_kp,
                          num_verified_matches=verified)
    reasons: List[str] = []
    recs, error = incremental_mapping(db_path, image_dir, sparse_dir, mapper_options(config),
                                      timings)
    if error:
        reasons.append(error)
    best = _incremental_poses(result, recs, names, reasons)
    inconsistent = _two_view_pass(result, db_path, colmap_cam, ids, cam, config, reasons,
                                  timings)
    _set_status(result, best is not None, inconsistent, reasons, config)
    return result


def _extract_and_match(db_path: Path, image_dir: Path, names: List[str], cam: PinholeCamera,
                       config: ColmapConfig, timings: Dict[str, float]) -> None:
    """SIFT features of every image and exhaustive, geometrically verified matching
    into ``db_path`` (``timings["extract"]``, ``timings["match"]``)."""
    import pycolmap

    max_size = int(config.max_image_size) if config.max_image_size > 0 else 0
    timings["extract"] = extract_sift(db_path, image_dir, names, cam, config.num_threads,
                                      config.max_num_features, max_size)
    mo = sift_matching_options(config.num_threads, config.max_ratio)
    t = time.perf_counter()
    pycolmap.match_exhaustive(db_path, matching_options=mo,
                              verification_options=verification_options(config),
                              device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t


def _read_database(db_path: Path, names: List[str]):
    """``(image ids, keypoints per image, verified matches of each view with the
    reference, COLMAP camera)`` from the database; ``RuntimeError`` when an image
    was not imported."""
    import pycolmap

    n = len(names)
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
    return ids, num_kp, verified, colmap_cam


def _incremental_poses(result: ColmapResult, recs, names: List[str], reasons: List[str]):
    """Fill ``result`` from the reconstruction of ``recs`` that holds the reference and
    the most posed images; returns it (None when no reconstruction holds the reference)."""
    n = len(names)
    best, best_count = None, 0
    for rec in (recs or {}).values():
        reg = {im.name for im in rec.images.values() if im.has_pose}
        if names[0] in reg and len(reg) > best_count:
            best, best_count = rec, len(reg)
    if best is None and recs:
        reasons.append("the reference is in no reconstruction")
    if best is not None:
        posed = {im.name: im for im in best.images.values() if im.has_pose}
        T_world_ref = invert_pose(cam_from_world(posed[names[0]]))
        for j in range(1, n):
            im = posed.get(names[j])
            if im is not None:
                result.T_ref_view[j - 1] = relative_pose(T_world_ref, invert_pose(cam_from_world(im)))
                result.view_method[j - 1] = "incremental"
        result.num_points3D = int(best.num_points3D())
        result.mean_reprojection_error = float(best.compute_mean_reprojection_error())
    return best


def _two_view_pass(result: ColmapResult, db_path: Path, colmap_cam, ids: List[int],
                   cam: PinholeCamera, config: ColmapConfig, reasons: List[str],
                   timings: Dict[str, float]) -> List[int]:
    """Two-view geometry with the reference: the fallback pose of each unregistered
    view, the check of each incremental one; returns the inconsistent views."""
    import pycolmap

    n = len(ids)
    result.two_view_disagreement_deg = [float("nan")] * (n - 1)
    need_fallback = config.fallback_two_view and any(T is None for T in result.T_ref_view)
    inconsistent = []
    if need_fallback or config.check_two_view:
        from spgeo.evaluation.pose_metrics import rotation_error_deg

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
    return inconsistent


def _set_status(result: ColmapResult, has_model: bool, inconsistent: List[int],
                reasons: List[str], config: ColmapConfig) -> None:
    """``result.status``, ``num_registered`` and ``message`` from the poses found."""
    n = result.num_images
    for j in range(1, n):
        if result.T_ref_view[j - 1] is None and not config.fallback_two_view:
            reasons.append(f"view {j} not registered by the incremental mapper")

    n_posed = sum(T is not None for T in result.T_ref_view)
    result.num_registered = n_posed + 1 if n_posed else (1 if has_model else 0)
    if n_posed == 0:
        result.status = "failed"
    elif inconsistent:
        result.status = "inconsistent"
    else:
        result.status = "ok" if n_posed == n - 1 else "partial"
    result.message = "; ".join(reasons)


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


# ====================================================================== CLI
NAME = "colmap"


@dataclass
class ColmapComparison:
    """COLMAP (and any other estimators) vs ground truth on one frame set.

    Attributes:
        comparison: :func:`compare_on_dataset`'s dict.
        result: COLMAP's :class:`ColmapResult` (None when it did not run).
    """

    comparison: Dict[str, object]
    result: Optional[ColmapResult]

    def status_line(self) -> str:
        """One line: COLMAP's status, images posed, points and time ("" without a result)."""
        res = self.result
        if res is None:
            return ""
        return (f"COLMAP: status {res.status}, {res.num_registered}/{res.num_images} images posed "
                f"({', '.join(str(m) for m in res.view_method)}), {res.num_points3D} points, "
                f"{res.timings.get('total', float('nan')):.1f} s"
                + (f"; {res.message}" if res.message else ""))

    def table(self) -> str:
        """:func:`format_comparison` of :attr:`comparison`."""
        return format_comparison(self.comparison)

    def to_dict(self) -> Dict[str, object]:
        """The comparison plus ``"colmap_result"`` (:meth:`ColmapResult.summary`)."""
        payload = dict(self.comparison)
        if self.result is not None:
            payload["colmap_result"] = self.result.summary()
        return payload


def compare_colmap(frames: Sequence[object], config: Optional[ColmapConfig] = None,
                   workdir: Optional[Union[str, os.PathLike]] = None) -> ColmapComparison:
    """:func:`colmap_estimator` on ``frames`` (reference first, Frames with
    ground truth) through :func:`compare_on_dataset`."""
    est = colmap_estimator(config, workdir=workdir)
    comparison = compare_on_dataset(frames, {"colmap": est})
    return ColmapComparison(comparison, est.last_result)  # type: ignore[attr-defined]


def _parse_frames(values: Optional[List[str]]):
    if not values:
        return None
    if len(values) == 1 and ":" in values[0]:
        return values[0]
    try:
        return [int(v) for v in values]
    except ValueError:
        raise SystemExit(f"--frames: expected frame numbers or 'A:B[:S]', got {values}")


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = protocol_parser(
        "python -m spgeo.evaluation.references.colmap",
        "Relative-pose errors of COLMAP (pycolmap, SIFT, fixed intrinsics) on a "
        "reference frame plus supporting frames, against ground truth.",
        dataset=False, verbose=False)
    add_dataset_arguments(parser, frames_nargs="+",
                          frames_help="frame numbers, reference first (e.g. 0 4 8), or "
                                      "'A:B[:S]' (default: all frames of the data set)")
    parser.add_argument("--json", default=None, help="write the full comparison as JSON here")
    parser.add_argument("--workdir", default=None, help="keep COLMAP's files in this folder")
    parser.add_argument("--threads", type=int, default=1, help="COLMAP threads (default 1)")
    parser.add_argument("--no-fallback", action="store_true",
                        help="do not pose unregistered views by two-view geometry")
    add_verbose_argument(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    """Open the frames, run :func:`compare_colmap`, print the table, write ``--json``;
    0 on success, 1 if COLMAP posed no view."""
    args.frames = _parse_frames(args.frames)
    seq = open_sequence(args)
    frames = list(seq)
    if len(frames) < 2:
        raise ValueError("need a reference and at least one supporting frame")
    config = ColmapConfig(num_threads=args.threads, fallback_two_view=not args.no_fallback)
    out = compare_colmap(frames, config, workdir=args.workdir)
    print(f"{seq.name}: reference {frames[0].name}, views "
          f"{', '.join(f.name for f in frames[1:])}; camera {seq.camera}")
    if out.result is not None:
        print(out.status_line())
    print(out.table())
    if args.json:
        write_json(args.json, out.to_dict())
    res = out.result
    return 0 if res is not None and res.status != "failed" else 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: COLMAP (and any registered estimators) vs ground truth on
    a reference + supporting frames of a data set; prints a table and optionally
    writes JSON.  Returns the exit status (0 on success, 1 if COLMAP posed no view,
    2 for bad input)."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
