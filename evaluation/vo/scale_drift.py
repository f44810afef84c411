"""Scale drift of a monocular VO run, keyframe by keyframe: the median ratio of the
sensor depth to each keyframe's primitive depth (after the run).

    python -m spgeo.evaluation.vo.scale_drift --dataset 7scenes PATH [--frames 0:300]
        [--frontend classical] [--set FIELD=VALUE ...]

A monocular map has one unknown scale; if it held, the ratio would be the same for
every keyframe.  Its growth or decay along the run is the scale drift that
Sim(3) ATE alignment can only average out.  The data set must have depth (used
here only, never by a monocular front-end).  Prints one line per keyframe:
frame number, ratio, the ratio relative to keyframe 0's, and the ratio of the
ground-truth to the estimated distance from the previous keyframe (the
trajectory's own scale: where it departs from the depth ratio, translations and
depths of the map disagree).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.tables import cell, markdown_table
from spgeo.evaluation.runner import (add_vo_arguments, open_sequence, protocol_parser,
                                     run_protocol, run_vo_dataset)

__all__ = ["keyframe_depth_ratios", "keyframe_baseline_ratios", "ScaleDriftResult", "scale_drift",
           "build_parser", "run", "main"]


def keyframe_depth_ratios(run, frames) -> List[Tuple[int, float]]:
    """``[(frame number in the run, median(sensor depth / keyframe depth)), ...]`` for
    the keyframes of ``run`` (:class:`spgeo.apps.vo_run.VORun`); ``frames``: the
    run's input frames with depth, indexable in run order.  Keyframes without a
    valid pixel are left out."""
    import cv2

    res = run.result()
    kf_frames = [i for i, s in enumerate(res.statuses) if s in ("keyframe", "reinit")]
    out = []
    for f, kf in zip(kf_frames, run.odometry.keyframes):
        prims = kf.primitives
        gt = frames[f].depth
        if gt is None:
            continue
        gt = cv2.resize(np.asarray(gt, np.float32), prims.camera.size,
                        interpolation=cv2.INTER_NEAREST).reshape(-1)[prims.pixels]
        est = np.exp(prims.scaled_log_depth())
        ok = np.isfinite(gt) & (gt > 0) & np.isfinite(est)
        if ok.any():
            out.append((f, float(np.median(gt[ok] / est[ok]))))
    return out


def keyframe_baseline_ratios(run) -> Dict[int, float]:
    """``{frame number: |GT baseline| / |estimated baseline|}`` from the previous
    keyframe to each keyframe of ``run`` (final poses; keyframes without ground
    truth or with a zero estimated baseline are left out)."""
    res = run.result()
    kf = [i for i in np.flatnonzero(res.is_keyframe) if run.gt_poses[i] is not None]
    out = {}
    for a, b in zip(kf[:-1], kf[1:]):
        est = np.linalg.norm(res.poses[b][:3, 3] - res.poses[a][:3, 3])
        gt = np.linalg.norm(run.gt_poses[b][:3, 3] - run.gt_poses[a][:3, 3])
        if est > 0:
            out[int(b)] = float(gt / est)
    return out


@dataclass
class ScaleDriftResult:
    """:func:`scale_drift` of a run: ``ratios`` (:func:`keyframe_depth_ratios`) and
    ``baselines`` (:func:`keyframe_baseline_ratios`)."""

    ratios: List[Tuple[int, float]]
    baselines: Dict[int, float]

    def table(self) -> str:
        """Markdown: one line per keyframe (frame, ratio, ratio relative to keyframe 0's,
        ground-truth / estimated baseline or ``-``)."""
        r0 = self.ratios[0][1]
        return "\n".join(markdown_table(
            ["frame", "sensor / keyframe depth", "relative to keyframe 0",
             "GT / estimated baseline"],
            [[cell(f), cell(r, 3), cell(r / r0, 3), cell(self.baselines.get(f), 3)]
             for f, r in self.ratios]))


def scale_drift(run, frames) -> ScaleDriftResult:
    """The keyframe depth and baseline ratios of ``run`` on ``frames`` (see
    :func:`keyframe_depth_ratios`).  Raises ValueError when no keyframe has sensor depth."""
    ratios = keyframe_depth_ratios(run, frames)
    if not ratios:
        raise ValueError("no keyframe with sensor depth")
    return ScaleDriftResult(ratios, keyframe_baseline_ratios(run))


NAME = "vo_scale_drift"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__)
    add_vo_arguments(ap)
    return ap


def run(args: argparse.Namespace) -> int:
    """Run the VO on ``args.dataset`` and print the :class:`ScaleDriftResult` table."""
    vo_run = run_vo_dataset(args)
    frames = open_sequence(args, load_depth=None)
    print(scale_drift(vo_run, frames).table())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
