"""Metric output scale (issue 30, ``--metric-scale``): :func:`estimate_metric_scale` with an
oracle depth predictor on rendered views of known scale (noise and outliers), the similarity
applied to a run's outputs (trajectory, clouds, ATE), the VO on a synthetic sequence with an
oracle, and ``spgeo vo --metric-scale`` with the real FastDepth on the shared 7-Scenes
frames (skipped without ../shared) against the Sim(3) ATE scale."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import shared_data_dir, write_synthetic_views
from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_metric_scale, run_odometry
from spgeo.cli import main
from spgeo.vo.metric_scale import (MetricScaleConfig, ScaledOdometry, estimate_metric_scale,
                                   scaled_trajectory)

#: the known factor: metres per VO unit of the synthetic "keyframe depths"
FACTOR = 2.7


def rendered_keyframes(n=6, seed=3, size=(96, 72)):
    """``n`` rendered views of a synthetic room: (image, true depth in metres)."""
    cam = synthetic.default_camera(*size)
    scene = synthetic.SyntheticScene.generate(seed)
    views = [scene.render(cam, T) for T in synthetic.make_trajectory(3 * n, seed)[::3]]
    return [(v.rgb, v.depth.astype(np.float64)) for v in views]


def noisy_oracle(truth, factor=1.0, noise=0.1, outliers=0.2, seed=0):
    """``image -> depth``: the true depth (looked up by image) times ``factor``, times
    log-normal noise (sigma ``noise``), with a fraction ``outliers`` of pixels x0.2..x5."""
    rng = np.random.default_rng(seed)

    def predict(image):
        i = int(np.argmin([np.abs(image - img).mean() for img, _ in truth]))
        d = truth[i][1] * factor * np.exp(rng.normal(0.0, noise, truth[i][1].shape))
        bad = rng.random(d.shape) < outliers
        return np.where(bad, d * np.exp(rng.uniform(np.log(0.2), np.log(5.0), d.shape)), d)
    return predict


def test_recovers_a_known_factor_with_noise_and_outliers():
    """Keyframe depths in a unit FACTOR times smaller than metres, with holes (NaN) and
    non-positive pixels; the network: truth with 10 % log noise and 20 % outliers.
    Stated tolerance: the factor within 2 %, the spread below x1.05."""
    truth = rendered_keyframes()
    rng = np.random.default_rng(1)
    pairs = []
    for img, d in truth:
        kf = d / FACTOR
        kf[rng.random(kf.shape) < 0.3] = np.nan      # pixels no primitive covers
        kf[:4] = 0.0                                  # invalid
        pairs.append((img, kf))
    res = estimate_metric_scale(pairs, noisy_oracle(truth))
    assert res.scale == pytest.approx(FACTOR, rel=0.02)
    assert 1.0 <= res.spread < 1.05 and res.n_keyframes == len(truth)
    assert res.interval[0] <= res.scale <= res.interval[1]
    assert all(r == pytest.approx(FACTOR, rel=0.03) for r in res.per_keyframe)
    d = res.to_dict()
    assert d["estimated"] is True and d["n_keyframes"] == len(truth)
    json.dumps(d)


def test_a_keyframe_without_overlap_is_left_out_and_none_refused():
    truth = rendered_keyframes(n=3)
    pairs = [(img, d / FACTOR) for img, d in truth]
    pairs[1] = (pairs[1][0], np.full_like(pairs[1][1], np.nan))
    res = estimate_metric_scale(pairs, noisy_oracle(truth, noise=0.0, outliers=0.0))
    assert res.per_keyframe[1] is None and res.n_pixels[1] == 0 and res.n_keyframes == 2
    assert res.scale == pytest.approx(FACTOR, rel=1e-6)
    with pytest.raises(ValueError, match="none of the 1 keyframes has 100 pixels"):
        estimate_metric_scale([pairs[1]], noisy_oracle(truth))
    with pytest.raises(ValueError, match="no keyframe was given"):
        estimate_metric_scale([], noisy_oracle(truth))
    with pytest.raises(ValueError, match="min_pixels"):
        MetricScaleConfig(min_pixels=0)


def test_prediction_of_another_size_is_resized():
    img, d = rendered_keyframes(n=1)[0]
    small = d[::2, ::2] * FACTOR
    res = estimate_metric_scale([(img, d)], lambda image: small)
    assert res.scale == pytest.approx(FACTOR, rel=0.02)


# ------------------------------------------------------------------ a VO run
@pytest.fixture(scope="module")
def synthetic_run():
    """The monocular VO on 50 rendered frames, processed at their 160x120."""
    from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence
    from spgeo.vo import OdometryConfig

    frames = synthetic_sequence(SyntheticVOConfig(n_frames=50, seed=0, size=(160, 120),
                                                  rotation=None))
    config = VORunConfig(progress=False, odometry=OdometryConfig(resolution=(160, 120)))
    return frames, run_odometry(frames, config)


class FrameOracle:
    """A metric-depth 'network': the rendered depth of the frame whose image it is, times
    ``factor``, with log noise and outliers (:func:`noisy_oracle`)."""

    def __init__(self, frames, factor):
        self.predict_metric = noisy_oracle(
            [(f.image, f.depth.astype(np.float64)) for f in frames], factor)


@pytest.mark.slow
def test_run_scale_agrees_with_the_sim3_alignment(synthetic_run, tmp_path):
    """On a synthetic sequence, the estimated scale (oracle = truth x 1.5) is 1.5 times the
    Sim(3) ATE scale (ground-truth metres per VO unit) within 5 % (measured: 3.5 %, the
    keyframes' depths against the trajectory's scale; the per-keyframe scales agree with
    each other to 1 %, spread below x1.02); the scaled run's outputs
    are the unscaled ones times the estimate and its ATE scale is then 1 / 1.5."""
    frames, run = synthetic_run
    ate_scale = run.ate()["per-frame"].scale
    est = run_metric_scale(run.odometry, FrameOracle(frames, 1.5), "oracle")
    assert est.scale == pytest.approx(1.5 * ate_scale, rel=0.05)
    assert est.spread < 1.02
    assert est.model == "oracle" and est.seconds >= 0
    assert est.n_keyframes == len(run.odometry.keyframes_with_depth()) >= 3

    plain = run.result()
    run.metric_scale = est
    try:
        scaled = run.result()
        np.testing.assert_allclose(scaled.poses[:, :3, 3], est.scale * plain.poses[:, :3, 3])
        np.testing.assert_array_equal(scaled.poses[:, :3, :3], plain.poses[:, :3, :3])
        assert run.ate()["per-frame"].scale == pytest.approx(ate_scale / est.scale, rel=1e-6)
        paths = run.save(tmp_path / "out")
        report = json.loads((tmp_path / "out" / "report.json").read_text())
        assert report["metric_scale"]["estimated"] is True
        assert report["metric_scale"]["scale"] == pytest.approx(est.scale)
        assert any("metric scale" in line for line in run.summary_lines())
        view = ScaledOdometry(run.odometry, est.scale)
        k = run.odometry.keyframes_with_depth()[-1]
        X = run.odometry.keyframe(k).primitives.point_cloud().transformed(
            run.odometry.keyframe(k).T_world_kf).points
        Xs = view.keyframe(k).primitives.point_cloud().transformed(view.keyframe(k).T_world_kf)
        np.testing.assert_allclose(Xs.points, est.scale * X, rtol=1e-9, atol=1e-9)
        assert len(paths["clouds"]) == len(run.odometry.keyframes_with_depth())
        saved = view.save(tmp_path / "view")          # the view writes what it shows
        T_saved = np.loadtxt(saved["trajectory"], comments="#")
        np.testing.assert_allclose(T_saved[:, 1:4], scaled.poses[:, :3, 3], rtol=1e-6, atol=1e-8)
        tf = json.loads(run.export_nerfstudio(tmp_path / "ns").read_text())
        centres = np.array([f["transform_matrix"] for f in tf["frames"]])[:, :3, 3]
        kf_poses = scaled.poses[scaled.is_keyframe]
        np.testing.assert_allclose(centres, kf_poses[:, :3, 3], rtol=1e-6, atol=1e-9)
    finally:
        run.metric_scale = None
    np.testing.assert_array_equal(run.result().poses, plain.poses)


def test_scaled_trajectory_keeps_nan_and_statuses():
    from spgeo.trajectory import Trajectory

    poses = np.stack([np.eye(4)] * 3)
    poses[1, :3, 3] = [1.0, 2.0, 3.0]
    poses[2] = np.nan
    t = Trajectory(np.arange(3.0), poses, ["ok", "keyframe", "lost"])
    s = scaled_trajectory(t, 2.0)
    np.testing.assert_array_equal(s.poses[1, :3, 3], [2.0, 4.0, 6.0])
    assert np.isnan(s.poses[2]).all() and s.statuses == t.statuses
    np.testing.assert_array_equal(t.poses[1, :3, 3], [1.0, 2.0, 3.0])     # not modified


# ------------------------------------------------------------------ the command line
def test_bad_model_path_exits_2_naming_it(tmp_path, capsys):
    write_synthetic_views(tmp_path, seed=0)
    out = tmp_path / "out"
    missing = tmp_path / "nope.onnx"
    rc = main(["vo", "--dataset", "folder", str(tmp_path), "--out", str(out), "--no-progress",
               "--metric-scale", str(missing)])
    _, err = capsys.readouterr()
    assert rc == 2 and "metric scale model" in err and "nope.onnx" in err
    assert "Traceback" not in err and not out.exists()


def test_a_run_without_a_map_keeps_vo_units(tmp_path, caplog):
    """Two frames never initialise a monocular map: no estimate, the reason in the report."""
    from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence

    frames = synthetic_sequence(SyntheticVOConfig(n_frames=2, size=(64, 48), rotation=None))
    run = run_odometry(frames, VORunConfig(progress=False))
    with pytest.raises(ValueError, match="no keyframe carries depth"):
        run_metric_scale(run.odometry, FrameOracle(frames, 1.0))
    run.metric_scale_failure = "no keyframe carries depth"
    run.save(tmp_path / "out")
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["metric_scale"]["estimated"] is False
    assert "no keyframe carries depth" in report["metric_scale"]["reason"]


def test_config_refuses_an_empty_model():
    with pytest.raises(ValueError, match="metric_scale"):
        VORunConfig(metric_scale="  ")


def test_non_metric_model_is_refused(tmp_path, monkeypatch, capsys):
    """A registered relative-depth model (generic-depth-518 preset): exit 2, 'not metric'."""
    import onnx_builders as B
    from spgeo import models

    write_synthetic_views(tmp_path, seed=0)
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "cache"))
    models.register_model("toy-relative", B.depth_model(tmp_path / "rel.onnx",
                                                        coeffs=(0.2, -0.1, 0.5)))
    out = tmp_path / "out"
    rc = main(["vo", "--dataset", "folder", str(tmp_path), "--out", str(out), "--no-progress",
               "--metric-scale", "toy-relative"])
    _, err = capsys.readouterr()
    assert rc == 2 and "metric scale model 'toy-relative'" in err and "not metric" in err
    assert not out.exists()


#: measured on 7-Scenes redkitchen 0:300 (classical front-end, 320x240): the Sim(3) ATE
#: scale of the metric outputs (ground truth / estimate) is 0.94 (FastDepth's own median
#: scale there is ~0.99 of the ground truth; the rest is the keyframe depths' error); the
#: test allows 0.85-1.15.
SEVEN_SCENES_TOLERANCE = 0.15


@pytest.mark.slow
def test_fastdepth_on_7scenes_agrees_with_the_ate_scale(tmp_path, capsys):
    model = shared_data_dir().parent / "models" / "fastdepth" / "fastdepth_nyu_224.onnx"
    seq = shared_data_dir() / "7scenes_redkitchen_dev"
    if not model.is_file() or not seq.is_dir():
        pytest.skip("shared FastDepth model or 7-Scenes frames not found")
    out = tmp_path / "out"
    rc = main(["vo", "--dataset", "7scenes", str(seq), "--frames", "0:300", "--out", str(out),
               "--no-progress", "--metric-scale", str(model)])
    text, err = capsys.readouterr()
    assert rc == 0, err
    report = json.loads((out / "report.json").read_text())
    m = report["metric_scale"]
    assert m["estimated"] is True and m["model"] == str(model) and m["n_keyframes"] >= 10
    assert m["spread"] >= 1.0 and len(m["per_keyframe"]) >= m["n_keyframes"]
    # the outputs are in metres: the Sim(3) alignment to the ground truth is about 1
    residual = report["ate"]["per-frame"]["scale"]
    assert abs(residual - 1.0) < SEVEN_SCENES_TOLERANCE, (residual, m["scale"])
    assert "metric scale (estimated" in text
