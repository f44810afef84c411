"""Monocular VO (spgeo.vo) on a synthetic hand-held sequence, 160x120,
depth-derived ("depth", oracle) front-end."""
import json
import logging

import gtsam
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_sim3, read_status, read_tum
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.graph.keys import pose_key, scale_key
from spgeo.vo import InitConfig, KeyframeDecisionConfig, Odometry, OdometryConfig, MappingConfig

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
    """Default config but keyframes every 0.1 median depths of translation (the
    slow sequence crosses the default 0.2 once), with frame BLANK replaced by a
    blank image."""
    vo = Odometry(CAM, OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=0.1)),
                  frontend())
    results = []
    for i, f in enumerate(frames):
        if i == BLANK:
            f = Frame(np.zeros_like(f.image), CAM, f.timestamp, depth=f.depth, name="blank")
        results.append(vo.track(f))
    return vo, results


@pytest.fixture(scope="module")
def run_frequent_kf(frames):
    """As ``run`` with keyframes every 0.1 median depths of translation (3
    keyframes on this sequence, so two mapping updates)."""
    vo = Odometry(CAM, OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=0.1),
                                      mapping=MappingConfig(mode="inline")), frontend())
    for i, f in enumerate(frames):
        if i == BLANK:
            f = Frame(np.zeros_like(f.image), CAM, f.timestamp, depth=f.depth, name="blank")
        vo.track(f)
    return vo


@pytest.mark.slow
def test_end_to_end_accuracy(frames, run):
    """With sensor depth the map starts at frame 0 (no SfM, no frame waiting for
    keyframe 1: each is tracked); keyframes mapped by the smoother; Sim(3) ATE of
    the tracked frames < 3% of the trajectory length."""
    vo, results = run
    res = vo.result()
    assert len(res.timestamps) == N_FRAMES
    assert res.is_keyframe.sum() >= 2
    assert vo.report()["mapping"] and not any(m.get("failed") for m in vo.report()["mapping"])
    assert vo.report()["sfm"] == [] and "init" not in res.statuses
    assert res.statuses[0] == "keyframe" and res.statuses[1] == "ok"
    good = np.array([s != "lost" for s in res.statuses])
    gt = np.array([f.T_world_cam for f in frames])
    ate = ate_sim3((res.timestamps[good], res.poses[good]), (res.timestamps, gt))
    log.info("VO ATE %.4f m = %.2f%% of %.2f m, %d keyframes, %.1f FPS", ate.rmse,
             ate.rmse_percent_of_length, ate.trajectory_length, res.is_keyframe.sum(),
             N_FRAMES / sum(r.timings["total"] for r in results))
    assert ate.rmse_percent_of_length < 3.0
    # keyframe 0 -> 1 (refined by the smoother):
    # rotation and translation direction (scale-free) against the ground truth
    kf_idx = np.flatnonzero(res.is_keyframe)
    T_est = np.linalg.inv(res.poses[kf_idx[0]]) @ res.poses[kf_idx[1]]
    T_gt = np.linalg.inv(gt[kf_idx[0]]) @ gt[kf_idx[1]]
    dR = T_est[:3, :3].T @ T_gt[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 1.0
    cos_t = T_est[:3, 3] @ T_gt[:3, 3] / np.linalg.norm(T_est[:3, 3]) / np.linalg.norm(T_gt[:3, 3])
    assert np.degrees(np.arccos(np.clip(cos_t, -1, 1))) < 5.0
    if kf_idx.size >= 3:    # a Sim(3) alignment needs three positions
        kf_ate = ate_sim3((res.keyframe_timestamps, res.keyframe_poses), (res.timestamps, gt),
                          label="keyframe-only")
        assert kf_ate.rmse_percent_of_length < 3.0


@pytest.mark.slow
def test_blank_frame_is_lost_and_tracking_continues(run):
    vo, results = run
    assert results[BLANK].status == "lost"
    # the trajectory keeps the previous frame's pose (online, the last good pose: with live
    # mapping it moves with a window update applied in between)
    poses = vo.result().poses
    np.testing.assert_allclose(poses[BLANK], poses[BLANK - 1])
    after = [r.status for r in results[BLANK + 1:]]
    assert after[0] in ("relocalised", "keyframe")
    assert sum(s == "lost" for s in after) <= 2
    assert after[-1] != "lost"


@pytest.mark.slow
def test_save_writes_parseable_files(run, tmp_path):
    vo, _ = run
    paths = vo.save(tmp_path)
    traj = read_tum(paths["trajectory"])
    kfs = read_tum(paths["keyframes"])
    res = vo.result()
    posed = np.array([s != "lost" for s in res.statuses])    # lost frames: no line (issue 53)
    assert len(traj.timestamps) == int(posed.sum()) < N_FRAMES
    assert len(kfs.timestamps) == int(res.is_keyframe.sum())
    np.testing.assert_allclose(traj.poses[-1], res.poses[posed][-1], atol=1e-6)
    _, status = read_status(paths["status"])
    assert status == res.statuses
    rep = json.loads(paths["report"].read_text())
    assert rep["n_frames"] == N_FRAMES and rep["status_counts"]["lost"] >= 1


@pytest.mark.slow
def test_fixed_lag_marginalises_old_keyframes(frames):
    """Default 5-keyframe window; frequent keyframes (relative-cost threshold
    0.08, 3 LM iterations per update, for test time): once more than 5 keyframes exist, the oldest keyframes' keys
    have left the smoother (marginalised) and exactly the last 5 remain."""
    cfg = OdometryConfig(keyframe=KeyframeDecisionConfig(max_relative_cost=0.08),
                         # inline: the smoother is reached
                         mapping=MappingConfig(iterations=3, mode="inline"))
    vo = Odometry(CAM, cfg, frontend())
    for f in frames:
        vo.track(f)
    n_kf = len(vo.keyframes)
    assert n_kf > cfg.window
    est = vo.smoother_estimate()
    in_window = [k for k in range(n_kf) if est.exists(pose_key(k))]
    assert in_window == list(range(n_kf - cfg.window, n_kf))
    assert not est.exists(scale_key(0, keyframe=0))
    assert est.exists(scale_key(0, keyframe=n_kf - 1))
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
    with Odometry(CAM, OdometryConfig()) as default:    # spgeo vo's classical front-end
        assert default.frontend.uses_depth is False
        assert tuple(default.frontend.config.working_size) == default.camera.size
    with pytest.raises(ValueError):
        OdometryConfig(window=1)
    for bad in ({"mapping": MappingConfig(pixel_fraction=0.0)}, {"init": InitConfig(min_gap=0)},
                {"init": InitConfig(min_gap=31)}, {"init": InitConfig(extra_views=-1)},
                {"render_prior_weight": 0.0}):
        with pytest.raises(ValueError):
            OdometryConfig(**bad)


# ---------------------------------------------------------------- issue-4 system features
@pytest.mark.slow
def test_supporting_frames_are_optimised_in_the_window(run_frequent_kf):
    """Each mapping update links the previous keyframe to up to ``n_support``
    supporting non-keyframes whose poses are smoother variables; result() reports them at
    their smoothed poses."""
    from spgeo.graph.keys import support_pose_key

    vo = run_frequent_kf
    rep = vo.report()
    sup = [m["support_frames"] for m in rep["mapping"]]
    n = vo.config.n_support
    assert n >= 2 and all(len(s) <= n for s in sup) and sum(len(s) for s in sup) >= 2 * n
    kf_frames = {i for i, r in enumerate(vo.frames) if r.keyframe_index is not None}
    flat = [f for s in sup for f in s]
    assert not kf_frames.intersection(flat)
    est = vo.smoother_estimate()
    latest = [f for f in sup[-1]]
    assert latest and all(est.exists(support_pose_key(f)) for f in latest)
    res = vo.result()
    f = latest[0]
    np.testing.assert_allclose(res.poses[f], est.atPose3(support_pose_key(f)).matrix(), atol=1e-9)


@pytest.mark.slow
def test_reinitialisation_after_a_long_loss(frames):
    """Frames of another room after the first 25: tracking is lost, then (after
    max_lost_frames) the map re-initialises on a textured frame as a new
    segment and tracks the new room; no crash, every frame has a pose, the
    status file marks the segment."""
    other = synthetic.render_frames(synthetic.SyntheticScene.generate(7), CAM,
                                     synthetic.make_trajectory(25, 7), supersample=2)
    seq = list(frames[:25]) + [Frame(np.zeros_like(frames[0].image), CAM, 0.0,
                                     depth=frames[0].depth)] * 2 + list(other)
    vo = Odometry(CAM, OdometryConfig(max_lost_frames=3), frontend())
    out = [vo.track(Frame(f.image, CAM, i / 30.0, depth=f.depth)) for i, f in enumerate(seq)]
    st = [r.status for r in out]
    assert st.count("reinit") == 1
    k = st.index("reinit")
    # blank frames 25, 26 are lost; frame 27 (the other room) is the 3rd lost
    # frame and, being textured, restarts the map
    assert st[25] == st[26] == "lost" and k == 27
    assert out[-1].segment == 1 and out[0].segment == 0
    after = st[k + 1:]
    assert after.count("lost") <= 2 and after[-1] != "lost"
    res = vo.result()
    assert res.poses.shape == (len(seq), 4, 4) and np.all(np.isfinite(res.poses))
    # the new segment is consistent with the other room's motion (own Sim(3)); 5.4 % since
    # its frames are tracked against keyframe 0's sensor depth at once (3.8 % when they
    # waited for a keyframe-pair SfM that refined keyframe 0 first: docs/results.md)
    seg = (res.segments == 1) & res.tracked
    gt = np.array([f.T_world_cam for f in other])[seg[27:]]
    a = ate_sim3((res.timestamps[seg], res.poses[seg]), (res.timestamps[seg], gt))
    assert a.rmse_percent_of_length < 6.0


@pytest.mark.parametrize("model", ["constant_depth", "constant_normal"])
def test_primitive_model_ablations_reshape_primitives(frames, model):
    from spgeo.primitive_models import apply_primitive_model

    prims = frontend().primify(frames[0].image, CAM, frames[0].depth)
    out = apply_primitive_model(prims, model)
    assert len(out) == len(prims)
    np.testing.assert_allclose(out.log_scales, prims.log_scales, atol=0.05)
    if model == "constant_depth":
        np.testing.assert_array_equal(out.log_depth, 0.0)
    else:
        # every primitive lies on its plane: 1/z is affine in (x, y)
        th = out.fit_planes()
        w = CAM.width
        x = (out.pixels % w - CAM.cx) / CAM.fx
        y = (out.pixels // w - CAM.cy) / CAM.fy
        ids = out.primitive_ids
        rho = th[ids, 0] * x + th[ids, 1] * y + th[ids, 2]
        np.testing.assert_allclose(np.exp(-out.scaled_log_depth()), rho, rtol=2e-3)


@pytest.mark.slow
def test_classical_planar_monocular_accuracy(frames):
    """Monocular classical front-end (never reads depth) with 3-DoF planar
    primitives optimised in mapping: Sim(3) ATE < 3% of the trajectory length
    on the 50-frame sequence (the issue's bound for the long run, asserted on
    the short one)."""
    fe = make_frontend("classical", FrontEndConfig(working_size=(160, 120)))
    vo = Odometry(CAM, OdometryConfig(primitive_model="planar"), fe)
    for f in frames:
        vo.track(Frame(f.image, CAM, f.timestamp))     # no depth given at all
    res = vo.result()
    gt = np.array([f.T_world_cam for f in frames])
    ok = res.tracked
    ate = ate_sim3((res.timestamps[ok], res.poses[ok]), (res.timestamps, gt))
    log.info("classical planar ATE %.2f%%", ate.rmse_percent_of_length)
    assert ok.sum() >= N_FRAMES - 2
    assert ate.rmse_percent_of_length < 3.0


@pytest.mark.slow
def test_mapping_failure_restarts_the_window(frames, caplog):
    """A gtsam exception inside the smoother update (e.g. an indeterminant
    system) restarts the window from the last two keyframes instead of
    crashing; tracking goes on and the trajectory stays accurate."""

    class Failing:
        def update(self, *args):
            raise RuntimeError("Indeterminant linear system detected (injected)")

    # keyframes every 0.1 median depths: a third keyframe maps after the failure
    vo = Odometry(CAM, OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=0.1),
                                      mapping=MappingConfig(mode="inline")), frontend())
    injected = False
    for i, f in enumerate(frames):
        if not injected and len(vo.keyframes) >= 2:
            vo.smoother, injected = Failing(), True
        vo.track(f)
    assert injected
    assert any("restarting the window" in r.message for r in caplog.records)
    res = vo.result()
    assert res.tracked.all() and res.is_keyframe.sum() >= 3
    gt = np.array([f.T_world_cam for f in frames])
    assert ate_sim3((res.timestamps, res.poses), (res.timestamps, gt)).rmse_percent_of_length < 3.0


def test_pixel_selection_accuracy(frames):
    """With a pixel budget (tracking on DSO-style selected pixels, default
    thresholds: the decisions are taken on the decision pixels) the
    run meets the all-pixel bound of test_end_to_end_accuracy, with as many
    keyframes as the all-pixel run give or take one; tracking uses at most
    the budget plus the per-primitive minima at the finest level, every
    keyframe (keyframe 0 of the initialisation included) the selection."""
    cfg = OdometryConfig(pixel_budget=1000)
    vo = Odometry(CAM, cfg, frontend())
    results = [vo.track(f) for f in frames]
    assert all(kf.selection == cfg.selection for kf in vo.keyframes)
    assert results[1].track.report[-1]["pixels"] <= 1000 + (
        cfg.pixel_selection.min_per_primitive * results[1].track.report[-1]["primitives"])
    vo_all = Odometry(CAM, OdometryConfig(), frontend())
    for f in frames:
        vo_all.track(f)
    res = vo.result()
    assert abs(res.is_keyframe.sum() - vo_all.result().is_keyframe.sum()) <= 1
    assert res.is_keyframe.sum() >= 2 and res.tracked.sum() >= N_FRAMES - 2
    mapping = vo.report()["mapping"]
    assert mapping and all("primitives_without_pixels" in m for m in mapping)
    gt = np.array([f.T_world_cam for f in frames])
    ok = res.tracked
    ate = ate_sim3((res.timestamps[ok], res.poses[ok]), (res.timestamps, gt))
    log.info("VO with pixel selection: ATE %.2f%%", ate.rmse_percent_of_length)
    assert ate.rmse_percent_of_length < 3.0
    n_min = cfg.pixel_selection.min_per_primitive
    tracked = [r.track for r in results[-10:] if r.track is not None and r.track.ok]
    assert tracked
    for tr in tracked:
        fine = tr.report[-1]
        assert fine["level"] == 0 and fine["pixels"] <= 1000 + n_min * fine["primitives"]


def test_monocular_reinitialisation_keeps_the_depth_scale(frames):
    """A monocular (classical) map re-initialised after a loss starts its new
    segment near the previous map's depth scale (a coarse check: the synthetic
    map's scale is close to 1, the unit of an unscaled front-end)."""
    other = synthetic.render_frames(synthetic.SyntheticScene.generate(7), CAM,
                                     synthetic.make_trajectory(40, 7), supersample=2)
    seq = list(frames[:40]) + [Frame(np.zeros_like(frames[0].image), CAM, 0.0)] * 2 + list(other)
    vo = Odometry(CAM, OdometryConfig(max_lost_frames=3),
                  make_frontend("classical", FrontEndConfig(working_size=(160, 120))))
    out = [vo.track(Frame(f.image, CAM, i / 30.0)) for i, f in enumerate(seq)]
    assert [r.status for r in out].count("reinit") == 1
    seg = {0: [], 1: []}
    for kf_res in out:
        if kf_res.keyframe_index is not None:
            seg[kf_res.segment].append(vo.keyframes[kf_res.keyframe_index].median_depth)
    assert len(seg[0]) >= 2 and len(seg[1]) >= 2, seg
    # the rooms differ, the scale of the map does not jump by more than the scenes do
    ratio = np.median(seg[1]) / seg[0][-1]
    assert 0.4 < ratio < 2.5, (seg, ratio)
