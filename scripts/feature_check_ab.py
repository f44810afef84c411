"""The feature check on and off on the two driving runs of results.md ("The house, fifth
pass (issue 50)"): the shared KITTI clip (51 frames, defaults: live mapping) and the first
32 frames of the synthetic straight street (inline mapping), as tests/test_vo_drive.py and
tests/test_road.py run them.  Prints status counts, map segments and the ATE (percent of the
ground-truth path, frames not lost) or t_rel.  Run from a checkout's root, with that
checkout's spgeo installed (it imports the checkout's tests):

    python3 scripts/feature_check_ab.py [../shared]
"""
from __future__ import annotations

import collections
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def _configs(cfg):
    from spgeo.vo.feature_retry import FeatureRetryConfig
    return (("check on", cfg),
            ("check off", replace(cfg, feature_retry=FeatureRetryConfig(min_agreement=None))))


def kitti(shared: Path) -> None:
    from spgeo.apps.vo_run import run_vo
    from spgeo.metrics.ate import ate_sim3
    from spgeo.vo import OdometryConfig
    from test_vo_drive import _kitti_frames

    frames, gt = _kitti_frames(shared / "data" / "kitti_odometry_clip_51", 51)
    stamps = np.arange(len(frames), dtype=float)
    length = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    for name, cfg in _configs(OdometryConfig()):
        vo, _, _ = run_vo(frames, config=cfg, progress=False)
        res = vo.result()
        status = [str(s) for s in res.status]
        ok = np.array([s != "lost" for s in status])
        ate = ate_sim3((stamps[ok], res.poses[ok]), (stamps[ok], gt[ok]))
        print(f"KITTI clip, {name}: {dict(collections.Counter(status))}, "
              f"{len(set(res.segments.tolist()))} segment(s), ATE {100 * ate.rmse / length:.2f} %")
        vo.close()


def street() -> None:
    from spgeo import synthetic
    from spgeo.evaluation.kitti_metrics import kitti_relative_errors
    from spgeo.synthetic.road import straight_street
    from spgeo.vo import MappingConfig, OdometryConfig
    from test_road import _drive, _steps

    road = straight_street()
    frames = synthetic.render_frames(road.scene, synthetic.street_camera(), road.drive()[:32],
                                     supersample=2)
    gt = np.stack([f.T_world_cam for f in frames])
    for name, cfg in _configs(OdometryConfig(mapping=MappingConfig(mode="inline"))):
        status, res = _drive(frames, cfg)
        first = next(i for i in range(1, len(status)) if status[i] not in ("init", "lost"))
        est = np.stack(res.poses)
        scale = _steps(gt[first:]).sum() / _steps(est[first:]).sum()
        t_rel = kitti_relative_errors(est[first:], gt[first:], scale).t_rel_pct
        print(f"street, {name}: {dict(collections.Counter(status))}, t_rel {t_rel:.2f} %")


if __name__ == "__main__":
    kitti(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared")
    street()
