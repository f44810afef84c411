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
import sys
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

__all__ = ["keyframe_depth_ratios", "keyframe_baseline_ratios", "main"]


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


def main(argv: Optional[Sequence[str]] = None) -> int:
    from spgeo.apps.vo_run import VORunConfig, run_dataset
    from spgeo.apps.args import add_dataset_arguments
    from spgeo.configs import parse_assignments, nest, apply_overrides
    from spgeo.datasets import open_dataset

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_dataset_arguments(ap)
    ap.add_argument("--frontend", default="classical")
    ap.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                    help="OdometryConfig overrides (Python literals)")
    args = ap.parse_args(argv)
    kind, path = args.dataset
    try:
        over: Dict[str, object] = nest(parse_assignments(args.set, strict=True))
        cfg = apply_overrides(VORunConfig(frontend=args.frontend, progress=False),
                              {"odometry": over} if over else {})
        run = run_dataset(kind, path, args.frames, cfg)
        frames = open_dataset(kind, path, frames=args.frames)
    except (ValueError, TypeError, OSError) as exc:
        print(f"vo_scale_drift: error: {exc}", file=sys.stderr)
        return 2
    ratios = keyframe_depth_ratios(run, frames)
    if not ratios:
        print("vo_scale_drift: error: no keyframe with sensor depth", file=sys.stderr)
        return 2
    r0 = ratios[0][1]
    baselines = keyframe_baseline_ratios(run)
    print("| frame | sensor / keyframe depth | relative to keyframe 0 | GT / estimated baseline |")
    print("|---|---|---|---|")
    for f, r in ratios:
        b = baselines.get(f)
        print(f"| {f} | {r:.3f} | {r / r0:.3f} | {'-' if b is None else f'{b:.3f}'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
