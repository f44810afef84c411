"""Bad input of the issue-25 sources through ``spgeo vo``: an unreadable video, a camera
that gives no frame, a ``--fov`` outside (10, 160) degrees and a KITTI folder without
``calib.txt`` each end with exit code 2, one ``spgeo vo: error:`` line on stderr naming
the file or value (OpenCV's and FFmpeg's own lines silenced: checked at the file
descriptor) and no output folder."""
import cv2
import numpy as np
import pytest

from spgeo.cli import main


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 3-frame 64x48 MJPG video."""
    path = tmp_path_factory.mktemp("video_in") / "ok.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for i in range(3):
        writer.write(np.full((48, 64, 3), 60 * i, np.uint8))
    writer.release()
    return path


def run_vo(capfd, tmp_path, *argv):
    out = tmp_path / "o"
    rc = main(["vo", *map(str, argv), "--no-progress", "--out", str(out)])
    _, err = capfd.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    return rc, lines, out


def check_error(rc, lines, out, fragment):
    assert rc == 2, lines
    assert len(lines) == 1 and lines[0].startswith("spgeo vo: error:"), lines
    assert fragment in lines[0]
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.name}.*"))         # no staging left behind


@pytest.mark.parametrize("content", [b"", b"this is not a video", b"\x00" * 4096],
                         ids=["empty", "text", "zeros"])
def test_unreadable_video(tmp_path, capfd, content):
    bad = tmp_path / "clip.mp4"
    bad.write_bytes(content)
    check_error(*run_vo(capfd, tmp_path, "--dataset", "video", bad), "clip.mp4")


def test_missing_video(tmp_path, capfd):
    check_error(*run_vo(capfd, tmp_path, "--dataset", "video", tmp_path / "gone.avi"),
                "gone.avi")


def test_camera_without_device(tmp_path, capfd):
    cap = cv2.VideoCapture(97)
    opened = cap.isOpened()
    cap.release()
    if opened:
        pytest.skip("camera 97 exists on this machine")
    capfd.readouterr()
    check_error(*run_vo(capfd, tmp_path, "--dataset", "camera", "97"), "camera 97")


@pytest.mark.parametrize("fov", ["5", "165", "175", "nan", "wide"])
def test_fov_outside_range(video, tmp_path, capfd, fov):
    check_error(*run_vo(capfd, tmp_path, "--dataset", "video", video, "--fov", fov),
                f"--fov {fov}")


def test_fov_and_intrinsics_together(video, tmp_path, capfd):
    check_error(*run_vo(capfd, tmp_path, "--dataset", "video", video, "--fov", "60",
                        "--intrinsics", "50,50,31.5,23.5"), "not both")


def test_kitti_without_calib(tmp_path, capfd):
    seq = tmp_path / "sequences" / "00"
    (seq / "image_0").mkdir(parents=True)
    cv2.imwrite(str(seq / "image_0" / "000000.png"), np.zeros((48, 64), np.uint8))
    check_error(*run_vo(capfd, tmp_path, "--dataset", "kitti", seq), str(seq / "calib.txt"))
