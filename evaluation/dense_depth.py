"""Runs whose dense depth :mod:`spgeo.evaluation.depth_eval` scores (issue 54): VO runs on
named sequences with sensor depth, and few-view SfM on frame triplets.

Sequence specs (:func:`vo_frames`): ``7scenes[:A:B]`` (the shared 7-Scenes redkitchen
frames ``A:B``, default ``0:300``, all there are), ``tum`` (the shared TUM fr1_desk 9
frames), ``icl`` (the shared ICL-NUIM living room's 5 widely spaced frames),
``synthetic[:SEED[:N]]`` (a rendered room, :func:`spgeo.evaluation.vo.synthetic.synthetic_sequence`,
``N`` frames at 160x120, default seed 0 and 90 frames; exact depth in scene units).
SfM specs (:func:`sfm_triplets`): ``7scenes:G`` (triplets ``(ref, ref+G, ref+2G)`` for each
given ref), ``tum`` (frames 0, 4, 8), ``icl`` (frames 1, 2, 3).

:func:`vo_depth_row` runs the VO (:func:`spgeo.apps.vo_run.run_odometry`, in this process)
and scores its keyframes; :func:`sfm_depth_row` runs :func:`spgeo.sfm.few_view_sfm` on
each triplet (the front-end at 320x240, as ``spgeo eval sfm_real``) and scores its
reference depth.  Each returns one JSON-ready row (:data:`ROW_KEYS`).
"""
from __future__ import annotations

import logging
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.depth_eval import (DEPTH_RANGE, DepthMapScore, merge_breakdowns,
                                         sfm_reference_depth, summarize, vo_keyframe_depth)
from spgeo.evaluation.shared_data import shared_data_root

__all__ = ["SEVENSCENES", "SFM_SIZE", "vo_frames", "vo_overrides", "vo_depth_row",
           "sfm_triplets", "sensor_depth_floor", "sfm_depth_row", "ROW_KEYS"]

log = logging.getLogger(__name__)

SEVENSCENES = "7scenes_redkitchen_dev"
#: synthetic VO spec defaults: seed, frames
SYNTHETIC_DEFAULT = (0, 90)
#: the keys every row has (besides the summary's, :func:`summarize`)
ROW_KEYS = ("kind", "sequence", "frontend", "frames", "keyframes", "ate_m", "rot_err_deg",
            "seconds", "error")


def _parts(spec: str) -> Tuple[str, List[str]]:
    name, *rest = spec.strip().split(":")
    return name, rest


def vo_frames(spec: str):
    """The frames (with sensor depth and ground truth) of a VO sequence spec (module
    docstring); ValueError for an unknown spec."""
    from spgeo.datasets import open_dataset

    name, rest = _parts(spec)
    root = shared_data_root()
    if name == "7scenes":
        a, b = (int(rest[0]), int(rest[1])) if rest else (0, 300)
        return open_dataset("7scenes", root / SEVENSCENES, frames=f"{a}:{b}", load_depth=True)
    if name == "tum":
        return open_dataset("tum", root / "tum_fr1_desk_9", load_depth=True)
    if name == "icl":
        return open_dataset("icl", root / "icl_nuim_lr_5", load_depth=True)
    if name == "synthetic":
        from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence

        seed = int(rest[0]) if rest else SYNTHETIC_DEFAULT[0]
        n = int(rest[1]) if len(rest) > 1 else SYNTHETIC_DEFAULT[1]
        return synthetic_sequence(SyntheticVOConfig(n_frames=n, seed=seed, rotation=None))
    raise ValueError(f"unknown VO sequence {spec!r} (7scenes[:A:B], tum, icl, "
                     "synthetic[:SEED[:N]])")


def vo_overrides(spec: str) -> Dict[str, Any]:
    """The sequence's own :class:`~spgeo.apps.vo_run.VORunConfig` overrides: the
    synthetic frames are processed at their size (160x120)."""
    return {"odometry.resolution": (160, 120)} if _parts(spec)[0] == "synthetic" else {}


def _row(kind: str, sequence: str, frontend: str, scores: Sequence[DepthMapScore],
         **extra) -> Dict[str, Any]:
    row: Dict[str, Any] = {k: None for k in ROW_KEYS}
    row.update(kind=kind, sequence=sequence, frontend=frontend, **summarize(scores), **extra)
    row["maps"] = [{"name": s.name, "frame": s.frame, **s.metrics} for s in scores]
    return row


def vo_depth_row(spec: str, config, depth_range: Tuple[float, float] = DEPTH_RANGE,
                 breakdown: bool = False, oracle: bool = False) -> Dict[str, Any]:
    """Run the VO on the sequence ``spec`` with ``config`` (a
    :class:`~spgeo.apps.vo_run.VORunConfig`; :func:`vo_overrides` applied on top) and
    score its keyframes' depth (:func:`~spgeo.evaluation.depth_eval.vo_keyframe_depth`):
    the row has the summary, ``frames``, ``keyframes`` (with depth and a frame),
    ``ate_m`` (per-frame Sim(3) ATE RMSE), ``seconds`` (the VO run's wall time),
    ``maps`` (per keyframe), with ``breakdown`` the merged
    :func:`~spgeo.evaluation.depth_eval.primitive_breakdown` and with ``oracle`` the
    ``oracle_scale_abs_rel`` / ``oracle_plane_abs_rel`` of
    :func:`~spgeo.evaluation.depth_eval.oracle_depth_maps` (mean over the keyframes)."""
    from spgeo.apps.vo_run import run_odometry
    from spgeo.configs import apply_overrides

    frames = vo_frames(spec)
    cfg = apply_overrides(config, vo_overrides(spec))
    t0 = time.perf_counter()
    run = run_odometry(frames, cfg, n_frames=len(frames))
    secs = time.perf_counter() - t0
    ate = run.ate()
    per = None if ate is None else ate.get("per-frame")
    scores = vo_keyframe_depth(run.odometry, frames, depth_range, breakdown, oracle)
    row = _row("vo", spec, cfg.frontend, scores, frames=len(frames), keyframes=len(scores),
               ate_m=None if per is None else float(per.rmse), seconds=secs,
               fps=run.fps)
    if breakdown:
        row["breakdown"] = merge_breakdowns([s.breakdown for s in scores])
    return row


def sfm_triplets(spec: str, refs: Sequence[int] = (0, 60, 120)
                 ) -> List[Tuple[int, List[Any]]]:
    """``[(reference frame number, [ref frame, view, view]), ...]`` of an SfM spec (module docstring),
    frames with sensor depth and ground truth.  A 7-Scenes triplet past the shared
    frames is left out (logged)."""
    from spgeo.datasets import open_dataset

    name, rest = _parts(spec)
    root = shared_data_root()
    if name == "7scenes":
        if not rest:
            raise ValueError(f"SfM spec {spec!r}: give the gap, e.g. 7scenes:10")
        gap = int(rest[0])
        seq = open_dataset("7scenes", root / SEVENSCENES, load_depth=True)
        index = {int(n): i for i, n in enumerate(seq.frame_numbers)}
        out = []
        for r in refs:
            nums = [r, r + gap, r + 2 * gap]
            if all(n in index for n in nums):
                out.append((r, [seq[index[n]] for n in nums]))
            else:
                log.warning("SfM %s: triplet %s is past the shared frames; left out", spec, nums)
        return out
    if name in ("tum", "icl"):
        sub, nums = (("tum_fr1_desk_9", [0, 4, 8]) if name == "tum"
                     else ("icl_nuim_lr_5", [1, 2, 3]))
        seq = open_dataset(name, root / sub, load_depth=True)
        index = {int(n): i for i, n in enumerate(seq.frame_numbers)}
        return [(nums[0], [seq[index[n]] for n in nums])]
    raise ValueError(f"unknown SfM spec {spec!r} (7scenes:G, tum, icl)")


#: SfM working size of the evaluation (as ``spgeo eval sfm_real``)
SFM_SIZE = (320, 240)


def sensor_depth_floor(frame, working_size: Tuple[int, int] = SFM_SIZE,
                       depth_range: Tuple[float, float] = DEPTH_RANGE) -> Dict[str, float]:
    """The floor of a reference depth: the ``depth`` front-end's primitives of ``frame``
    (normals and one log-scale per primitive fitted to its sensor depth, at
    ``working_size``) scored against that depth
    (:func:`~spgeo.evaluation.depth_eval.median_scaled_depth`): what the primitives can
    represent of the sensor depth (its noise, its registration to colour, the shapes)
    when no view has to find their scales."""
    from spgeo.evaluation.depth_eval import median_scaled_depth, resize_depth
    from spgeo.frontend import FrontEndConfig, make_frontend

    fe = make_frontend("depth", FrontEndConfig(working_size=tuple(working_size)))
    prims = fe.primify(frame.image, frame.camera, frame.depth)
    return median_scaled_depth(prims.depth_map(), resize_depth(frame.depth, prims.camera.size),
                               *depth_range)


def _rotation_errors(result, frames) -> List[float]:
    """Per view: the rotation error (degrees) of ``result.T_ref_view`` against the
    ground truth (NaN without)."""
    from spgeo.evaluation.pose_metrics import rotation_error_deg

    ref = frames[0].T_world_cam
    out = []
    for T, v in zip(result.T_ref_view, frames[1:]):
        if ref is None or v.T_world_cam is None or not np.all(np.isfinite(T)):
            out.append(float("nan"))
            continue
        R_gt = (np.linalg.inv(ref) @ v.T_world_cam)[:3, :3]
        out.append(float(rotation_error_deg(np.asarray(T)[:3, :3], R_gt)))
    return out


def sfm_depth_row(spec: str, refs: Sequence[int] = (0, 60, 120), frontend: str = "classical",
                  config=None, depth_range: Tuple[float, float] = DEPTH_RANGE
                  ) -> Dict[str, Any]:
    """Few-view SfM (``frontend`` at 320x240, ``config`` a :class:`~spgeo.sfm.SfMConfig`,
    None: the default) on each triplet of ``spec`` (:func:`sfm_triplets`), its reference
    depth scored (:func:`~spgeo.evaluation.depth_eval.sfm_reference_depth`); ``frontend
    "floor"``: no SfM, :func:`sensor_depth_floor` of each reference.  The row has
    the summary over the triplets, ``frames`` (triplets), ``rot_err_deg`` (mean over the
    views), ``seconds`` (sum of the SfM runs), ``maps`` (per triplet, with its status)."""
    from spgeo.frontend import FrontEndConfig, make_frontend
    from spgeo.sfm import SfMConfig, few_view_sfm

    config = SfMConfig() if config is None else config
    scores, rot, secs, status = [], [], 0.0, []
    for number, frames in sfm_triplets(spec, refs):
        ref = frames[0]
        if frontend == "floor":
            scores.append(DepthMapScore(f"ref {number}", number, sensor_depth_floor(ref)))
            status.append("floor")
            continue
        fe = make_frontend(frontend, FrontEndConfig(working_size=SFM_SIZE))
        t0 = time.perf_counter()
        res = few_view_sfm(ref.image, [v.image for v in frames[1:]], ref.camera, fe, config,
                           ref_depth=ref.depth if fe.uses_depth else None)
        secs += time.perf_counter() - t0
        scores.append(DepthMapScore(f"ref {number}", number,
                                    sfm_reference_depth(res, ref.depth, depth_range)))
        rot += _rotation_errors(res, frames)
        status.append(res.status)
    row = _row("sfm", spec, frontend, scores, frames=len(scores), seconds=secs,
               rot_err_deg=float(np.nanmean(rot)) if np.any(np.isfinite(rot)) else None)
    for m, s in zip(row["maps"], status):
        m["status"] = s
    return row
