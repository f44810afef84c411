"""The methods of the VO comparison (:mod:`spgeo.evaluation.vo.compare`) and what they see.

:data:`METHODS` (with :data:`METHOD_LABELS`; :data:`ORACLE_METHODS` read the sensor depth),
the size every method sees (:func:`compare_size`: :data:`AUTO_RESOLUTION` is the processing
size ``spgeo vo`` chooses), the options (:class:`VOCompareConfig`), the frames resized once
(:func:`prepare_frames`) and one method run on them (:func:`run_method`: spgeo's VO, the
OpenCV feature baseline or COLMAP; :func:`check_methods` checks the names).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Optional, Sequence, Tuple, Union

import numpy as np
from tqdm import tqdm

from spgeo.vo import OdometryConfig
from spgeo.frame import Frame, resize_frame

from spgeo.evaluation.references.colmap_vo import ColmapVOConfig, check_resolution, run_colmap_vo
from spgeo.evaluation.references.feature_vo import FeatureVOConfig, run_feature_vo
from spgeo.evaluation.vo.reference_metrics import DEFAULT_GAP, DEFAULT_WINDOW

__all__ = ["METHODS", "METHOD_LABELS", "ORACLE_METHODS", "AUTO_RESOLUTION", "DEFAULT_RESOLUTION",
           "compare_size", "VOCompareConfig", "prepare_frames", "check_methods", "run_method"]

#: Method names accepted by :func:`~spgeo.evaluation.vo.compare.compare_vo`, in table order.
METHODS = ("spgeo-classical", "spgeo-depth", "feature", "colmap")
#: Human-readable description of each method (used in tables).
METHOD_LABELS = {
    "spgeo-classical": "spgeo VO, classical front-end (RGB only)",
    "spgeo-depth": "spgeo VO, depth front-end (ORACLE: reads sensor depth)",
    "feature": "OpenCV feature VO baseline (ORB + PnP, RGB only)",
    "colmap": "COLMAP incremental SfM reference (offline, RGB only)",
}
#: Methods that read the sensor depth (not monocular: oracle).
ORACLE_METHODS = ("spgeo-depth",)
#: ``resolution`` value meaning "the processing size ``spgeo vo`` chooses for
#: these frames" (:meth:`spgeo.vo.OdometryConfig.processing_size_for` of the
#: default :class:`~spgeo.vo.OdometryConfig`, the one rule of both tools).
AUTO_RESOLUTION = "auto"
#: What every method sees by default: :data:`AUTO_RESOLUTION`.
DEFAULT_RESOLUTION = AUTO_RESOLUTION


def compare_size(resolution: Union[None, str, Tuple[int, int]],
                 input_size: Tuple[int, int]) -> Optional[Tuple[int, int]]:
    """The ``(width, height)`` every method sees for frames of ``input_size``:
    ``spgeo vo``'s default processing size for :data:`AUTO_RESOLUTION`,
    ``resolution`` itself for a size, None (the frames' size) for None."""
    if isinstance(resolution, str):
        if resolution != AUTO_RESOLUTION:
            raise ValueError(f"resolution must be (width, height), None or "
                             f"{AUTO_RESOLUTION!r}, got {resolution!r}")
        return OdometryConfig().processing_size_for(tuple(input_size))
    return None if resolution is None else (int(resolution[0]), int(resolution[1]))


@dataclass
class VOCompareConfig:
    """Options of :func:`~spgeo.evaluation.vo.compare.compare_vo`.

    Attributes:
        resolution: ``(width, height)`` in pixels every method sees; default
            :data:`DEFAULT_RESOLUTION` (``"auto"``: ``spgeo vo``'s default
            processing size for the frames, :func:`compare_size`); None keeps
            the frames' size.
        max_time_diff: ATE timestamp association tolerance; None (default):
            0.1 for frame-number timestamps, 0.02 s otherwise
            (:func:`~spgeo.evaluation.trajectory.default_max_time_diff`).
        feature: :class:`~spgeo.evaluation.references.feature_vo.FeatureVOConfig` of the
            baseline (default options).
        colmap: :class:`~spgeo.evaluation.references.colmap_vo.ColmapVOConfig` (its
            ``resolution`` is replaced by ``resolution``); default options.
        odometry: ``spgeo.odometry.OdometryConfig`` of the spgeo methods; None
            (default) = its defaults.
        progress: tqdm bars, default False.
        rotation_gap: frame gap of the relative rotation error against the
            references (default 30,
            :func:`~spgeo.evaluation.vo.reference_metrics.relative_rotation_error`).
        scale_window: frames per window of the scale against COLMAP (default 50,
            :func:`~spgeo.evaluation.vo.reference_metrics.window_scale`).
    """

    resolution: Union[None, str, Tuple[int, int]] = DEFAULT_RESOLUTION
    max_time_diff: Optional[float] = None
    feature: FeatureVOConfig = field(default_factory=FeatureVOConfig)
    colmap: ColmapVOConfig = field(default_factory=ColmapVOConfig)
    odometry: Optional[object] = None
    progress: bool = False
    rotation_gap: int = DEFAULT_GAP
    scale_window: int = DEFAULT_WINDOW

    def __post_init__(self) -> None:
        if isinstance(self.resolution, str):
            compare_size(self.resolution, (640, 480))       # only "auto" is accepted
        else:
            self.resolution = check_resolution(self.resolution, "VOCompareConfig.resolution")
        if self.max_time_diff is not None and not float(self.max_time_diff) > 0:
            raise ValueError("VOCompareConfig.max_time_diff must be > 0")
        if int(self.rotation_gap) < 1 or int(self.scale_window) < 3:
            raise ValueError("VOCompareConfig: rotation_gap must be >= 1, scale_window >= 3")


# ================================================================== frames
def prepare_frames(frames: Iterable[Frame], resolution: Union[None, str, Tuple[int, int]],
                   keep_depth: bool = False, progress: bool = False) -> List[Frame]:
    """Frames resized once to ``resolution`` (:func:`compare_size` of the first
    frame's size; ``cv2.INTER_AREA``; depth with nearest neighbour when
    ``keep_depth``, else dropped), as every method of
    :func:`~spgeo.evaluation.vo.compare.compare_vo` would resize them; consumes a lazy
    reader frame by frame so that only the small copies are held."""
    out: List[Frame] = []
    size: Optional[Tuple[int, int]] = None
    for f in tqdm(frames, disable=not progress, desc="load", unit="frame"):
        if not out:
            size = compare_size(resolution, f.camera.size)
        out.append(resize_frame(f, size, keep_depth=keep_depth))
    return out


# ================================================================= methods
def _run_spgeo(frames: List[Frame], frontend: str, config: VOCompareConfig):
    from spgeo.apps.vo_run import run_vo

    kwargs = {} if config.odometry is None else {"config": config.odometry}
    size = compare_size(config.resolution, frames[0].camera.size) or frames[0].camera.size
    vo, _, _ = run_vo(frames, resolution=tuple(size), frontend=frontend,
                      progress=config.progress, **kwargs)
    r = vo.result()
    poses = np.array(r.poses, dtype=np.float64).reshape(-1, 4, 4)
    finite = np.all(np.isfinite(poses.reshape(len(poses), -1)), axis=1)
    ok = finite & np.array([s != "lost" for s in r.statuses], dtype=bool)
    poses[~ok] = np.nan
    counts: Dict[str, int] = {}
    for s in r.statuses:
        counts[s] = counts.get(s, 0) + 1
    return (np.asarray(r.timestamps, np.float64), poses, np.asarray(r.is_keyframe, bool),
            list(r.statuses), {"status_counts": counts})


def _run_feature(frames: List[Frame], config: VOCompareConfig):
    cfg = dataclasses.replace(config.feature, show_progress=config.progress)
    res = run_feature_vo(frames, frames[0].camera, cfg)
    return (res.timestamps, res.poses, res.is_keyframe, list(res.status),
            {"status_counts": res.status_counts(), "n_segments": res.n_segments})


def _run_colmap(frames: List[Frame], config: VOCompareConfig):
    cfg = dataclasses.replace(config.colmap, resolution=config.resolution,
                              show_progress=config.progress)
    res = run_colmap_vo(frames, cfg)
    info = {"model_sizes": res.model_sizes, "num_points3D": res.num_points3D,
            "mean_reprojection_error_px": res.mean_reprojection_error,
            "timings_s": dict(res.timings), "message": res.message}
    return res.timestamps, res.poses, None, res.status, info


def check_methods(methods: Sequence[str]) -> List[str]:
    """``methods`` as a list; ValueError for an unknown one or none."""
    methods = list(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"compare_vo: unknown method(s) {unknown}; expected {list(METHODS)}")
    if not methods:
        raise ValueError("compare_vo: no methods")
    return methods


def run_method(method: str, frames: List[Frame], cfg: VOCompareConfig):
    """``(timestamps, poses, is_keyframe, status, info)`` of one method on ``frames``."""
    n = len(frames)
    if method == "spgeo-depth" and any(f.depth is None for f in frames):
        raise ValueError("the depth front-end needs depth on every frame "
                         f"({sum(f.depth is None for f in frames)} of {n} have none)")
    if method.startswith("spgeo-"):
        return _run_spgeo(frames, method.split("-", 1)[1], cfg)
    if method == "feature":
        return _run_feature(frames, cfg)
    return _run_colmap(frames, cfg)
