"""Place recognition, Sim(3) verification and the LoopCloser driver of spgeo.loop on
synthetic rooms (revisit found and measured; look-alikes and unseen places rejected),
plus the 7-Scenes sample when present."""
from pathlib import Path

import numpy as np
import pytest

from spgeo.geometry import invert_pose
from spgeo.loop import (LoopCloser, LoopClosureConfig, PlaceRecognitionConfig,
                        VerificationConfig, extract_features, match_features, verify_sim3)
from spgeo.similarity import sim3, sim3_difference
from spgeo.synthetic import SyntheticScene
from spgeo.synthetic.poses import camera_rotation, default_camera

CAM = default_camera(320, 240)
DRIFT = 1.1   # the query's depth unit over the true one (emulated scale drift)
# single detections accepted: the verification itself is under test (the consistency
# of consecutive detections has its own test)
CONFIG = LoopClosureConfig(enabled=True, recognition=PlaceRecognitionConfig(min_keyframe_gap=5),
                           verification=VerificationConfig(consistent_detections=1))
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "7scenes_redkitchen_dev"


def pose(yaw_deg, position=(0.0, 0.0, 1.4)):
    T = np.eye(4)
    T[:3, :3] = camera_rotation(np.radians(yaw_deg), -0.1)
    T[:3, 3] = position
    return T


KF_POSES = [pose(15 * k) for k in range(12)]          # a sweep around the room
Q_POSE = pose(47, (0.05, -0.03, 1.42))                  # back near keyframe 3, later


@pytest.fixture(scope="module")
def scenes():
    return SyntheticScene.generate(0), SyntheticScene.generate(1)


@pytest.fixture(scope="module")
def keyframe_views(scenes):
    return [scenes[0].render(CAM, T) for T in KF_POSES]


@pytest.fixture(scope="module")
def query_view(scenes):
    return scenes[0].render(CAM, Q_POSE)


def filled_closer(views, config=CONFIG):
    closer = LoopCloser(CAM, config)
    for k, (T, v) in enumerate(zip(KF_POSES, views)):
        assert closer.add_keyframe(k, v.rgb, v.depth, T) is None
    return closer


def true_S_cand_query(T_world_cand, T_world_query, drift=DRIFT):
    return invert_pose(T_world_cand) @ T_world_query @ sim3(np.eye(3), np.zeros(3), 1 / drift)


def test_revisit_detected_and_verified(keyframe_views, query_view):
    closer = filled_closer(keyframe_views)
    loop = closer.add_keyframe(100, query_view.rgb, query_view.depth * DRIFT, Q_POSE)
    assert loop is not None and loop.candidate_id == 3 and closer.loops == [loop]
    rot, trans, dlog = sim3_difference(true_S_cand_query(KF_POSES[3], Q_POSE), loop.S_cand_query)
    assert rot < 1.0 and trans < 0.03 and dlog < np.log(1.02)
    assert loop.inlier_ratio > 0.9 and loop.neighbour_support >= 1


def test_recent_keyframes_are_not_candidates(keyframe_views, query_view):
    closer = filled_closer(keyframe_views)
    features = extract_features(query_view.rgb, CAM, query_view.depth, CONFIG.recognition.features)
    assert closer.detect(4, features) is None          # no keyframe outside the gap of 5
    assert all(c.kf_id <= 2 for c in closer.database.candidates(7, features))
    assert [c.kf_id for c in closer.database.candidates(8, features)][:1] == [3]


def test_poster_lookalike_rejected(keyframe_views, query_view):
    """A photograph of the place (same image, flat depth): descriptors match, 3-D does not."""
    closer = filled_closer(keyframe_views)
    flat = np.full_like(query_view.depth, 2.0)
    features = extract_features(query_view.rgb, CAM, flat, CONFIG.recognition.features)
    assert closer.detect(100, features) is None
    cand = closer.database.entries[3].features
    ver = verify_sim3(features, cand, match_features(cand, features, CONFIG.recognition.features))
    assert ver.n_matches >= 100 and not ver.accepted and ver.reason == "low_inlier_ratio"


def test_isolated_lookalike_rejected_by_neighbours(scenes, keyframe_views, query_view):
    """A keyframe that looks like the query among neighbours that do not (another room):
    verification alone accepts it, the neighbour check does not."""
    other = [scenes[1].render(CAM, T) for T in KF_POSES[:5]]
    views = other[:3] + [keyframe_views[3]] + other[3:]

    def run(support):
        cfg = LoopClosureConfig(recognition=CONFIG.recognition,
                                verification=VerificationConfig(min_neighbour_support=support,
                                                                 consistent_detections=1))
        closer = LoopCloser(CAM, cfg)
        for k, v in enumerate(views):
            closer.add_keyframe(k, v.rgb, v.depth, KF_POSES[k])
        return closer.add_keyframe(100, query_view.rgb, query_view.depth, Q_POSE)

    assert run(0) is not None and run(0).candidate_id == 3
    assert run(1) is None


def test_unseen_place_gives_no_candidate(scenes, keyframe_views):
    closer = filled_closer(keyframe_views)
    view = scenes[1].render(CAM, Q_POSE)
    features = extract_features(view.rgb, CAM, view.depth, CONFIG.recognition.features)
    assert closer.database.candidates(100, features) == []
    assert closer.detect(100, features) is None


def test_correction_moves_query_and_is_a_fixed_point(keyframe_views, query_view):
    """The query keyframe arrives with a drifted pose (and depth); the correction moves it
    towards the truth with the depth factor 1 / DRIFT; applied, a second solve moves little."""
    closer = filled_closer(keyframe_views)
    T_drifted = Q_POSE.copy()
    T_drifted[:3, 3] += [0.3, -0.2, 0.1]
    loop = closer.add_keyframe(100, query_view.rgb, query_view.depth * DRIFT, T_drifted)
    assert loop is not None
    corr = closer.correct()
    err_before = np.linalg.norm(T_drifted[:3, 3] - Q_POSE[:3, 3])
    err_after = np.linalg.norm(corr.T_world_kf[100][:3, 3] - Q_POSE[:3, 3])
    assert err_after < 0.25 * err_before
    assert corr.scales[100] == pytest.approx(1 / DRIFT, rel=0.02)
    assert corr.scales[0] == pytest.approx(1.0, abs=1e-6)
    for k in corr.kf_ids:   # a frame at a keyframe's old pose moves with it
        old = KF_POSES[k] if k < 100 else T_drifted
        assert np.allclose(corr.frame_pose(k, old), corr.T_world_kf[k], atol=1e-9)
    again = closer.correct()   # the applied map re-solved: the loop's leftover residual only
    assert np.allclose(list(again.scales.values()), 1.0, atol=0.01)
    for k in again.kf_ids:
        assert np.linalg.norm(again.T_world_kf[k][:3, 3] - corr.T_world_kf[k][:3, 3]) < 0.1 * err_before


def test_loop_accepted_after_consistent_detections(scenes, keyframe_views, query_view):
    """With consistent_detections=2 a single detection is held back; the next keyframe's
    detection near the same candidate accepts both (two edges, each with a positive
    definite information); a keyframe without a loop in between breaks the streak."""
    from dataclasses import replace

    cfg = replace(CONFIG, verification=VerificationConfig(consistent_detections=2))
    closer = filled_closer(keyframe_views, cfg)
    second = scenes[0].render(CAM, pose(52, (0.02, 0.0, 1.40)))
    assert closer.add_keyframe(100, query_view.rgb, query_view.depth * DRIFT, Q_POSE) is None
    loop = closer.add_keyframe(101, second.rgb, second.depth * DRIFT, pose(52, (0.02, 0.0, 1.40)))
    assert loop is not None and [lp.query_id for lp in closer.loops] == [100, 101]
    for lp in closer.loops:
        assert abs(lp.candidate_id - 3) <= 1
        assert np.linalg.eigvalsh(lp.information).min() > 0
    broken = filled_closer(keyframe_views, cfg)
    unseen = scenes[1].render(CAM, Q_POSE)
    assert broken.add_keyframe(100, query_view.rgb, query_view.depth * DRIFT, Q_POSE) is None
    assert broken.add_keyframe(101, unseen.rgb, unseen.depth, Q_POSE) is None
    assert broken.add_keyframe(102, second.rgb, second.depth * DRIFT, Q_POSE) is None
    assert broken.loops == []


def test_ids_must_increase(keyframe_views):
    closer = filled_closer(keyframe_views[:2])
    v = keyframe_views[0]
    with pytest.raises(ValueError):
        closer.add_keyframe(1, v.rgb, v.depth, KF_POSES[0])


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="shared 7-Scenes sample absent")
def test_seven_scenes_revisits():
    """Real frames (Kinect depth, ground-truth poses): revisits of keyframes 0..90 are
    found with the right Sim(3); frames of other parts of the kitchen give no loop."""
    from spgeo.datasets.sevenscenes import SevenScenesConfig, SevenScenesSequence

    frames = {int(f.meta["frame_number"]): f for f in SevenScenesSequence(
        DATA, SevenScenesConfig(frames=[0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 5, 45, 150, 200]))}
    closer = LoopCloser(frames[0].camera, LoopClosureConfig(enabled=True))
    for i, n in enumerate(range(0, 100, 10)):
        closer.add_keyframe(i, frames[n].image, frames[n].depth, frames[n].T_world_cam)
    for j, n in enumerate((0, 5, 45)):
        f = frames[n]
        loop = closer.detect(1000 + j, extract_features(f.image, f.camera, f.depth * DRIFT,
                                                        closer.config.recognition.features))
        assert loop is not None, n
        T_c = frames[10 * loop.candidate_id].T_world_cam
        rot, trans, dlog = sim3_difference(true_S_cand_query(T_c, f.T_world_cam), loop.S_cand_query)
        assert rot < 1.0 and trans * DRIFT < 0.03 and dlog < np.log(1.02), n
    for j, n in enumerate((150, 200)):
        f = frames[n]
        assert closer.detect(2000 + j, extract_features(
            f.image, f.camera, f.depth, closer.config.recognition.features)) is None, n


def test_database_keeps_sift_descriptors_in_a_quarter_of_the_memory(keyframe_views, query_view):
    """OpenCV's SIFT descriptors are whole numbers in [0, 255]: the database keeps them
    as uint8 (4x less memory per keyframe over a long recording) and matches exactly
    as with the float32 originals."""
    from spgeo.loop import KeyframeDatabase

    db = KeyframeDatabase(CONFIG.recognition)
    feats = [extract_features(v.rgb, CAM, v.depth, CONFIG.recognition.features)
             for v in keyframe_views[:4]]
    for k, f in enumerate(feats):
        db.add(k, f, KF_POSES[k])
        assert db.entries[k].features.descriptors.dtype == np.uint8
        assert db.entries[k].features.descriptors.nbytes * 4 == f.descriptors.nbytes
    q = extract_features(query_view.rgb, CAM, query_view.depth, CONFIG.recognition.features)
    for k, f in enumerate(feats):
        assert np.array_equal(db.matches(k, q), match_features(f, q, CONFIG.recognition.features))
