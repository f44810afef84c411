"""``spgeo vo`` and the library batch runner (spgeo.apps.vo_run) on a tiny
synthetic 7-Scenes-style sequence (40 frames rendered at 160x120, stored at
640x480 with nearest-neighbour upsampling so that the runner's INTER_AREA
downsampling gives the rendered images back)."""
import json

import cv2
import numpy as np
import pytest

from layouts import write_7scenes
from spgeo import synthetic
from spgeo.cli import main
from spgeo.evaluation.trajectory import read_status, read_tum
from spgeo.frame import Frame
from spgeo.apps.vo_run import VORunConfig, run_dataset, run_odometry
from spgeo.vo import OdometryConfig
from spgeo.apps.args import parse_resolution

N = 20
CAM = synthetic.default_camera(160, 120)
CAM_BIG = CAM.resized(640, 480)


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    # 2N frames: the CLI run takes every second one (--frames 0:40:2), enough
    # parallax to initialise within N processed frames
    return synthetic.render_frames(scene, CAM, synthetic.make_trajectory(2 * N, 0),
                                   supersample=2)


@pytest.fixture(scope="module")
def seven_scenes(tmp_path_factory, frames):
    return write_7scenes(tmp_path_factory.mktemp("vo") / "seq-01", frames, CAM_BIG.K)


@pytest.fixture(scope="module")
def seven_scenes_bad_depth(tmp_path_factory, frames):
    return write_7scenes(tmp_path_factory.mktemp("vo") / "seq-02", frames, CAM_BIG.K,
                         garbage_depth=True)


@pytest.fixture(scope="module")
def depth_run(seven_scenes, tmp_path_factory):
    out = tmp_path_factory.mktemp("vo_out") / "depth"
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes), "--frames", f"0:{2 * N}:2",
               "--frontend", "depth", "--no-progress", "--out", str(out),
               "--set", "keyframe.max_translation=0.05"])
    return rc, out


@pytest.mark.slow
def test_cli_depth_frontend_writes_trajectory_and_ate(depth_run, capsys):
    """All files written; timestamps are the 7-Scenes frame numbers (every
    second frame here); per-frame Sim(3) ATE < 5% of the trajectory length."""
    rc, out = depth_run
    assert rc == 0
    traj = read_tum(out / "trajectory.txt")
    np.testing.assert_array_equal(traj.timestamps, np.arange(0, 2 * N, 2, dtype=float))
    assert np.all(np.isfinite(traj.poses))
    np.testing.assert_allclose(traj.poses[0], np.eye(4), atol=1e-5)  # VO world = keyframe 0
    kfs = read_tum(out / "keyframes.txt")
    assert 2 <= len(kfs) <= N and kfs.timestamps[0] == 0.0
    assert set(kfs.timestamps) <= set(traj.timestamps)
    stamps, status = read_status(out / "trajectory.status.txt")
    assert len(status) == N and status[0] == "keyframe"
    rep = json.loads((out / "report.json").read_text())
    assert rep["n_frames"] == N and rep["run"]["n_frames"] == N
    assert rep["run"]["resolution"] == [320, 240] and rep["run"]["fps_wall"] > 0  # the default
    mem = rep["run"]["memory"]       # peak RSS, MiB (Linux); no checkpoint before 100 frames
    assert mem["peak_rss_mb"] > 10 and mem["rss_every_frames"] == 100
    ate = rep["ate"]
    pf = ate["per-frame"]
    assert pf["label"] == "per-frame"
    assert pf["n_associated"] == N - status.count("lost")
    assert pf["trajectory_length_m"] > 0.05
    assert pf["rmse_percent_of_length"] < 5.0
    assert pf["rmse_m"] == pytest.approx(pf["rmse_percent_of_length"] / 100
                                         * pf["trajectory_length_m"], rel=1e-6)
    assert "keyframe-only" in ate    # None with fewer than 3 keyframes
    if ate["keyframe-only"] is not None:
        assert ate["keyframe-only"]["n_associated"] == len(kfs)
    # keyframe point clouds (written by Odometry.save or by the runner)
    clouds = sorted((out / "clouds").glob("*.ply"))
    assert len(clouds) == len(kfs)
    assert all(p.stat().st_size > 1000 for p in clouds)


def test_cli_depth_summary_printed(seven_scenes, tmp_path, capsys):
    """The printed summary names both ATE variants (short 6-frame run)."""
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes), "--frames", "0:6",
               "--frontend", "depth", "--no-progress", "--out", str(tmp_path / "o")])
    text = capsys.readouterr().out
    assert rc == 0
    assert "6 frames" in text and "FPS" in text and "Sim(3) ATE per-frame" in text
    assert "keyframe-only" in text


def test_cli_classical_never_reads_depth(seven_scenes_bad_depth, tmp_path, monkeypatch):
    """Every depth file is garbage and the depth reader raises: the monocular
    run still succeeds; --frames 0:20:2 processes 10 frames (timestamps = frame
    numbers 0, 2, ..., 18)."""
    import spgeo.datasets.common as common
    import spgeo.datasets.sevenscenes as sevenscenes

    def boom(*args, **kwargs):
        raise AssertionError("depth read by a monocular run")

    monkeypatch.setattr(sevenscenes, "read_depth_png", boom)
    monkeypatch.setattr(common, "read_depth_png", boom)
    out = tmp_path / "classical"
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes_bad_depth), "--frames", "0:20:2",
               "--frontend", "classical", "--no-progress", "--out", str(out)])
    # 10 frames are too few for keyframe 1: finished, outputs written, flagged (exit 3)
    assert rc == 3
    traj = read_tum(out / "trajectory.txt")
    np.testing.assert_array_equal(traj.timestamps, np.arange(0, 20, 2, dtype=float))
    rep = json.loads((out / "report.json").read_text())
    assert rep["n_frames"] == 10
    assert rep["run"]["status"] == "no_map" and "keyframe 1" in rep["run"]["init_failure"]
    assert rep["ate"] is None or "per-frame" in rep["ate"]


def test_depth_frontend_on_garbage_depth_fails_cleanly(seven_scenes_bad_depth, tmp_path, capsys):
    """The depth front-end does read depth: undecodable files -> exit 2 with the file named."""
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes_bad_depth), "--frames", "0:3",
               "--frontend", "depth", "--no-progress", "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "depth.png" in capsys.readouterr().err


@pytest.mark.parametrize("args", [
    ["--resolution", "160by120"], ["--resolution", "0x120"], ["--resolution", "160x"],
    ["--frames", "5:3"], ["--frames", "a:b"],
])
def test_cli_bad_arguments_exit_2(seven_scenes, tmp_path, capsys, args):
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes), *args, "--no-progress",
               "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "spgeo vo: error" in capsys.readouterr().err
    assert not (tmp_path / "o" / "trajectory.txt").exists()


def test_cli_bad_dataset_exit_2(tmp_path, capsys):
    assert main(["vo", "--dataset", "7scenes", str(tmp_path / "missing"),
                 "--out", str(tmp_path / "o")]) == 2
    assert main(["vo", "--dataset", "kitti", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "kitti" in capsys.readouterr().err


def test_parse_resolution():
    assert parse_resolution("320X240") == (320, 240)
    assert parse_resolution(" 160x120 ") == (160, 120)
    for bad in ("160", "160x120x3", "-160x120", "1.5x2", "8x8"):
        with pytest.raises(ValueError):
            parse_resolution(bad)
    with pytest.raises(ValueError):
        OdometryConfig(resolution=(0, 120))
    # the shared parser behind it: 'native' and the minimum size are the caller's choice
    from spgeo.apps.args import parse_resolution as parse_any
    assert parse_any("native", allow_native=True) is None
    assert parse_any("8x8", min_size=1) == (8, 8)
    with pytest.raises(ValueError):
        parse_any("native")


def test_cli_dataset_kinds_are_the_readers():
    from spgeo.apps.args import DATASET_KINDS
    from spgeo.datasets import DATASET_KINDS as READERS

    assert set(DATASET_KINDS) == set(READERS)
    with pytest.raises(ValueError):
        VORunConfig(frontend="sift")


class _NoDepthFrame:
    """A frame whose depth must not be touched."""

    def __init__(self, f):
        self.image, self.camera, self.timestamp = f.image, f.camera, f.timestamp
        self.T_world_cam, self.name = f.T_world_cam, f.name

    @property
    def depth(self):
        raise AssertionError("Frame.depth read by a monocular run")


def test_run_odometry_library(frames):
    """Library runner: monocular never reads Frame.depth; ground truth kept per
    frame; the image is resized to the requested resolution."""
    cfg = VORunConfig(odometry=OdometryConfig(resolution=(80, 60)), progress=False)
    run = run_odometry((_NoDepthFrame(f) for f in frames[:4]), cfg)
    assert run.n_frames == 4 and len(run.gt_poses) == 4
    np.testing.assert_allclose(run.gt_poses[2], frames[2].T_world_cam)
    np.testing.assert_array_equal(run.timestamps, [f.timestamp for f in frames[:4]])
    assert run.odometry.camera.size == (80, 60)
    assert run.odometry.camera.fx == pytest.approx(CAM.fx / 2)
    assert run.fps > 0 and run.wall_seconds > 0
    assert run.has_ground_truth
    lines = run.summary_lines()
    assert lines[0].startswith("4 frames")


def test_run_odometry_bad_input(frames, tmp_path):
    cfg = VORunConfig(progress=False)
    with pytest.raises(ValueError, match="no frames"):
        run_odometry([], cfg)
    small = synthetic.default_camera(80, 60)
    odd = Frame(np.zeros((60, 80, 3), np.float32), small, 1.0)
    with pytest.raises(ValueError, match="one camera"):
        run_odometry([frames[0], odd], cfg)
    with pytest.raises(ValueError, match="timestamp"):
        run_odometry([frames[1], frames[0]], cfg)
    nodepth = Frame(frames[0].image, CAM, 0.0)
    with pytest.raises(ValueError, match="no depth"):
        run_odometry([nodepth], VORunConfig(frontend="depth", progress=False))
    with pytest.raises(FileNotFoundError):
        run_dataset("7scenes", tmp_path / "missing", config=cfg)


def test_no_ground_truth_gives_no_ate(frames):
    no_gt = [Frame(f.image, CAM, f.timestamp, name=f.name) for f in frames[:3]]
    run = run_odometry(no_gt, VORunConfig(progress=False))
    assert not run.has_ground_truth and run.ate() is None
    assert "no ground truth" in run.summary_lines()[-1]


def test_evaluation_run_vo_wrapper(frames):
    """evaluation.vo_run.run_vo keeps its signature and return value."""
    from spgeo.apps.vo_run import run_vo
    from spgeo.vo import Odometry, OdometryConfig

    vo, gt, fps = run_vo(frames[:3], (160, 120), "classical", OdometryConfig(), progress=False)
    assert isinstance(vo, Odometry) and len(vo.result().timestamps) == 3
    assert len(gt) == 3 and gt[0] is not None and fps > 0


@pytest.mark.slow
def test_cli_report_has_effective_config(depth_run):
    """report.json: the OdometryConfig under "config", the rest of the run config under
    "run_config" (spgeo vo --set / --config)."""
    from spgeo.odometry import OdometryConfig

    rc, out = depth_run
    rep = json.loads((out / "report.json").read_text())
    assert rep["config"]["window"] == OdometryConfig().window
    assert rep["run_config"]["frontend"] == "depth"
    # no --resolution: the config keeps None (the rule), the run reports the size used
    assert rep["config"]["resolution"] is None and "odometry" not in rep["run_config"]
    assert rep["run"]["resolution"] == [320, 240]


def test_rerun_without_rerun_installed_is_a_bad_input_with_the_hint(seven_scenes, tmp_path,
                                                                     monkeypatch, capsys):
    """``--rerun`` where rerun is not importable: exit 2 and the install hint, not an
    "unexpected ImportError" (issue 53)."""
    import sys

    monkeypatch.setitem(sys.modules, "rerun", None)
    code = main(["vo", "--dataset", "7scenes", str(seven_scenes), "--frames", "0:3",
                 "--rerun", "save", str(tmp_path / "a.rrd"), "--no-progress",
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "pip install 'spgeo[viz]'" in err and "unexpected" not in err
