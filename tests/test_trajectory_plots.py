"""spgeo.apps.trajectory_plots: evo-like top view and error-over-time PNGs,
written atomically, their error curve equal to the per-frame ATE errors; and
VORun.save writing them when the ground truth is known."""
import struct

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from spgeo.vo import OdometryConfig
from spgeo import synthetic  # noqa: E402
from spgeo.apps.trajectory_plots import (ERROR_NAME, TOPVIEW_NAME,  # noqa: E402
                                         write_reconstruction_topview, write_trajectory_plots)
from spgeo.apps.vo_run import VORunConfig, run_odometry  # noqa: E402
from spgeo.evaluation.trajectory import ate_sim3  # noqa: E402
from spgeo.geometry import so3_exp  # noqa: E402


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _estimate(gt: np.ndarray, seed: int = 0) -> np.ndarray:
    """``gt`` in another Sim(3) frame, with noisy positions."""
    rng = np.random.default_rng(seed)
    S = np.eye(4)
    S[:3, :3] = so3_exp(np.array([0.3, -0.2, 0.5]))
    S[:3, 3] = [1.0, -2.0, 0.5]
    est = np.array([S @ T for T in gt])
    est[:, :3, 3] = 0.5 * est[:, :3, 3] + rng.normal(0, 0.01, (len(gt), 3))
    return est


def test_plots_and_their_error_curve(tmp_path):
    gt = synthetic.make_trajectory(60, 3)
    t = np.arange(60) / 30.0
    ate = ate_sim3((t, _estimate(gt)), (t, gt), max_time_diff=1e-3)
    plots = write_trajectory_plots(ate, tmp_path / "seq", title="seq", size_px=(640, 480))
    assert plots.topview == tmp_path / "seq" / TOPVIEW_NAME
    assert plots.error == tmp_path / "seq" / ERROR_NAME
    for p in (plots.topview, plots.error):
        assert _png_size(p) == (640, 480)
    # the plotted errors are the per-frame ATE errors, i.e. |aligned estimate - ground truth|
    np.testing.assert_array_equal(plots.errors, ate.errors)
    np.testing.assert_allclose(plots.errors, np.linalg.norm(
        ate.aligned_positions - ate.gt_positions, axis=1), atol=1e-9)
    np.testing.assert_allclose(plots.timestamps, t)
    assert np.sqrt(np.mean(plots.errors ** 2)) == pytest.approx(ate.rmse, rel=1e-9)
    # the top view uses the ground truth's two axes of largest spread
    spread = np.ptp(gt[:, :3, 3], axis=0)
    assert np.argmin(spread) not in plots.plane
    # atomic writes leave no temporary files behind
    assert sorted(p.name for p in (tmp_path / "seq").iterdir()) == sorted([TOPVIEW_NAME,
                                                                           ERROR_NAME])


def test_bad_input_and_reconstruction_view(tmp_path):
    class Short:
        timestamps = np.zeros(1)
        errors = np.zeros(1)
        aligned_positions = gt_positions = np.zeros((1, 3))
        rmse = median = 0.0

    with pytest.raises(ValueError, match="2 poses"):
        write_trajectory_plots(Short(), tmp_path)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3))
    out = write_reconstruction_topview(tmp_path / "view.png", [(pts, rng.random((500, 3)))],
                                       np.cumsum(rng.normal(size=(20, 3)), 0),
                                       ground_truth=np.zeros((20, 3)), size_px=(480, 320))
    assert _png_size(out) == (480, 320)


@pytest.mark.slow
def test_vo_run_save_writes_the_plots(tmp_path):
    cam = synthetic.default_camera(80, 60)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(0), cam,
                                     synthetic.make_trajectory(12, 0)[::2])
    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(80, 60)), frontend="depth",
                                           progress=False))
    ate = run.ate()
    paths = run.save(tmp_path / "run", ate=ate)
    assert paths["plot_topview"] == tmp_path / "run" / TOPVIEW_NAME
    assert _png_size(paths["plot_error"]) == (640, 480)
    assert ate["per-frame"].n_associated == 6
    # no ground truth: no plots
    for f in frames:
        f.T_world_cam = None
    paths = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(80, 60)), frontend="depth",
                                             progress=False)).save(tmp_path / "nogt")
    assert "plot_topview" not in paths and not (tmp_path / "nogt" / TOPVIEW_NAME).exists()
