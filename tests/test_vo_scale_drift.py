"""Keyframe scale-drift diagnostic (spgeo.evaluation.vo.scale_drift): with the
depth front-end (metric scales from the sensor depth) every keyframe's depth
matches the sensor's and the keyframe baselines the ground truth's, so the
ratios are 1 within a few per cent."""
import numpy as np

from spgeo.vo import KeyframeDecisionConfig, OdometryConfig
from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.evaluation.vo.scale_drift import keyframe_baseline_ratios, keyframe_depth_ratios, main


def test_depth_frontend_ratios_are_one():
    cam = synthetic.default_camera(160, 120)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(0), cam,
                                     synthetic.make_trajectory(30, 0), supersample=2)
    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(160, 120), keyframe=KeyframeDecisionConfig(max_translation=0.05)), frontend="depth",
                                           progress=False))
    ratios = keyframe_depth_ratios(run, frames)
    assert len(ratios) >= 2 and ratios[0][0] == 0
    np.testing.assert_allclose([r for _, r in ratios], 1.0, rtol=0.05)
    baselines = keyframe_baseline_ratios(run)
    assert set(baselines) == {f for f, _ in ratios[1:]}
    np.testing.assert_allclose(list(baselines.values()), 1.0, rtol=0.1)


def test_cli_bad_dataset(tmp_path, capsys):
    assert main(["--dataset", "tum", str(tmp_path / "none")]) == 2
    assert "vo_scale_drift: error:" in capsys.readouterr().err
