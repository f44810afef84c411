"""Monocular VO (spgeo.odometry) on a synthetic hand-held sequence, 160x120,
depth-derived ("depth", oracle) front-end."""
import json
import logging

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_sim3, read_status, read_tum
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.odometry import (Odometry, OdometryConfig, kf_pose_key, kf_scale_key)

log = logging.getLogger(__name__)
CAM = synthetic.default_camera(160, 120)
N_FRAMES = 50
BLANK = 25


def frontend():
    return make_frontend("depth", FrontEndConfig(working_size=(160, 120)))


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    poses = synthetic.make_trajectory(N_FRAMES, 0)
    return synthetic.render_frames(scene, CAM, poses, supersample=2)


@pytest.fixture(scope="module")
def run(frames):
    """Default config over the sequence, with frame BLANK replaced by a blank image."""
    vo = Odometry(CAM, OdometryConfig(), frontend())
    results = []
    for i, f in enumerate(frames):
        if i == BLANK:
            f = Frame(np.zeros_like(f.image), CAM, f.timestamp, depth=f.depth, name="blank")
        results.append(vo.track(f))
    return vo, results


def test_end_to_end_accuracy(frames, run):
    """Several keyframes; Sim(3) ATE of the tracked frames < 3% of the
    trajectory length (measured 1.7% on this 50-frame, 0.63 m sequence)."""
    vo, results = run
    res = vo.result()
    assert len(res.timestamps) == N_FRAMES
    assert res.is_keyframe.sum() >= 3
    assert res.statuses[0] == "keyframe"
    good = np.array([s != "lost" for s in res.statuses])
    gt = np.array([f.T_world_cam for f in frames])
    ate = ate_sim3((res.timestamps[good], res.poses[good]), (res.timestamps, gt))
    log.info("VO ATE %.4f m = %.2f%% of %.2f m, %d keyframes, %.1f FPS", ate.rmse,
             ate.rmse_percent_of_length, ate.trajectory_length, res.is_keyframe.sum(),
             N_FRAMES / sum(r.timings["total"] for r in results))
    assert ate.rmse_percent_of_length < 3.0
    kf_ate = ate_sim3((res.keyframe_timestamps, res.keyframe_poses), (res.timestamps, gt),
                      label="keyframe-only")
    assert kf_ate.rmse_percent_of_length < 3.0


def test_blank_frame_is_lost_and_tracking_continues(run):
    vo, results = run
    assert results[BLANK].status == "lost"
    np.testing.assert_allclose(results[BLANK].T_world_cam, results[BLANK - 1].T_world_cam)
    after = [r.status for r in results[BLANK + 1:]]
    assert after[0] in ("relocalised", "keyframe")
    assert sum(s == "lost" for s in after) <= 2
    assert after[-1] != "lost"


def test_save_writes_parseable_files(run, tmp_path):
    vo, _ = run
    paths = vo.save(tmp_path)
    traj = read_tum(paths["trajectory"])
    kfs = read_tum(paths["keyframes"])
    res = vo.result()
    assert len(traj.timestamps) == N_FRAMES
    assert len(kfs.timestamps) == int(res.is_keyframe.sum())
    np.testing.assert_allclose(traj.poses[-1], res.poses[-1], atol=1e-6)
    _, status = read_status(paths["status"])
    assert status == res.statuses
    rep = json.loads(paths["report"].read_text())
    assert rep["n_frames"] == N_FRAMES and rep["status_counts"]["lost"] >= 1


def test_fixed_lag_marginalises_old_keyframes(frames):
    """Default 5-keyframe window; frequent keyframes (relative-cost threshold
    0.08, 3 LM iterations per update, for test time: measured 9 keyframes,
    ATE 2.0%): once more than 5 keyframes exist, the oldest keyframes' keys
    have left the smoother (marginalised) and exactly the last 5 remain."""
    cfg = OdometryConfig(kf_max_relative_cost=0.08, map_iterations=3)
    vo = Odometry(CAM, cfg, frontend())
    for f in frames:
        vo.track(f)
    n_kf = len(vo.keyframes)
    assert n_kf > cfg.window
    est = vo.smoother_estimate()
    in_window = [k for k in range(n_kf) if est.exists(kf_pose_key(k))]
    assert in_window == list(range(n_kf - cfg.window, n_kf))
    assert not est.exists(kf_scale_key(0, 0))
    assert est.exists(kf_scale_key(n_kf - 1, 0))
    res = vo.result()
    assert "lost" not in res.statuses
    gt = np.array([f.T_world_cam for f in frames])
    ate = ate_sim3((res.timestamps, res.poses), (res.timestamps, gt))
    assert ate.rmse_percent_of_length < 3.5


def test_bad_input_raises(frames):
    vo = Odometry(CAM, OdometryConfig(), frontend())
    small = synthetic.default_camera(80, 60)
    with pytest.raises(ValueError):
        vo.track(Frame(np.zeros((60, 80, 3), np.float32), small, 0.0))
    with pytest.raises(ValueError):
        Odometry(CAM, OdometryConfig(), None)
    with pytest.raises(ValueError):
        OdometryConfig(window=1)
