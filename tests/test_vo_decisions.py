"""The VO's decisions, each in one object (issue 50): the keyframe policy
(:class:`spgeo.vo.keyframe_policy.KeyframePolicy`), the one tracking decision and its
re-tracking loop (:class:`spgeo.vo.frame_tracker.FrameTracker`), and what the map
hands back instead of moving the motion model (:meth:`KeyframeMap.apply_similarity`,
:meth:`MotionModel.follow`).  The structural rules (no tracking outside the tracker,
the thresholds read in one module) are in tests/test_layering.py."""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.geometry import invert_pose, rotation_angle_deg
from spgeo.similarity import moved_frame, sim3
from spgeo.vo.config import KeyframeDecisionConfig, OdometryConfig
from spgeo.vo.frame_tracker import FrameTracker
from spgeo.vo.keyframe_policy import AFTER_UPDATE, KEYFRAME, NO_KEYFRAME, KeyframePolicy
from spgeo.vo.map import KeyframeMap, MapKeyframe, SupportCandidate
from spgeo.vo.motion import MotionChange, MotionModel

CAM = PinholeCamera(100.0, 100.0, 40.0, 30.0, 80, 60)


class FakePort:
    """An :class:`~spgeo.vo.keyframe_policy.UpdateSchedule`: pending or not, its
    schedule lets a keyframe wait for the update or not; deferrals counted."""

    def __init__(self, pending: bool, available: bool) -> None:
        self.pending, self.available, self.deferred = pending, available, 0

    def update_available(self) -> bool:
        return self.available

    def defer_keyframe(self) -> None:
        self.deferred += 1


def _pose(t=(0.0, 0.0, 0.0), angle_deg: float = 0.0) -> np.ndarray:
    a = np.radians(angle_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = t
    return T


def _kf(median_depth: float = 2.0):
    return SimpleNamespace(keyframe=SimpleNamespace(median_depth=median_depth))


def _track(valid: float = 0.9, cost: float = 0.05):
    return SimpleNamespace(valid_fraction=valid, relative_cost=cost)


def test_the_thresholds_of_a_keyframe():
    cfg = KeyframeDecisionConfig()
    policy = KeyframePolicy(cfg, FakePort(False, True))
    kf = _kf(2.0)
    assert not policy.crosses(_track(), _pose(), kf)
    # translation over the keyframe's median depth, just past and just under 0.2
    assert policy.crosses(_track(), _pose((0.41, 0, 0)), kf)
    assert not policy.crosses(_track(), _pose((0.39, 0, 0)), kf)
    assert policy.crosses(_track(valid=0.59), _pose(), kf)
    assert policy.crosses(_track(cost=0.21), _pose(), kf)
    assert policy.crosses(_track(), _pose(angle_deg=15.5), kf)
    assert not policy.crosses(_track(), _pose(angle_deg=14.5), kf)
    # the view test alone (also the end of the wait for keyframe 1)
    assert policy.leaves_view(_track(valid=0.59), _pose())
    assert policy.leaves_view(_track(), _pose(angle_deg=15.5))
    assert not policy.leaves_view(_track(cost=0.9), _pose((5.0, 0, 0)))
    assert rotation_angle_deg(_pose(angle_deg=15.5)[:3, :3]) == pytest.approx(15.5)


@pytest.mark.parametrize("pending, available, older, crossed, expected, deferred", [
    (False, True, False, False, NO_KEYFRAME, 0),   # nothing crossed
    (False, True, False, True, KEYFRAME, 0),       # crossed, no update in flight
    (True, True, False, True, AFTER_UPDATE, 0),    # crossed, the update may move the latest
    (True, False, False, True, NO_KEYFRAME, 1),    # "ready" schedule, update not ready: deferred
    (False, True, True, False, KEYFRAME, 0),       # relocalised against an older keyframe
    (True, True, True, False, KEYFRAME, 0),        # ... made at once (it re-anchors the map)
    (True, False, True, False, NO_KEYFRAME, 1),    # ... or deferred like any other
    (True, False, False, False, NO_KEYFRAME, 0),   # not wanted: no deferral counted
])
def test_the_decision_and_its_deferral(pending, available, older, crossed, expected, deferred):
    port = FakePort(pending, available)
    policy = KeyframePolicy(KeyframeDecisionConfig(), port)
    latest = _kf(2.0)
    ref = _kf(2.0) if older else latest
    T = _pose((1.0, 0, 0)) if crossed else _pose()
    assert policy.decide(_track(), T, ref, latest) == expected
    assert port.deferred == deferred


def test_motion_follows_the_similarities_in_order_then_the_keyframe():
    motion = MotionModel()
    motion.set_poses(_pose((1.0, 0, 0), 5.0), _pose((0.5, 0, 0)))
    W1 = sim3(_pose(angle_deg=3.0)[:3, :3], np.array([0.1, 0.2, 0.3]), 1.5)
    W2 = sim3(np.eye(3), np.array([-0.2, 0.0, 0.1]), 0.8)
    last, prev = motion.last_good.copy(), motion.prev_good.copy()
    motion.follow(MotionChange([W1, W2]))
    for got, was in ((motion.last_good, last), (motion.prev_good, prev)):
        want = moved_frame(W2, moved_frame(W1, was))
        assert np.allclose(got[:3, 3], want[:3, 3], atol=1e-12)
        assert np.allclose(got[:3, :3] @ got[:3, :3].T, np.eye(3), atol=1e-12)   # rigid again
    # no frame tracked since the keyframe: the motion restarts at its smoothed pose,
    # the previous pose moved by the same world correction
    motion.set_poses(last, prev)
    T_new = _pose((1.1, 0.0, 0.0), 5.0)
    motion.brightness = np.array([0.1, 0.2])
    motion.follow(MotionChange(keyframe_pose=T_new))
    assert np.array_equal(motion.last_good, T_new)
    assert np.allclose(motion.prev_good, T_new @ invert_pose(last) @ prev)
    assert np.array_equal(motion.brightness, np.zeros(2))


def _map_with_candidates():
    kmap = KeyframeMap(window=3, levels=1, n_support=2)
    for k in range(2):
        kmap.add(MapKeyframe(k, 10 * k, None, SimpleNamespace(T_world_kf=np.eye(4),
                                                              median_depth=1.0)),
                 new_segment=(k == 0))
    kmap.add_candidate(SupportCandidate(11, None, _pose((0.2, 0, 0)), np.zeros(2)))
    return kmap


def test_the_map_hands_back_the_newest_keyframes_similarity():
    W = sim3(np.eye(3), np.array([1.0, 0, 0]), 2.0)
    kmap = _map_with_candidates()
    # the newest keyframe (1) moved: its W comes back and the candidates are scaled
    assert np.array_equal(kmap.apply_similarity({1: W}, 2.0), W)
    assert kmap.candidates[0].T_kf_frame[0, 3] == pytest.approx(0.4)
    # ... unless what follows the newest keyframe is the caller's
    kmap = _map_with_candidates()
    assert kmap.apply_similarity({1: W}, 2.0, follow_newest=False) is None
    assert kmap.candidates[0].T_kf_frame[0, 3] == pytest.approx(0.2)
    # an older keyframe moved: nothing follows the newest
    kmap = _map_with_candidates()
    assert kmap.apply_similarity({0: W}, 2.0) is None
    assert kmap.candidates[0].T_kf_frame[0, 3] == pytest.approx(0.2)


class ScriptedTracker(FrameTracker):
    """The one decision's loop over guesses, with the photometric tracker replaced by
    a script: a guess "succeeds" when it is within ``basin`` of ``truth``."""

    def __init__(self, truth: dict, basin: float = 0.05) -> None:
        super().__init__(CAM, dataclasses.replace(
            OdometryConfig(), feature_retry=dataclasses.replace(
                OdometryConfig().feature_retry, enabled=False)))
        self.truth, self.basin, self.calls = truth, basin, []

    def track(self, kf, image, guesses, brightness, features=True, landmarks=None):
        self.calls.append((kf, image))
        T_true = self.truth[(id(kf), image)]
        tries = [g() for g in guesses]
        for T0 in tries:
            if T0 is not None and np.linalg.norm(T0[:3, 3] - T_true[:3, 3]) < self.basin:
                return SimpleNamespace(ok=True, T_world_frame=T_true.copy(),
                                       brightness=np.array([0.01, 0.0]))
        return SimpleNamespace(ok=False, T_world_frame=tries[0], brightness=np.zeros(2))


def test_retrack_follows_the_motion_model_and_keeps_the_last_good_pose():
    kf = SimpleNamespace(keyframe=SimpleNamespace(T_world_kf=np.eye(4)), index=0)
    # constant velocity 0.1 per frame; frame 3 jumps out of every basin
    truth = {(id(kf), i): _pose((0.1 * i, 0, 0)) for i in (1, 2, 4)}
    truth[(id(kf), 3)] = _pose((5.0, 0, 0))
    tracker = ScriptedTracker(truth)
    motion = MotionModel()
    motion.reset(np.eye(4))
    motion.set_poses(_pose((0.0, 0, 0)), _pose((-0.1, 0, 0)))
    out = tracker.retrack(kf, [(i, i, None) for i in (1, 2, 3, 4)], motion,
                          extra_guess=lambda i: _pose((0.1 * i, 0, 0)))
    assert [r.ok for r in out] == [True, True, False, True]
    assert np.allclose(out[2].T_world_frame, _pose((0.2, 0, 0)))   # the last good pose
    # frame 4 came back through the extra guess (the velocity saw frame 2 last)
    assert np.allclose(out[3].T_kf_frame, _pose((0.4, 0, 0)))
    assert np.allclose(motion.last_good, _pose((0.4, 0, 0)))


def test_relocalisation_goes_through_the_one_decision():
    older = [SimpleNamespace(keyframe=SimpleNamespace(T_world_kf=np.eye(4)), index=k)
             for k in (3, 2, 1)]
    image = "frame"
    truth = {(id(older[0]), image): _pose((2.0, 0, 0)),     # out of reach
             (id(older[1]), image): _pose((0.01, 0, 0)),    # the first that tracks
             (id(older[2]), image): _pose((0.0, 0, 0))}
    tracker = ScriptedTracker(truth)
    motion = MotionModel()
    motion.reset(np.eye(4))
    tr, kf = tracker.relocalise(older, image, motion)
    assert tr.ok and kf is older[1]
    assert [c[0] for c in tracker.calls] == older[:2]   # newest first, stops at the first
    tracker.truth = {k: _pose((9.0, 0, 0)) for k in truth}
    assert tracker.relocalise(older, image, motion) == (None, None)


def _result(T, reason):
    from spgeo.vo.tracking import TrackResult

    return TrackResult(T, np.zeros(2), 1.0, 1.0, 0.5, 0.9, [3], [0],
                       "lost" if reason else "ok", reason, {}, [])


def test_a_pose_refused_only_for_its_cost_is_judged_by_the_pnp_poses():
    """Issue 51: a ``high_cost`` result is ``ok`` at its own pose when a PnP pose's
    matches agree with it, else at the PnP pose of most inliers; a result lost for
    another reason stays lost; without PnP poses nothing changes."""
    from spgeo.vo.feature_retry import pnp_pose

    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-1, 1, 60), rng.uniform(-1, 1, 60), rng.uniform(2, 5, 60)])
    T_true = _pose((0.1, 0.0, 0.0))
    uv, _ = CAM.project(X - T_true[:3, 3])
    tracker = FrameTracker(CAM, OdometryConfig())
    cfg = OdometryConfig().feature_retry
    strong = pnp_pose(X, uv, CAM, cfg)
    weak = pnp_pose(X[:30], uv[:30], CAM, cfg)
    assert strong.inliers == 60 and weak.inliers == 30
    near = tracker._checked(_result(_pose((0.1, 0.0, 1e-5)), "high_cost"), [weak, strong])
    assert near.ok and near.feature_checked and not near.feature_pose
    assert np.allclose(near.T_world_frame, _pose((0.1, 0.0, 1e-5)))
    far = tracker._checked(_result(_pose((0.5, 0.0, 0.0)), "high_cost"), [weak, strong])
    assert far.ok and far.feature_pose and far.pnp_inliers == 60
    assert np.allclose(far.T_world_frame, T_true, atol=1e-6)
    other = tracker._checked(_result(_pose((0.5, 0.0, 0.0)), "low_overlap"), [strong])
    assert not other.ok and other.pnp_inliers == 60
    alone = _result(_pose((0.5, 0.0, 0.0)), "high_cost")
    assert tracker._checked(alone, []) is alone


def test_the_read_side_holds_no_reference_back_to_the_odometry():
    """The readout is given the odometry's parts (and a partial of them that applies a
    pending update), not the odometry: dropping an odometry frees it at once, without
    the cycle collector (its keyframe store and mapping worker go with it)."""
    import gc
    import weakref

    from spgeo.frontend import make_frontend
    from spgeo.vo import MappingConfig, Odometry

    vo = Odometry(CAM, OdometryConfig(mapping=MappingConfig(mode="inline")),
                  make_frontend("classical"))
    assert vo.readout is not None and repr(vo).startswith("Odometry(80x60, 0 frames")
    ref = weakref.ref(vo)
    enabled = gc.isenabled()
    gc.disable()
    try:
        del vo
        assert ref() is None
    finally:
        if enabled:
            gc.enable()
