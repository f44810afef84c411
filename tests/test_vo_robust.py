"""Robust recordings (issue 23): an unreadable frame is skipped, not fatal
(``--strict`` keeps the abort), and the default processing size keeps the
input's aspect ratio (:func:`spgeo.vo.processing.processing_size`).

Small synthetic sequences: a 7-Scenes-style folder (640x480 PNGs, depth, poses)
and a plain folder of 2:1 images with ``camera.json`` and ``depth/*.npy``."""
import json

import cv2
import numpy as np
import pytest

from layouts import write_7scenes
from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_dataset, run_odometry
from spgeo.vo import OdometryConfig
from spgeo.vo.processing import DEFAULT_TARGET_PIXELS, SIZE_MULTIPLE, processing_size
from spgeo.camera import PinholeCamera
from spgeo.cli import main
from spgeo.datasets import open_dataset
from spgeo.evaluation.trajectory import read_status
from spgeo.tum_files import read_tum_arrays as read_tum
from spgeo.trajectory import FrameStatus, Trajectory
from spgeo.validation import FrameReadError, InputError

N = 12                      # processed frames of the 7-Scenes-style runs
BAD = 5                     # the frame whose colour file is truncated
CAM = synthetic.default_camera(160, 120)
CAM_BIG = CAM.resized(640, 480)


def _frames(camera, n):
    scene = synthetic.SyntheticScene.generate(0)
    return synthetic.render_frames(scene, camera, synthetic.make_trajectory(2 * n, 0)[::2],
                                   supersample=2)


def _rgb8(f):
    return cv2.cvtColor(np.clip(np.round(f.image * 255), 0, 255).astype(np.uint8),
                        cv2.COLOR_RGB2BGR)


def _truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


@pytest.fixture(scope="module")
def broken_seq(tmp_path_factory):
    """A 7-Scenes-style sequence whose frame BAD has a truncated colour PNG."""
    folder = write_7scenes(tmp_path_factory.mktemp("robust") / "seq-01", _frames(CAM, N),
                           CAM_BIG.K)
    _truncate(folder / f"frame-{BAD:06d}.color.png")
    return folder


def _vo(folder, out, *extra):
    return main(["vo", "--dataset", "7scenes", str(folder), "--frontend", "depth",
                 "--no-progress", "--out", str(out), *extra])


# ------------------------------------------------------------ resolution rule
def test_processing_size_rule():
    assert DEFAULT_TARGET_PIXELS == 320 * 240
    for size in ((640, 480), (1280, 960), (320, 240)):
        assert processing_size(size) == (320, 240)
    for size in ((160, 120), (320, 160), (37, 21)):        # not upsampled
        assert processing_size(size) == size
    for size in ((1241, 376), (640, 320), (1920, 1080), (480, 640)):
        w, h = processing_size(size)
        assert w % SIZE_MULTIPLE == 0 and h % SIZE_MULTIPLE == 0
        assert abs(w * h / DEFAULT_TARGET_PIXELS - 1) < 0.05
        assert abs((w / h) / (size[0] / size[1]) - 1) < 0.03
    assert processing_size((1241, 376)) == (504, 152)
    assert processing_size((640, 480), target_pixels=160 * 120) == (160, 120)
    with pytest.raises(InputError):
        processing_size((0, 480))


def test_explicit_resolution_wins_and_compare_follows_the_rule():
    from spgeo.evaluation.vo.compare import DEFAULT_RESOLUTION, VOCompareConfig, compare_size

    assert OdometryConfig().resolution is None
    assert OdometryConfig().processing_size_for((1241, 376)) == processing_size((1241, 376))
    assert OdometryConfig(resolution=(160, 120)).processing_size_for((1241, 376)) == (160, 120)
    assert OdometryConfig(target_pixels=160 * 120).processing_size_for((640, 480)) == (160, 120)
    with pytest.raises(InputError):
        OdometryConfig(target_pixels=0)
    assert VOCompareConfig().resolution == DEFAULT_RESOLUTION
    assert (compare_size(DEFAULT_RESOLUTION, (1241, 376))
            == OdometryConfig().processing_size_for((1241, 376)))
    assert compare_size(None, (1241, 376)) is None
    assert compare_size((64, 48), (1241, 376)) == (64, 48)


def test_cli_help_states_the_default_rule(capsys):
    with pytest.raises(SystemExit):
        main(["vo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"{DEFAULT_TARGET_PIXELS} pixels" in text and f"multiples of {SIZE_MULTIPLE}" in text
    assert "--strict" in text


def test_non_4_3_folder_keeps_the_aspect_ratio(tmp_path):
    """A 2:1 image folder runs with default arguments; the processing camera keeps 2:1."""
    cam = PinholeCamera(262.5, 262.5, 159.5, 79.5, 320, 160)
    folder = tmp_path / "wide"
    (folder / "depth").mkdir(parents=True)
    for i, f in enumerate(_frames(cam, 8)):
        assert cv2.imwrite(str(folder / f"{i:04d}.png"), _rgb8(f))
        np.save(folder / "depth" / f"{i:04d}.npy", np.nan_to_num(f.depth).astype(np.float32))
    (folder / "camera.json").write_text(json.dumps(cam.to_dict()))
    out = tmp_path / "out"
    rc = main(["vo", "--dataset", "folder", str(folder), "--frontend", "depth",
               "--no-progress", "--out", str(out)])
    assert rc == 0
    report = json.loads((out / "report.json").read_text())
    w, h = report["run"]["resolution"]
    assert (w, h) == processing_size((320, 160))
    assert abs((w / h) / 2.0 - 1) < 0.03 and report["config"]["resolution"] is None
    assert report["run"]["n_frames"] == 8 and report["run"]["n_skipped"] == 0


# ------------------------------------------------------------- skipped frames
def test_reader_raises_frame_read_error(broken_seq):
    seq = open_dataset("7scenes", broken_seq, load_depth=False)
    with pytest.raises(FrameReadError) as info:
        seq[BAD]
    err = info.value
    assert isinstance(err, InputError) and err.index == BAD
    assert err.path.endswith(f"frame-{BAD:06d}.color.png") and "truncated" in err.reason
    assert err.timestamp == seq.timestamps[BAD]
    assert seq[BAD + 1].name            # the sequence still reads the next frame


def test_cli_skips_a_truncated_frame(broken_seq, tmp_path, caplog):
    out = tmp_path / "out"
    assert _vo(broken_seq, out) == 0
    assert any(f"frame-{BAD:06d}.color.png" in r.getMessage() for r in caplog.records
               if r.levelname == "WARNING")
    report = json.loads((out / "report.json").read_text())
    assert report["run"]["n_skipped"] == 1 and report["run"]["n_frames"] == N - 1
    (sk,) = report["skipped"]
    assert sk["index"] == BAD and sk["path"].endswith(f"frame-{BAD:06d}.color.png")
    assert report["status_counts"]["skipped"] == 1
    assert report["ate"]["n_skipped_excluded"] == 1
    assert report["ate"]["per-frame"]["n_associated"] <= N - 1
    stamps, status = read_status(out / "trajectory.status.txt")
    assert len(stamps) == N and status[BAD] == "skipped"
    assert status.count("skipped") == 1
    t_tum, _ = read_tum(out / "trajectory.txt")
    assert float(stamps[BAD]) not in set(np.round(t_tum, 6)) and len(t_tum) == N - 1
    loaded = Trajectory.load(out / "trajectory.txt")
    assert loaded.status[BAD] is FrameStatus.SKIPPED and not loaded.tracked[BAD]
    assert loaded.tracked[BAD + 1]      # the frame after the gap is tracked


def test_cli_strict_aborts_naming_the_file(broken_seq, tmp_path, capsys):
    out = tmp_path / "out"
    assert _vo(broken_seq, out, "--strict") == 2
    assert f"frame-{BAD:06d}.color.png" in capsys.readouterr().err
    assert not (out / "report.json").exists()


def test_library_strict_and_other_errors_propagate(broken_seq):
    with pytest.raises(FrameReadError, match=f"frame-{BAD:06d}"):
        run_dataset("7scenes", broken_seq, frames=f"0:{BAD + 2}",
                    config=VORunConfig(frontend="depth", progress=False, strict=True))
    seq = open_dataset("7scenes", broken_seq, frames="0:4")

    def bug(index, record):
        raise RuntimeError("a bug, not a bad file")

    seq._load = bug
    with pytest.raises(RuntimeError, match="a bug"):
        run_odometry(seq, VORunConfig(frontend="depth", progress=False))


def test_trajectory_with_skipped_round_trip(tmp_path):
    tr = Trajectory([0.0, 2.0, 3.0], np.tile(np.eye(4), (3, 1, 1)), ["keyframe", "ok", "lost"],
                    [True, False, False], columns={"inliers": [1, 2, 3]})
    out = tr.with_skipped([1.0, 4.0])
    assert list(out.timestamps) == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert [s.value for s in out.status] == ["keyframe", "skipped", "ok", "lost", "skipped"]
    assert list(out.tracked) == [True, False, True, False, False]
    assert list(out.segment) == [0, -1, 0, 0, -1] and out.columns["inliers"][1] == "nan"
    assert tr.with_skipped([]) is tr
    with pytest.raises(ValueError):
        tr.with_skipped([2.0])
    out.save(tmp_path / "t.txt")
    t_tum, _ = read_tum(tmp_path / "t.txt")
    assert list(t_tum) == [0.0, 2.0]       # the lost frame has no line (issue 53)
    assert [s.value for s in Trajectory.load(tmp_path / "t.txt").status] == \
        [s.value for s in out.status]


def test_missing_frame_file_is_skipped_and_still_a_file_not_found(broken_seq, tmp_path):
    import shutil

    folder = tmp_path / "seq-01"
    shutil.copytree(broken_seq, folder)
    seq = open_dataset("7scenes", folder, frames=f"0:{BAD + 3}")
    (folder / f"frame-{BAD - 1:06d}.color.png").unlink()     # vanished after the listing
    with pytest.raises(FileNotFoundError) as info:
        seq[BAD - 1]
    assert isinstance(info.value, FrameReadError) and info.value.index == BAD - 1
    run = run_odometry(seq, VORunConfig(frontend="depth", progress=False))
    assert [s.index for s in run.skipped] == [BAD - 1, BAD] and run.n_frames == BAD + 1
    assert run.status_counts()["skipped"] == 2
    traj = run.trajectory()
    assert [traj.status[i] for i in (BAD - 1, BAD)] == [FrameStatus.SKIPPED] * 2
