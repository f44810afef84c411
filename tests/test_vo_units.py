"""Unit tests of the VO's parts without an Odometry run: the map
:class:`~spgeo.vo.initialisation.Initialiser` (its decisions on tracked
frames) and the :class:`~spgeo.vo.smoother.WindowMapper` (keyframes with known
poses).  Synthetic 160x120 frames, depth-derived ("depth") front-end: metric
primitives (keyframe 0 is tracked against at ground-truth scale; the
initialisation's SfM, monocular, solves in its own units: its poses compare with
ground truth after the scale of keyframe 0's median depth)."""
import dataclasses

import gtsam
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.geometry import invert_pose, rotation_angle_deg
from spgeo.graph.keys import pose_key, scale_key
from spgeo.vo import InitConfig, OdometryConfig, MappingConfig
from spgeo.vo.initialisation import FAILED, START, WAIT, Initialiser
from spgeo.vo.map import MapKeyframe, SupportCandidate
from spgeo.vo.smoother import WindowMapper
from spgeo.vo.tracking import Keyframe, track_frame

CAM = synthetic.default_camera(160, 120)
STEP = 3            # trajectory poses per frame
N_FRAMES = 12
#: quick initialisation: keyframe 1 at >= 4 % of keyframe 0's median depth
INIT = OdometryConfig(init=InitConfig(min_parallax=0.04, min_gap=2, max_gap=10))


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    poses = synthetic.make_trajectory(STEP * N_FRAMES, 0)[::STEP]
    return synthetic.render_frames(scene, CAM, poses, supersample=1)


@pytest.fixture(scope="module")
def frontend():
    return make_frontend("depth", FrontEndConfig(working_size=(160, 120)))


def _map_keyframe(frames, frontend, i, k, cfg=INIT, T=None):
    f = frames[i]
    prims = frontend.primify(f.image, CAM, f.depth)
    T = f.T_world_cam if T is None else T
    return MapKeyframe(k, i, np.asarray(f.image),
                       Keyframe.build(f.image, prims, T, cfg.keyframe_levels, cfg.selection))


def _pose_error(T, T_gt):
    """(translation m, rotation deg) between two camera-to-world poses."""
    D = invert_pose(T_gt) @ T
    return float(np.linalg.norm(T[:3, 3] - T_gt[:3, 3])), rotation_angle_deg(D[:3, :3])


def _in_metres(T, dec, kf0):
    """``T`` (camera-to-world, in the units of the initialisation ``dec``'s solved
    keyframe 0) with its translation from keyframe 0 scaled to metres (keyframe 0's
    metric median depth over the solved one)."""
    s = kf0.keyframe.median_depth / dec.keyframe0.median_depth
    T = np.array(T, dtype=float)
    origin = kf0.keyframe.T_world_kf[:3, 3]
    T[:3, 3] = origin + s * (T[:3, 3] - origin)
    return T


def _step(init, frames, kf0, i, image=None, tr=None):
    """One Initialiser step for frame ``i`` tracked against ``kf0`` from its
    ground-truth pose (or the given TrackResult)."""
    img = frames[i].image if image is None else image
    if tr is None:
        tr = track_frame(kf0.keyframe, img, frames[i].T_world_cam, (0.0, 0.0), INIT.tracker)
    timings = {}
    return init.step(img, i, kf0, tr, np.zeros(2), 0, timings), tr, timings


# ------------------------------------------------------------------ Initialiser
def test_initialiser_waits_then_starts_a_map_and_retracks_the_buffer(frames, frontend):
    """Frames below init.min_parallax wait (buffered, a wait note, no SfM);
    the first frame past it starts the map: keyframe 1's pose and the
    re-tracked buffered frames are near ground truth, the buffer is emptied."""
    kf0 = _map_keyframe(frames, frontend, 0, 0)
    init = Initialiser(INIT, CAM)
    waited = []
    for i in range(1, N_FRAMES):
        dec, tr, timings = _step(init, frames, kf0, i)
        if dec.action != WAIT:
            break
        assert tr.ok and "init" not in timings and not init.reports
        assert "parallax" in init.wait_note and init.failure is None
        waited.append(i)
        assert [j for j, _ in init.buffer] == waited
        np.testing.assert_allclose(dec.T_kf0_frame,
                                   invert_pose(kf0.keyframe.T_world_kf) @ tr.T_world_frame)
    assert dec.action == START and len(waited) >= 2, (dec.action, waited)
    parallax = np.linalg.norm(dec.T_kf0_frame[:3, 3]) / kf0.keyframe.median_depth
    assert parallax >= INIT.init.min_parallax
    assert init.buffer == [] and "init" in timings
    assert len(init.reports) == 1 and init.reports[0]["accepted"]
    # keyframe 0 keeps its pose and pixels, with the SfM's shapes
    np.testing.assert_array_equal(dec.keyframe0.T_world_kf, kf0.keyframe.T_world_kf)
    np.testing.assert_array_equal(dec.keyframe0.primitives.pixels, kf0.keyframe.primitives.pixels)
    t_err, r_err = _pose_error(_in_metres(dec.T_world_kf1, dec, kf0), frames[i].T_world_cam)
    assert t_err < 0.01 and r_err < 0.5, (t_err, r_err)
    assert [r.frame for r in dec.retracked] == waited and all(r.ok for r in dec.retracked)
    for r in dec.retracked:
        t_err, r_err = _pose_error(_in_metres(r.T_world_frame, dec, kf0),
                                   frames[r.frame].T_world_cam)
        assert t_err < 0.01 and r_err < 0.5, (r.frame, t_err, r_err)
        np.testing.assert_allclose(dec.keyframe0.T_world_kf @ r.T_kf_frame, r.T_world_frame,
                                   atol=1e-12)
    np.testing.assert_array_equal(dec.T_world_last, dec.retracked[-1].T_world_frame)


def test_initialiser_rejects_a_pair_without_parallax(frames, frontend):
    """At init.max_gap a frame without parallax (keyframe 0's own image) is
    solved, rejected (no map) with a note; the next retry waits half a gap."""
    cfg = dataclasses.replace(INIT, init=dataclasses.replace(INIT.init, max_gap=4))
    kf0 = _map_keyframe(frames, frontend, 0, 0, cfg)
    init = Initialiser(cfg, CAM)
    still = frames[0].image.copy()
    tr = track_frame(kf0.keyframe, still, kf0.keyframe.T_world_kf, (0.0, 0.0), cfg.tracker)
    dec = init.step(still, 4, kf0, tr, np.zeros(2), 0, {})
    assert dec.action == WAIT
    assert "no map initialised from keyframes 0-1" in init.failure
    assert len(init.reports) == 1 and not init.reports[0]["accepted"]
    assert init.reports[0]["rejected"] and init.wait_until == 4 + 2
    assert [j for j, _ in init.buffer] == [4]
    # gap 5 < wait_until: waits without an SfM (the tracked parallax is still 0)
    dec = init.step(still, 5, kf0, tr, np.zeros(2), 0, {})
    assert dec.action == WAIT and len(init.reports) == 1
    init.reset()
    assert init.buffer == [] and init.failure is None and init.wait_until == 0
    assert len(init.reports) == 1      # the reports of every segment stay


def test_initialiser_spaces_out_retries_after_a_failed_sfm(frames, frontend):
    """A frame lost against keyframe 0 before init.max_gap ends the wait; its
    SfM must be ``ok`` with parallax, else the decision is FAILED and the next
    lost frame waits until the gap has grown by half."""
    kf0 = _map_keyframe(frames, frontend, 0, 0)
    init = Initialiser(INIT, CAM)
    still = frames[0].image.copy()
    tr = track_frame(kf0.keyframe, still, kf0.keyframe.T_world_kf, (0.0, 0.0), INIT.tracker)
    lost = dataclasses.replace(tr, status="lost", reason="high_cost")
    dec = init.step(still, 4, kf0, lost, np.zeros(2), 0, {})
    assert dec.action == FAILED
    assert init.failure.startswith("frame 4: SfM of keyframes 0-1")
    assert init.retry_gap == 4 + 2 and [j for j, _ in init.buffer] == [4]
    dec = init.step(still, 5, kf0, lost, np.zeros(2), 0, {})
    assert dec.action == WAIT and "lost against keyframe 0" in init.wait_note
    assert len(init.reports) == 1
    dec = init.step(still, 6, kf0, lost, np.zeros(2), 0, {})      # gap reached: retried
    assert dec.action == FAILED and len(init.reports) == 2 and init.retry_gap == 6 + 3


# ------------------------------------------------------------------ WindowMapper
@pytest.fixture(scope="module")
def mapped(frames, frontend):
    """Keyframes 0, 3, 6, 9 of the frames (poses: ground truth, keyframe 3's
    moved 2 cm and 0.5 deg), mapped one by one in a window of 3."""
    cfg = dataclasses.replace(INIT, window=3, mapping=MappingConfig(iterations=5))
    mapper = WindowMapper(cfg)
    kfs = []
    moved = frames[3].T_world_cam.copy()
    moved[:3, 3] += [0.02, 0.0, 0.0]
    moved[:3, :3] = moved[:3, :3] @ gtsam.Rot3.Expmap(np.radians([0.0, 0.5, 0.0])).matrix()
    states = []
    mapper.support_kept = {}     # what the caller's map keeps of each update
    for k, i in enumerate((0, 3, 6, 9)):
        kfs.append(_map_keyframe(frames, frontend, i, k, cfg, moved if i == 3 else None))
        if k == 0:
            continue
        prev = kfs[-2]
        cands = [SupportCandidate(j, np.asarray(frames[j].image),
                                  invert_pose(prev.keyframe.T_world_kf) @ frames[j].T_world_cam,
                                  np.zeros(2)) for j in range(prev.frame + 1, i)]
        assert mapper.map_keyframe(kfs, cands, 0) is False
        mapper.support_kept.update(mapper.refreshed_support)
        est = mapper.estimate()
        states.append([est.exists(pose_key(j)) for j in range(len(kfs))])
    return mapper, kfs, states, cfg


def test_window_mapper_keeps_poses_near_ground_truth(frames, mapped):
    """Every mapped keyframe's and supporting frame's smoothed pose within
    2 cm / 0.5 deg of ground truth (the path is about 0.3 m); the moved
    keyframe is pulled back towards it (from 2 cm / 0.5 deg); the first
    keyframe is held by the gauge prior."""
    mapper, kfs, _, _ = mapped
    t_err, r_err = _pose_error(kfs[0].keyframe.T_world_kf, frames[0].T_world_cam)
    assert t_err < 1e-4 and r_err < 1e-3
    for kf in kfs[1:]:
        t_err, r_err = _pose_error(kf.keyframe.T_world_kf, frames[kf.frame].T_world_cam)
        assert t_err < 0.02 and r_err < 0.5, (kf.frame, t_err, r_err)
    t_err, r_err = _pose_error(kfs[1].keyframe.T_world_kf, frames[3].T_world_cam)
    assert t_err < 0.6 * 0.02 and r_err < 0.5 * 0.5, (t_err, r_err)
    rep = mapper.reports
    assert [r["keyframe"] for r in rep] == [1, 2, 3]
    assert all(r["factors_keyframe_pairs"] > 0 and 0 < len(r["support_frames"]) <= 2
               for r in rep)
    assert sorted(mapper.support_kept) == sorted(f for r in rep for f in r["support_frames"])
    for f, T in mapper.support_kept.items():
        t_err, r_err = _pose_error(T, frames[f].T_world_cam)
        assert t_err < 0.02 and r_err < 0.5, (f, t_err, r_err)


def test_window_mapper_marginalises_the_oldest_and_resets(mapped):
    """The window keeps the last ``window`` keyframes: keyframe 0 leaves when
    keyframe 3 arrives (its keys are gone from the estimate); reset empties it."""
    mapper, kfs, states, cfg = mapped
    assert states == [[True, True], [True, True, True], [False, True, True, True]]
    est = mapper.estimate()
    assert not est.exists(scale_key(0, keyframe=0)) and est.exists(scale_key(0, keyframe=3))
    mapper.reset()
    assert mapper.estimate().size() == 0
