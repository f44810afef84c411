"""Monocular VO under large inter-frame motion: a synthetic forward drive
(``spgeo.synthetic.make_forward_trajectory``: 0.4 m per frame, about 6 % of the
median depth, turning up to a few degrees per frame) at 320x240."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_sim3
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.geometry import invert_pose, rotation_angle_deg
from spgeo.vo import Odometry, OdometryConfig
from spgeo.vo.feature_retry import FeatureRetry, FeatureRetryConfig
from spgeo.vo.tracking import Keyframe, track_frame

SIZE = (320, 240)
STEP = 0.4
N_FRAMES = 17  # 6.4 m: the drive stays inside forward_scene_config's free zone


@pytest.fixture(scope="module")
def frames():
    cam = synthetic.default_camera(*SIZE)
    poses = synthetic.make_forward_trajectory(
        N_FRAMES, 0, synthetic.ForwardTrajectoryConfig(step=STEP))
    scene = synthetic.SyntheticScene.generate(0, synthetic.forward_scene_config())
    return synthetic.render_frames(scene, cam, poses, supersample=2)


@pytest.mark.slow
def test_forward_trajectory_shape(frames):
    """Steps of STEP metres, inter-frame rotations of a few degrees, all finite poses,
    and the path inside the forward scene's free zone."""
    T = np.stack([f.T_world_cam for f in frames])
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(steps, STEP, rtol=0.05)
    rot = [rotation_angle_deg(T[i, :3, :3].T @ T[i + 1, :3, :3]) for i in range(len(T) - 1)]
    assert 1.0 < max(rot) < 5.0
    free = synthetic.forward_scene_config().free_zone_radius
    assert np.all(np.linalg.norm(T[:, :2, 3], axis=1) < free)
    with pytest.raises(ValueError, match="step"):
        synthetic.make_forward_trajectory(5, 0, synthetic.ForwardTrajectoryConfig(step=0.0))


def _keyframe(frames, i):
    fe = make_frontend("depth", FrontEndConfig(working_size=SIZE))
    prims = fe.primify(frames[i].image, frames[i].camera, frames[i].depth)
    cfg = OdometryConfig()
    return Keyframe.build(frames[i].image, prims, frames[i].T_world_cam, cfg.keyframe_levels,
                          cfg.selection), cfg


@pytest.mark.slow
def test_feature_retry_recovers_a_pose_the_tracker_cannot_reach(frames):
    """Three frames (1.2 m) ahead: tracking from the keyframe's pose fails, the PnP
    pose on features lifted with the keyframe's depth is within 5 cm / 1 degree, and the
    tracker started there succeeds."""
    kf, cfg = _keyframe(frames, 0)
    target = frames[3]
    from_kf = track_frame(kf, target.image, kf.T_world_kf, (0.0, 0.0), cfg.tracker)
    assert not from_kf.ok
    retry = FeatureRetry(target.camera, FeatureRetryConfig())
    T0 = retry.guess(0, frames[0].image, kf.primitives, kf.T_world_kf, target.image)
    assert T0 is not None
    err = invert_pose(target.T_world_cam) @ T0
    assert np.linalg.norm(err[:3, 3]) < 0.05
    assert rotation_angle_deg(err[:3, :3]) < 1.0
    tr = track_frame(kf, target.image, T0, (0.0, 0.0), cfg.tracker)
    assert tr.ok
    err = invert_pose(target.T_world_cam) @ tr.T_world_frame
    assert np.linalg.norm(err[:3, 3]) < 0.02


@pytest.mark.slow
def test_feature_retry_rejects_an_unrelated_image(frames):
    """A blank frame has no features: no guess rather than a wrong one."""
    kf, _ = _keyframe(frames, 0)
    retry = FeatureRetry(frames[0].camera)
    blank = np.zeros_like(frames[3].image)
    assert retry.guess(0, frames[0].image, kf.primitives, kf.T_world_kf, blank) is None


@pytest.mark.slow
@pytest.mark.parametrize("frontend, max_ate_pct", [("classical", 1.5), ("depth", 1.0)])
def test_vo_holds_a_fast_forward_drive(frames, frontend, max_ate_pct):
    """Default VO config: at most one frame lost, one map segment, and the Sim(3) ATE
    of the tracked frames below ``max_ate_pct`` % of the path length."""
    cam = frames[0].camera
    vo = Odometry(cam, OdometryConfig(), make_frontend(frontend, FrontEndConfig(working_size=SIZE)))
    for f in frames:
        vo.track(f)
    res = vo.result()
    lost = np.array([s == "lost" for s in res.status])
    assert lost.sum() <= 1
    assert vo.report()["n_segments"] == 1
    gt = np.stack([f.T_world_cam for f in frames])
    stamps = np.arange(len(frames), dtype=float)
    ate = ate_sim3((stamps[~lost], res.poses[~lost]), (stamps[~lost], gt[~lost]))
    length = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    assert ate.rmse < max_ate_pct / 100.0 * length


def test_vo_synthetic_forward_sequence():
    """``spgeo eval vo_synthetic --forward STEP``'s sequence: steps of STEP metres,
    cut so the drive stays inside the hall (FORWARD_DRIVE_M)."""
    from spgeo.evaluation.vo.synthetic import (FORWARD_DRIVE_M, SyntheticVOConfig,
                                               synthetic_sequence)

    seq = synthetic_sequence(SyntheticVOConfig(n_frames=100, size=(40, 30), forward_step=0.8,
                                               supersample=1))
    assert len(seq) == 1 + int(FORWARD_DRIVE_M / 0.8)
    T = np.stack([f.T_world_cam for f in seq])
    np.testing.assert_allclose(np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1), 0.8,
                               rtol=0.05)
    with pytest.raises(ValueError, match="forward_step"):
        synthetic_sequence(SyntheticVOConfig(size=(40, 30), forward_step=-1.0))


def test_frames_before_keyframe_1_are_retracked_from_the_interpolated_pose():
    """A forward drive at 0.25 m per frame (seed 1): frames between keyframes 0 and
    1 that tracking against the unscaled keyframe 0 lost are re-tracked after the
    initialisation; where the constant-velocity guess fails (no velocity after a
    lost frame) the pose interpolated between keyframes 0 and 1 starts the tracker,
    so no frame stays lost."""
    from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence

    seq = synthetic_sequence(SyntheticVOConfig(seed=1, size=SIZE, forward_step=0.25))
    vo = Odometry(seq[0].camera, OdometryConfig(),
                  make_frontend("classical", FrontEndConfig(working_size=SIZE)))
    out = [vo.track(f) for f in seq]
    assert vo.initialised
    assert [r.status for r in out].count("init") > 0      # frames re-tracked after the init
    res = vo.result()
    assert not any(s == "lost" for s in res.status), res.status
    gt = np.stack([f.T_world_cam for f in seq])
    stamps = np.arange(len(seq), dtype=float)
    ate = ate_sim3((stamps, res.poses), (stamps, gt))
    length = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    assert ate.rmse < 0.01 * length
