"""Global photometric bundle adjustment after a VO run (spgeo.vo.global_ba,
Odometry.refine): synthetic hand-held sequence, 160x120, oracle-depth front-end,
a window of 2 so most keyframes are retired to the keyframe store."""
import json

import gtsam
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.configs import config_to_dict
from spgeo.evaluation.trajectory import ate_sim3
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.geometry import invert_pose, so3_exp
from spgeo.graph.keys import pose_key
from spgeo.vo import GlobalBAConfig, KeyframeDecisionConfig, Odometry, OdometryConfig
from spgeo.vo.global_ba import _DistanceGauge

CAM = synthetic.default_camera(160, 120)
N_FRAMES = 40


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    return synthetic.render_frames(scene, CAM, synthetic.make_trajectory(N_FRAMES, 0),
                                   supersample=2)


def _run(frames):
    """Keyframes every 0.02 median depths, a window of 2: most keyframes retire."""
    vo = Odometry(CAM, OdometryConfig(window=2,
                                      keyframe=KeyframeDecisionConfig(max_translation=0.02)),
                  make_frontend("depth", FrontEndConfig(working_size=(160, 120))))
    for f in frames:
        vo.track(f)
    return vo


def _kf_ate(vo, frames):
    res = vo.result()
    gt = np.array([f.T_world_cam for f in frames])
    return ate_sim3((res.keyframe_timestamps, res.keyframe_poses), (res.timestamps, gt),
                    label="keyframe-only")


def _frame_ate(vo, frames):
    res = vo.result()
    gt = np.array([f.T_world_cam for f in frames])
    ok = res.tracked
    return ate_sim3((res.timestamps[ok], res.poses[ok]), (res.timestamps, gt))


def test_distance_gauge_jacobians_match_numerical_derivatives():
    rng = np.random.default_rng(0)
    Ta = np.eye(4)
    Ta[:3, :3], Ta[:3, 3] = so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3)
    Tb = np.eye(4)
    Tb[:3, :3], Tb[:3, 3] = so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3)
    ka, kb = pose_key(0), pose_key(1)
    base = Tb[:3, 3] - Ta[:3, 3] + np.array([0.1, -0.05, 0.02])   # not the current one
    g = _DistanceGauge(ka, kb, base, 1e-3)
    vals = gtsam.Values()
    vals.insert(ka, gtsam.Pose3(Ta))
    vals.insert(kb, gtsam.Pose3(Tb))
    H = [None, None]
    e0 = g._error(g.factor, vals, H)
    d0 = np.linalg.norm(base)
    np.testing.assert_allclose(e0, [base @ (Tb[:3, 3] - Ta[:3, 3]) / d0 ** 2 - 1.0])
    eps = 1e-6
    for j, (key, T) in enumerate(((ka, Ta), (kb, Tb))):
        num = np.zeros(6)
        for i in range(6):
            xi = np.zeros(6)
            xi[i] = eps
            v2 = gtsam.Values(vals)
            v2.update(key, gtsam.Pose3(T).retract(xi))
            num[i] = (g._error(g.factor, v2, None)[0] - e0[0]) / eps
        np.testing.assert_allclose(H[j].ravel(), num, atol=1e-5)


@pytest.mark.slow
def test_refine_pulls_perturbed_keyframes_back(frames):
    """Perturbed keyframe poses (1 deg, 3 % of the depth) and scales (+5 %) of a
    finished run, keyframes 0 and 1 (the gauge) left alone: the adjustment brings
    the keyframe ATE back near the unperturbed run's."""
    vo = _run(frames)
    assert vo.n_keyframes >= 5
    ate0 = _kf_ate(vo, frames).rmse
    rng = np.random.default_rng(1)
    for k in range(2, vo.n_keyframes):
        mk = vo._map.kfs[k]
        dT = np.eye(4)
        dT[:3, :3] = so3_exp(rng.normal(size=3) * np.radians(1.0) / np.sqrt(3))
        dT[:3, 3] = rng.normal(size=3) * 0.03 * mk.median_depth / np.sqrt(3)
        mk.correct(mk.T_world_kf @ dT, 1.05)
    ate_pert = _kf_ate(vo, frames).rmse
    assert ate_pert > 2.0 * ate0
    res = vo.refine(GlobalBAConfig(max_iterations=50))
    assert res.status == "ok" and res.final_cost < res.initial_cost
    ate1 = _kf_ate(vo, frames).rmse
    assert ate1 < max(1.5 * ate0, ate0 + 0.2 * (ate_pert - ate0)), (ate0, ate_pert, ate1)


@pytest.mark.slow
def test_refine_keeps_or_improves_the_ate_and_updates_the_result(frames, tmp_path):
    """The refined trajectory's ATE is no worse (small margin); result() and the
    keyframes (retired ones read back from the store) carry the refined state;
    the report has the refinement."""
    vo = _run(frames)
    live = set(vo.window_keyframes())
    retired = [k for k in range(vo.n_keyframes) if k not in live]
    assert retired, "the test needs retired keyframes"
    ate_before = _frame_ate(vo, frames).rmse
    res = vo.refine()
    assert res.status == "ok" and set(res.T_world_kf) == set(range(vo.n_keyframes))
    assert res.n_factors > 0 and res.iterations >= 1 and res.seconds > 0
    ate_after = _frame_ate(vo, frames).rmse
    assert ate_after <= ate_before * 1.05 + 1e-4, (ate_before, ate_after)
    out = vo.result()
    kf_frames = np.flatnonzero(out.is_keyframe)
    for k, i in enumerate(kf_frames):
        np.testing.assert_allclose(out.poses[i], res.T_world_kf[k], atol=1e-9)
    for k in retired + sorted(live):
        kf = vo.keyframe(k)
        np.testing.assert_allclose(kf.T_world_kf, res.T_world_kf[k], atol=1e-9)
        np.testing.assert_allclose(kf.primitives.log_scales, res.shapes[k][:, 0], atol=1e-9)
    rep = vo.report()["refine"]
    assert rep["status"] == "ok" and rep["seconds"] > 0
    assert rep["final_cost"] <= rep["initial_cost"]
    json.dumps(rep)
    # the gauge: keyframe 0's pose and the keyframe 0-1 distance are kept
    T0 = res.T_world_kf[0]
    assert np.allclose(out.poses[kf_frames[0]], T0, atol=1e-5)


@pytest.mark.slow
def test_tracking_continues_after_refine(frames):
    """refine() in the middle of a run: the window restarts at the next keyframe
    and tracking goes on without loss."""
    vo = _run(frames[:25])
    vo.refine()
    n_kf = vo.n_keyframes
    out = [vo.track(f) for f in frames[25:]]
    assert all(r.status != "lost" for r in out)
    assert vo.n_keyframes > n_kf
    assert _frame_ate(vo, frames).rmse_percent_of_length < 3.0


def test_refine_without_a_map_is_skipped(frames):
    vo = Odometry(CAM, OdometryConfig(),
                  make_frontend("depth", FrontEndConfig(working_size=(160, 120))))
    vo.track(frames[0])
    res = vo.refine()
    assert res.status == "skipped" and not res.T_world_kf
    assert vo.report()["refine"]["status"] == "skipped"


def test_global_ba_config_validates():
    with pytest.raises(ValueError):
        GlobalBAConfig(neighbours=0)
    with pytest.raises(ValueError):
        GlobalBAConfig(relative_tol=0.0)
    with pytest.raises(ValueError):
        GlobalBAConfig(shape_prior_weight=0.0)


@pytest.mark.slow
def test_refine_with_planar_primitives(frames):
    """primitive_model="planar": plane variables (N, 3) per keyframe, applied to
    the keyframes (retired ones included)."""
    vo = Odometry(CAM, OdometryConfig(window=2,
                                      keyframe=KeyframeDecisionConfig(max_translation=0.02),
                                      primitive_model="planar"),
                  make_frontend("depth", FrontEndConfig(working_size=(160, 120))))
    for f in frames[:30]:
        vo.track(f)
    res = vo.refine()
    assert res.status == "ok" and all(s.shape[1] == 3 for s in res.shapes.values())
    assert res.final_cost < res.initial_cost
    # the bound of the VO tests (the mechanics are checked here, accuracy in the tests above)
    assert _frame_ate(vo, frames[:30]).rmse_percent_of_length < 3.0
    for k in range(vo.n_keyframes):      # the keyframe's points lie on the refined planes
        prims, th = vo.keyframe(k).primitives, res.shapes[k]
        x = (prims.pixels % CAM.width - CAM.cx) / CAM.fx
        y = (prims.pixels // CAM.width - CAM.cy) / CAM.fy
        ids = prims.primitive_ids
        rho = th[ids, 0] * x + th[ids, 1] * y + th[ids, 2]
        np.testing.assert_allclose(np.exp(-prims.scaled_log_depth()), rho, rtol=2e-3)


@pytest.mark.slow
def test_run_odometry_refine_reports_time_and_memory(frames, tmp_path):
    """VORunConfig.refine: the runner refines after the last frame; report.json has
    "refine" (seconds, costs, iterations) and the peak RSS before it."""
    from spgeo.apps.vo_run import VORunConfig, run_odometry

    cfg = VORunConfig(frontend="depth", progress=False, refine=GlobalBAConfig(),
                      odometry=OdometryConfig(resolution=(160, 120), window=2,
                                              keyframe=KeyframeDecisionConfig(max_translation=0.02)))
    run = run_odometry(frames, cfg)
    run.save(tmp_path / "out")
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert rep["refine"]["status"] == "ok" and rep["refine"]["seconds"] > 0
    assert rep["refine"]["iterations"] >= 1
    assert rep["run"]["memory"]["peak_rss_mb_before_refine"] > 0
    assert rep["run_config"]["refine"] == config_to_dict(GlobalBAConfig())


def test_cli_refine_flag_sets_the_run_config():
    from spgeo.cli import build_parser
    from spgeo.cli.vo import _run_config

    parse = build_parser().parse_args
    args = parse(["vo", "--dataset", "7scenes", "x", "--out", "y", "--refine"])
    assert _run_config(args).refine == GlobalBAConfig()
    args = parse(["vo", "--dataset", "7scenes", "x", "--out", "y"])
    assert _run_config(args).refine is None
    # --set refine.FIELD=VALUE switches the refinement on with that value
    args = parse(["vo", "--dataset", "7scenes", "x", "--out", "y",
                  "--set", "refine.max_iterations=7"])
    assert _run_config(args).refine == GlobalBAConfig(max_iterations=7)
    args = parse(["vo", "--dataset", "7scenes", "x", "--out", "y", "--refine",
                  "--set", "refine=False"])
    assert _run_config(args).refine is None
