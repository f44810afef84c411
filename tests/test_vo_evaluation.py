"""Trajectory I/O, Sim(3) ATE (evo) and the OpenCV feature-VO baseline."""
import numpy as np
import pytest

from spgeo.evaluation.references.feature_vo import (STATUSES, FeatureVOConfig,
                                                    main as feature_vo_main, resize_frames,
                                                    run_feature_vo)
from spgeo.evaluation.trajectory import (TumTrajectory, ate_per_frame_and_keyframes, ate_sim3,
                                         path_length, read_status, read_tum, status_path_for,
                                         write_status, write_tum)
from spgeo.frame import Frame
from spgeo.geometry import so3_exp
from spgeo.similarity import sim3_parts, umeyama
from spgeo.synthetic import (SyntheticScene, TrajectoryConfig, default_camera, make_trajectory,
                             render_frames)


def _sim3_transform(poses, s, R, t):
    out = poses.copy()
    out[:, :3, 3] = s * poses[:, :3, 3] @ R.T + t
    out[:, :3, :3] = R @ poses[:, :3, :3]
    return out


# ---------------------------------------------------------------- file I/O
def test_tum_round_trip_and_evo_compatible(tmp_path):
    poses = make_trajectory(20, seed=3)
    stamps = 1305031102.175304 + np.arange(20) / 30.0
    path = tmp_path / "traj.txt"
    poses_with_gap = list(poses)
    poses_with_gap[5] = None                        # a frame without a pose is skipped
    poses_with_gap[6] = np.full((4, 4), np.nan)
    assert write_tum(path, stamps, poses_with_gap, header=["test"]) == 18
    traj = read_tum(path)
    keep = np.r_[0:5, 7:20]
    np.testing.assert_allclose(traj.timestamps, stamps[keep], atol=1e-6)
    np.testing.assert_allclose(traj.poses, poses[keep], atol=1e-8)
    # evo's own reader accepts the file (8 columns, '#' comments)
    from evo.tools import file_interface
    evo_traj = file_interface.read_tum_trajectory_file(str(path))
    assert evo_traj.num_poses == 18
    np.testing.assert_allclose(evo_traj.positions_xyz, poses[keep, :3, 3], atol=1e-8)
    # status file beside it
    spath = status_path_for(path)
    assert spath.name == "traj.status.txt"
    status = ["tracked"] * 20
    status[5] = status[6] = "lost"
    write_status(spath, stamps, status, extra={"keyframe": [int(i % 5 == 0) for i in range(20)]})
    ts, st = read_status(spath)
    assert st == status and np.allclose(ts, stamps, atol=1e-6)


def test_read_tum_errors(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match="bad.txt:3"):
        read_tum(bad)
    bad.write_text("0 0 0 0 0 0 0 0\n")
    with pytest.raises(ValueError, match="quaternion"):
        read_tum(bad)
    with pytest.raises(FileNotFoundError):
        read_tum(tmp_path / "missing.txt")
    ok = tmp_path / "ok.txt"
    ok.write_text("\n# c\n0.5 1 2 3 0 0 0 1  # trailing comment from another tool\n")
    traj = read_tum(ok)
    assert len(traj) == 1 and np.allclose(traj.poses[0][:3, 3], [1, 2, 3])


# --------------------------------------------------------------------- ATE
def test_ate_sim3_recovers_known_sim3():
    gt = make_trajectory(120, seed=1)
    ts = np.arange(120) / 30.0
    R = so3_exp([0.4, -0.3, 1.2])
    s_est = 0.25                                   # estimate is 4x smaller than metric
    est = _sim3_transform(gt, s_est, R, np.array([3.0, -1.0, 0.5]))
    res = ate_sim3((ts, est), (ts, gt))
    assert res.n_associated == 120 and res.label == "per-frame"
    assert res.rmse < 1e-9 and res.max < 1e-9
    assert res.scale == pytest.approx(1 / s_est, rel=1e-9)
    assert res.trajectory_length == pytest.approx(path_length(gt[:, :3, 3]))
    assert res.rmse_percent_of_length < 1e-6


def test_ate_sim3_noise_level_matches_numpy_umeyama():
    rng = np.random.default_rng(0)
    gt = make_trajectory(150, seed=2)
    ts = np.arange(150) / 30.0
    R = so3_exp([-0.2, 0.9, 0.1])
    s_est, sigma = 2.0, 0.002                       # sigma: per-axis noise in metres
    est = _sim3_transform(gt, s_est, R, np.array([0.1, 0.2, 0.3]))
    est[:, :3, 3] += s_est * rng.normal(0, sigma, (150, 3))
    res = ate_sim3((ts, est), (ts, gt))
    # numpy Umeyama reference
    R_u, t_u, s_u = sim3_parts(umeyama(est[:, :3, 3], gt[:, :3, 3]))
    aligned = s_u * est[:, :3, 3] @ R_u.T + t_u
    rmse_u = np.sqrt(np.mean(np.sum((aligned - gt[:, :3, 3]) ** 2, 1)))
    assert res.scale == pytest.approx(s_u, rel=1e-6)
    assert res.rmse == pytest.approx(rmse_u, rel=1e-6)
    np.testing.assert_allclose(res.rotation, R_u, atol=1e-6)
    assert res.scale == pytest.approx(1 / s_est, rel=0.01)
    # 3-D RMSE of isotropic noise ~ sqrt(3) sigma
    assert 0.8 * np.sqrt(3) * sigma < res.rmse < 1.2 * np.sqrt(3) * sigma
    assert res.median <= res.rmse <= res.max


def test_ate_association_with_time_offsets_and_subsets():
    gt = make_trajectory(90, seed=4)
    ts = np.arange(90) / 30.0
    est = _sim3_transform(gt, 0.5, so3_exp([0, 0, 0.7]), np.zeros(3))
    # estimate stamps jittered by 5 ms, every 2nd frame, one frame without a pose
    est_ts = ts + 0.005
    est[10] = np.nan
    sub = np.arange(0, 90, 2)
    res = ate_sim3((est_ts[sub], est[sub]), (ts, gt), max_time_diff=0.02)
    assert res.n_associated == len(sub) - 1 and res.rmse < 1e-9
    # offsets beyond the tolerance do not associate
    with pytest.raises(ValueError):
        ate_sim3((ts + 100.0, est), (ts, gt), max_time_diff=0.02)
    # keyframe-only variant
    kf = np.zeros(90, bool)
    kf[::10] = True
    both = ate_per_frame_and_keyframes((est_ts, est), TumTrajectory(ts, gt), kf)
    assert both["per-frame"].n_associated == 89
    assert both["keyframe-only"].n_associated == 8   # keyframe 10 has no pose
    assert both["keyframe-only"].label == "keyframe-only"
    # degenerate input: all estimated positions identical
    flat = np.tile(np.eye(4), (90, 1, 1))
    with pytest.raises(ValueError):
        ate_sim3((ts, flat), (ts, gt))


# -------------------------------------------------------------- feature VO
N_SYN = 60


@pytest.fixture(scope="module")
def synthetic_sequence():
    scene = SyntheticScene.generate(0)
    camera = default_camera(320, 240)
    poses = make_trajectory(N_SYN, 0, TrajectoryConfig())
    frames = render_frames(scene, camera, poses, supersample=2)
    return frames


@pytest.mark.slow
def test_feature_vo_synthetic(synthetic_sequence, tmp_path):
    frames = synthetic_sequence
    gt = np.array([f.T_world_cam for f in frames])
    ts = np.array([f.timestamp for f in frames])
    length = path_length(gt[:, :3, 3])
    # enough translation for a monocular initialisation (~30 cm over the sequence at
    # ~2.7 m median depth); rotation-only motion would not initialise
    assert length > 0.5
    assert np.linalg.norm(gt[30, :3, 3] - gt[0, :3, 3]) > 0.15
    res = run_feature_vo(frames)
    assert res.poses.shape == (N_SYN, 4, 4) and len(res.status) == N_SYN
    assert set(res.status) <= set(STATUSES)
    assert res.valid.sum() >= N_SYN - 5
    np.testing.assert_allclose(res.poses[np.flatnonzero(res.valid)[0]], np.eye(4), atol=1e-12)
    assert res.is_keyframe.sum() >= 2 and res.n_segments == 1
    ate = res.ate(ts, gt)
    per_frame, kf = ate["per-frame"], ate["keyframe-only"]
    assert per_frame.rmse_percent_of_length < 6.0, str(per_frame)
    assert kf is not None and kf.rmse_percent_of_length < 8.0
    assert res.timings["total"] > 0 and np.all(res.frame_time_s >= 0)
    out = res.save_tum(tmp_path / "trajectory.txt")
    back = read_tum(out)
    assert len(back) == res.valid.sum()
    assert ate_sim3(back, (ts, gt)).rmse == pytest.approx(per_frame.rmse, rel=1e-5)
    _, st = read_status(status_path_for(out))
    assert st == res.status


@pytest.mark.slow
def test_feature_vo_blank_frame_is_flagged(synthetic_sequence):
    frames = list(synthetic_sequence[:50])
    k = 35
    f = frames[k]
    frames[k] = Frame(image=np.zeros_like(f.image), camera=f.camera, timestamp=f.timestamp,
                      name=f.name)
    res = run_feature_vo(frames)
    assert res.status[k] == "lost" and not res.valid[k]
    # the next frames re-localise against the same map
    assert all(s == "ok" for s in res.status[k + 1:])
    assert res.n_segments == 1
    gt = np.array([f.T_world_cam for f in synthetic_sequence[:50]])
    ts = np.array([f.timestamp for f in frames])
    assert np.isfinite(res.ate(ts, gt)["per-frame"].rmse)


def test_feature_vo_never_crashes_on_bad_input():
    camera = default_camera(64, 48)
    blank = [np.zeros((48, 64)) for _ in range(8)]
    res = run_feature_vo(blank, camera, FeatureVOConfig())
    assert not res.valid.any() and set(res.status) == {"init"}
    with pytest.raises(ValueError):
        run_feature_vo([], camera)
    with pytest.raises(ValueError):
        run_feature_vo(blank)                       # raw images need a camera
    with pytest.raises(ValueError):
        FeatureVOConfig(detector="surf")


@pytest.mark.slow
def test_feature_vo_7scenes(shared_data, tmp_path, capsys):
    path = shared_data / "7scenes_redkitchen_dev"
    if not path.is_dir():
        pytest.skip("7scenes_redkitchen_dev not in the shared data")
    from spgeo.datasets import open_dataset

    frames = resize_frames(list(open_dataset("7scenes", path, frames="0:100", load_depth=False)),
                           320, 240)
    res = run_feature_vo(frames)
    ts = [f.timestamp for f in frames]
    gt = [f.T_world_cam for f in frames]
    ate = res.ate(ts, gt, max_time_diff=0.1)["per-frame"]
    assert res.valid.sum() >= 50
    assert np.isfinite(ate.rmse) and ate.rmse < 0.25, str(ate)
    # CLI on a short range writes the outputs
    rc = feature_vo_main(["--dataset", "7scenes", str(path), "--frames", "0:40",
                          "--resolution", "160x120", "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    assert (tmp_path / "trajectory.txt").is_file() and (tmp_path / "report.json").is_file()
    assert (tmp_path / "trajectory.status.txt").is_file()
    assert "feature VO" in capsys.readouterr().out


def test_vo_synthetic_config_overrides():
    from spgeo.evaluation.vo.synthetic import odometry_config, parse_overrides

    over = parse_overrides(["pixel_budget=None", "render_prior_weight = 1e-5",
                            "tracker.iterations=(10, 5)", "tracker.relative_cost_tol=1e-4",
                            "tracker.photometric.huber_delta=0.05"])
    assert over == {"pixel_budget": None, "render_prior_weight": 1e-5,
                    "tracker": {"iterations": (10, 5), "relative_cost_tol": 1e-4,
                                "photometric": {"huber_delta": 0.05}}}
    cfg = odometry_config(over)
    assert cfg.tracker.relative_cost_tol == 1e-4 and cfg.tracker.photometric.huber_delta == 0.05
    assert cfg.tracker.levels == 3 and cfg.render_prior_weight == 1e-5
    for bad in (["pixel_budget"], ["=1"], ["window=five"], ["a.=1"],
                ["window=3", "window.x=1"]):
        with pytest.raises((ValueError, SyntaxError)):
            parse_overrides(bad)
    with pytest.raises(TypeError):
        odometry_config({"nonsense": {"x": 1}})
