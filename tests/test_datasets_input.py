"""Inputs of issue 25: video files (``cv2.VideoWriter`` MJPG/.avi written from
synthetic frames), KITTI odometry and EuRoC MAV folders written in their layouts,
the shared KITTI clip laid out as a KITTI sequence, and calibration when there is
none (``--intrinsics`` / ``--fov`` / a guess, flagged in ``report.json``) or when
another tool wrote it (``--calibration``: COLMAP, ORB-SLAM, Kalibr; issue 53)."""
import json
import logging
import math

import cv2
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.cli import main
from spgeo.datasets import (DEFAULT_HFOV_DEG, CameraSpec, EuRoCSequence, FolderSequence,
                            KITTISequence, VideoSequence, camera_from_fov, guess_camera,
                            open_dataset)
from spgeo.geometry import invert_pose, rot_to_quat, so3_exp
from spgeo.tum_files import read_tum_arrays
from spgeo.validation import FOV_RANGE_DEG, InputError, check_intrinsics

W, H = 160, 120
CAM = synthetic.default_camera(W, H)
FPS = 10.0


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    return synthetic.render_frames(scene, CAM, synthetic.make_trajectory(20, 0), supersample=1)


def _bgr8(frame):
    rgb = np.clip(np.round(frame.image * 255), 0, 255).astype(np.uint8)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)


def write_video(path, frames, fps=FPS):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (W, H))
    assert writer.isOpened()
    for f in frames:
        writer.write(_bgr8(f))
    writer.release()
    return path


@pytest.fixture(scope="module")
def video(tmp_path_factory, frames):
    return write_video(tmp_path_factory.mktemp("video") / "clip.avi", frames)


# ------------------------------------------------------------------ calibration
def test_camera_from_fov_and_spec():
    cam = camera_from_fov(W, H, 90.0)
    assert cam.fx == pytest.approx(W / 2) and cam.fy == cam.fx
    assert (cam.cx, cam.cy) == ((W - 1) / 2, (H - 1) / 2)
    fov = math.degrees(2 * math.atan(W / 2 / CAM.fx))
    assert camera_from_fov(W, H, fov).fx == pytest.approx(CAM.fx)
    assert CameraSpec(intrinsics=(100, 101, 79.5, 59.5)).camera(W, H).fy == 101
    for bad in (5, 175, 10, 160, 165, 170, float("nan")):
        with pytest.raises(InputError, match="--fov"):
            CameraSpec(fov_deg=bad)
    # one range: a --fov just inside it gives intrinsics the intrinsics check accepts
    lo, hi = FOV_RANGE_DEG
    for fov in (lo + 0.01, hi - 0.01):
        cam = CameraSpec(fov_deg=fov).camera(W, H)
        check_intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, W, H)
    with pytest.raises(InputError, match="not both"):
        CameraSpec((1, 2, 3, 4), 60)
    assert CameraSpec.from_options(None, None) is None
    with pytest.raises(InputError, match="--fov 150 degrees does not fit a 1080x1920"):
        camera_from_fov(1080, 1920, 150)        # portrait: the vertical view is too wide


def test_guess_camera_default_and_exif(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        cam, method = guess_camera(W, H)
    assert cam == camera_from_fov(W, H, DEFAULT_HFOV_DEG) and "default" in method
    assert "intrinsics guessed" in caplog.text
    PIL = pytest.importorskip("PIL.Image")
    img = PIL.new("RGB", (W, H))
    exif = img.getexif()
    exif.get_ifd(0x8769)[0xA405] = 26                  # FocalLengthIn35mmFilm
    img.save(tmp_path / "p.jpg", exif=exif)
    cam, method = guess_camera(W, H, tmp_path / "p.jpg")
    assert "EXIF" in method
    assert cam.fx == pytest.approx(26 * math.hypot(W, H) / math.hypot(36, 24))


def test_folder_without_intrinsics_guesses(tmp_path, frames):
    for i, f in enumerate(frames[:3]):
        cv2.imwrite(str(tmp_path / f"{i}.png"), _bgr8(f))
    seq = FolderSequence(tmp_path)
    assert seq.intrinsics["source"] == "guessed"
    seq = open_dataset("folder", tmp_path, given_camera=CameraSpec(fov_deg=70))
    assert seq.intrinsics["source"] == "given" and seq.intrinsics["detail"] == "--fov 70"
    (tmp_path / "intrinsics.txt").write_text(f"{CAM.fx} {CAM.fy} {CAM.cx} {CAM.cy}\n")
    seq = FolderSequence(tmp_path)
    assert seq.intrinsics["source"] == "file" and seq.camera == CAM


def test_a_folder_of_two_image_sizes_is_refused_naming_them(tmp_path, frames, capsys):
    """Issue 53: a folder whose images have two sizes is refused (exit 2, both sizes
    named) instead of skipping the odd ones as "unreadable" and exiting 0."""
    for i, f in enumerate(frames[:6]):
        img = _bgr8(f) if i != 4 else cv2.resize(_bgr8(f), (W // 2, H // 2))
        cv2.imwrite(str(tmp_path / f"{i:04d}.png"), img)
    code = main(["vo", "--dataset", "folder", str(tmp_path), "--no-progress",
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "mixes image sizes" in err and "0004.png" in err
    assert "(60, 80, 3)" in err and f"({H}, {W}, 3)" in err


# ------------------------------------------------------------------ video
def test_video_reads_back(video, frames):
    seq = VideoSequence(video)
    assert len(seq) == len(frames) and seq.camera.size == (W, H)
    assert seq.intrinsics["source"] == "guessed"
    t = seq.timestamps
    assert np.all(np.diff(t) > 0)
    assert t[1] - t[0] == pytest.approx(1 / FPS, abs=1e-3)
    f = seq[3]
    assert f.image.dtype == np.float32 and f.image.shape == (H, W, 3)
    assert np.abs(f.image - frames[3].image).mean() < 0.05       # MJPG is lossy
    assert np.abs(seq[1].image - frames[3].image).mean() > np.abs(f.image - frames[3].image).mean()
    sel = open_dataset("video", video, frames="2:11:3")
    assert sel.frame_numbers == [2, 5, 8]
    assert np.allclose(sel.timestamps, t[[2, 5, 8]])
    imgs = [g.image for g in sel]                                 # in order, then backwards
    assert np.allclose(sel[0].image, imgs[0])
    given = open_dataset("video", video, given_camera=CameraSpec(intrinsics=(
        CAM.fx, CAM.fy, CAM.cx, CAM.cy)))
    assert given.camera == CAM and given.intrinsics["source"] == "given"


def test_video_frame_that_fails_to_decode_is_a_frame_read_error(video):
    from spgeo.validation import FrameReadError

    seq = VideoSequence(video)
    seq[0]

    class Broken:           # a capture whose next frame does not decode
        def __init__(self, cap):
            self.cap = cap

        def grab(self):
            return self.cap.grab()

        def retrieve(self):
            return False, None

        def release(self):
            self.cap.release()

    seq._cap = Broken(seq._cap)
    with pytest.raises(FrameReadError, match="clip.avi"):
        seq[1]


# ------------------------------------------------------------------ KITTI
def _kitti_calib(baseline=0.54):
    P = np.zeros((4, 3, 4))
    for k in range(4):
        P[k, :, :3] = CAM.K
        P[k, :, 3] = CAM.K @ np.array([-baseline * (k % 2) + 0.06 * (k >= 2), 0.0, 0.0])
    return P


def write_kitti(root, frames, folder="image_0", with_poses=True):
    seq = root / "sequences" / "03"
    (seq / folder).mkdir(parents=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(seq / folder / f"{i:06d}.png"), _bgr8(f))
    P = _kitti_calib()
    (seq / "calib.txt").write_text("".join(
        f"P{k}: " + " ".join(f"{v:.12e}" for v in P[k].ravel()) + "\n" for k in range(4))
        + "Tr: " + " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]) + "\n")
    (seq / "times.txt").write_text("".join(f"{0.1037 * i:.6e}\n" for i in range(len(frames))))
    if with_poses:
        (root / "poses").mkdir()
        (root / "poses" / "03.txt").write_text("".join(
            " ".join(f"{v:.12e}" for v in f.T_world_cam[:3].ravel()) + "\n" for f in frames))
    return seq


def test_kitti_reads_back(tmp_path, frames):
    seq_dir = write_kitti(tmp_path, frames[:6])
    seq = open_dataset("kitti", seq_dir, frames="1:6:2")
    assert isinstance(seq, KITTISequence) and seq.name == "03"
    assert seq.camera == CAM and seq.intrinsics["source"] == "file"
    assert "P0" in seq.intrinsics["detail"]
    assert seq.frame_numbers == [1, 3, 5]
    assert np.allclose(seq.timestamps, [0.1037, 0.3111, 0.5185])
    f = seq[1]
    assert np.allclose(f.T_world_cam, frames[3].T_world_cam, atol=1e-9)
    assert np.abs(f.image - frames[3].image).max() < 1 / 255 + 1e-6


def test_kitti_colour_camera_pose_and_no_poses(tmp_path, frames):
    seq_dir = write_kitti(tmp_path, frames[:3], folder="image_2")
    seq = KITTISequence(seq_dir)
    assert "P2" in seq.intrinsics["detail"]
    T_cam0_cam2 = np.eye(4)
    T_cam0_cam2[0, 3] = -0.06           # P2 = K [I | t], t = (0.06, 0, 0): camera 2 at x = -0.06
    assert np.allclose(seq[2].T_world_cam, frames[2].T_world_cam @ T_cam0_cam2, atol=1e-9)
    (tmp_path / "poses" / "03.txt").unlink()
    assert KITTISequence(seq_dir).ground_truth() == [None] * 3


def test_kitti_left_folder_and_unlabelled_calib_lines(tmp_path, frames):
    """``image_l`` (the grey left camera, P0) with calib lines without ``Pk:`` (the
    layout of this project's shared clip); an unknown ``image_dir`` is refused
    naming the choices, a sequence without an image folder names those looked for."""
    seq_dir = write_kitti(tmp_path, frames[:3], folder="image_l")
    calib = seq_dir / "calib.txt"
    calib.write_text("".join(line.split(":", 1)[1].lstrip() + "\n"
                             for line in calib.read_text().splitlines() if line.startswith("P")))
    seq = open_dataset("kitti", seq_dir)
    assert seq.camera == CAM and "P0" in seq.intrinsics["detail"] and len(seq) == 3
    assert np.allclose(seq[2].T_world_cam, frames[2].T_world_cam, atol=1e-9)
    with pytest.raises(ValueError, match="image_r"):
        KITTISequence(seq_dir, image_dir="left")
    (seq_dir / "image_l").rename(seq_dir / "images")
    with pytest.raises(FileNotFoundError, match="image_0, image_2, image_l"):
        KITTISequence(seq_dir)


def test_7scenes_frame_without_its_colour_image_is_skipped_and_said(tmp_path, frames, caplog):
    """Issue 53: a 7-Scenes frame whose colour image is missing (its pose file is there)
    is no longer silently absent: the reader warns and the VO run records it as skipped."""
    from layouts import write_7scenes

    from spgeo.apps.vo_run import VORunConfig, run_odometry
    from spgeo.validation import FrameFileMissing
    from spgeo.vo import OdometryConfig

    K = np.diag([4.0, 4.0, 1.0]) @ CAM.K      # the 640x480 of a 7-Scenes folder
    seq_dir = write_7scenes(tmp_path / "seq-01", frames[:8], K)
    (seq_dir / "frame-000003.color.png").unlink()
    with caplog.at_level(logging.WARNING):
        seq = open_dataset("7scenes", seq_dir)
    assert "no colour image (frame numbers [3])" in caplog.text
    assert seq.frame_numbers == list(range(8))
    with pytest.raises(FrameFileMissing, match="frame-000003.color.png"):
        seq[3]
    run = run_odometry(seq, VORunConfig(progress=False,
                                        odometry=OdometryConfig(resolution=(W, H))))
    run.odometry.close()
    assert [s.index for s in run.skipped] == [3] and run.n_frames == 7


def test_kitti_without_calib_names_the_file(tmp_path, frames):
    seq_dir = write_kitti(tmp_path, frames[:2])
    (seq_dir / "calib.txt").unlink()
    with pytest.raises(FileNotFoundError, match="calib.txt"):
        KITTISequence(seq_dir)


def test_shared_kitti_clip_as_a_sequence(shared_data, tmp_path):
    clip = shared_data / "kitti_odometry_clip_51"
    seq_dir = tmp_path / "sequences" / "00"
    seq_dir.mkdir(parents=True)
    (tmp_path / "poses").mkdir()
    (seq_dir / "image_0").symlink_to(clip / "image_l", target_is_directory=True)
    (seq_dir / "calib.txt").symlink_to(clip / "calib.txt")
    (tmp_path / "poses" / "00.txt").symlink_to(clip / "poses.txt")
    seq = open_dataset("kitti", seq_dir)
    assert len(seq) == 51
    cam = seq.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((718.856, 718.856, 607.1928,
                                                               185.2157))
    assert cam.size == (1241, 376)
    gt = seq.ground_truth()
    assert all(T is not None for T in gt) and np.allclose(gt[0], np.eye(4), atol=1e-6)
    row = np.array(next(line for line in (clip / "poses.txt").read_text().splitlines()[50:]
                        ).split(), float).reshape(3, 4)
    assert np.allclose(gt[50][:3], row, atol=1e-4)
    assert seq.timestamps[1] == pytest.approx(0.1)
    f = seq[10]
    assert f.image.shape == (376, 1241, 3) and np.allclose(f.T_world_cam, gt[10])
    as_is = open_dataset("kitti", clip)          # the clip's own layout: image_l, poses.txt
    assert len(as_is) == 51 and as_is.camera == cam
    assert np.allclose(as_is[10].image, f.image) and np.allclose(as_is.ground_truth()[50], gt[50])


# ------------------------------------------------------------------ EuRoC
T_BS = np.eye(4)
T_BS[:3, :3] = so3_exp(np.array([0.02, -0.03, 1.55]))
T_BS[:3, 3] = [-0.0216, -0.0647, 0.0098]
DIST = (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
T0_NS = 1403636579763555584
STEP_NS = 50_000_000


def write_euroc(root, frames):
    cam0 = root / "mav0" / "cam0"
    (cam0 / "data").mkdir(parents=True)
    lines = ["#timestamp [ns],filename"]
    for i, f in enumerate(frames):
        ns = T0_NS + i * STEP_NS
        cv2.imwrite(str(cam0 / "data" / f"{ns}.png"), cv2.cvtColor(_bgr8(f), cv2.COLOR_BGR2GRAY))
        lines.append(f"{ns},{ns}.png")
    (cam0 / "data.csv").write_text("\n".join(lines) + "\n")
    tbs = ",\n         ".join(", ".join(f"{v:.15g}" for v in row) for row in T_BS)
    (cam0 / "sensor.yaml").write_text(f"""# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [{tbs}]

# Camera specific definitions.
rate_hz: 20
resolution: [{W}, {H}]
camera_model: pinhole
intrinsics: [{CAM.fx}, {CAM.fy}, {CAM.cx}, {CAM.cy}] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [{', '.join(map(str, DIST))}]
""")
    gt = root / "mav0" / "state_groundtruth_estimate0"
    gt.mkdir()
    rows = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
            "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
            "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
            "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"]
    for i, f in enumerate(frames):
        T_world_body = f.T_world_cam @ invert_pose(T_BS)
        qx, qy, qz, qw = rot_to_quat(T_world_body[:3, :3])
        for off in (-2_000_000, 1_000_000):       # 200 Hz-like rows beside each frame
            T = T_world_body.copy()
            T[:3, 3] += off * 1e-9      # a small offset the nearest row must not take
            ns = T0_NS + i * STEP_NS + off
            vals = [*T[:3, 3], qw, qx, qy, qz] + [0.0] * 9
            rows.append(f"{ns}," + ",".join(f"{v:.15g}" for v in vals))
    (gt / "data.csv").write_text("\n".join(rows) + "\n")
    return root


def test_euroc_reads_back(tmp_path, frames):
    root = write_euroc(tmp_path / "MH_01_easy", frames[:4])
    seq = open_dataset("euroc", root)
    assert isinstance(seq, EuRoCSequence) and seq.name == "MH_01_easy" and len(seq) == 4
    raw = seq.raw_camera
    assert (raw.fx, raw.fy, raw.cx, raw.cy) == pytest.approx((CAM.fx, CAM.fy, CAM.cx, CAM.cy))
    assert raw.distortion == pytest.approx(DIST) and seq.camera.distortion is None
    assert seq.intrinsics["source"] == "file" and seq.intrinsics["distortion"] is not None
    assert np.allclose(seq.timestamps, (T0_NS + np.arange(4) * STEP_NS) * 1e-9)
    shift = np.eye(4)       # the nearest row (+1 ms) has its body moved by 1 mm along each axis
    shift[:3, 3] = 1e-3
    for i, T in enumerate(seq.ground_truth()):
        assert np.allclose(T, shift @ frames[i].T_world_cam, atol=1e-9)
    f = open_dataset("euroc", root / "mav0", undistort=False, frames="2")[0]
    assert f.image.shape == (H, W, 3) and f.camera.distortion == pytest.approx(DIST)
    assert f.name == str(T0_NS + 2 * STEP_NS)


def test_euroc_ground_truth_too_far_is_none(tmp_path, frames):
    root = write_euroc(tmp_path / "seq", frames[:2])
    seq = EuRoCSequence(root, max_pose_difference=1e-4)
    assert seq.ground_truth() == [None, None]


# ------------------------------------------------------------------ the command
@pytest.mark.slow
def test_vo_on_a_video_with_fov(video, tmp_path, capsys):
    fov = math.degrees(2 * math.atan(W / 2 / CAM.fx))
    out = tmp_path / "o"
    rc = main(["vo", "--dataset", "video", str(video), "--fov", f"{fov:.4f}",
               "--resolution", f"{W}x{H}", "--no-progress", "--out", str(out)])
    assert rc in (0, 3)
    report = json.loads((out / "report.json").read_text())
    intr = report["intrinsics"]
    assert intr["source"] == "given" and intr["fx"] == pytest.approx(CAM.fx, rel=1e-3)
    assert report["run"]["n_frames"] == 20
    assert len((out / "trajectory.txt").read_text().split("\n")) >= 20


# ------------------------------------------------------------------ live camera
class FakeDevice:
    """A "camera" playing the video; ``read`` raises KeyboardInterrupt (Ctrl-C) at
    read number ``interrupt_at`` when set."""

    def __init__(self, video, interrupt_at=None):
        self.cap = cv2.VideoCapture(str(video))
        self.reads, self.interrupt_at, self.released = 0, interrupt_at, False

    def read(self):
        self.reads += 1
        if self.interrupt_at is not None and self.reads >= self.interrupt_at:
            raise KeyboardInterrupt
        return self.cap.read()

    def release(self):
        self.released = True
        self.cap.release()


def test_camera_stream_selection(video, monkeypatch):
    import spgeo.datasets.video as video_mod

    devices = []
    monkeypatch.setattr(video_mod, "open_capture",
                        lambda index: devices.append(FakeDevice(video)) or devices[-1])
    stream = open_dataset("camera", "0", frames="2:8:2")
    assert not hasattr(stream, "__len__") and stream.intrinsics["source"] == "guessed"
    got = list(stream)
    assert [f.name for f in got] == ["000002", "000004", "000006"]
    assert all(b.timestamp > a.timestamp for a, b in zip(got, got[1:]))
    assert got[0].image.shape == (H, W, 3) and devices[0].released
    with pytest.raises(InputError, match="A:B"):
        open_dataset("camera", "0", frames=[1, 2])


@pytest.mark.slow
def test_vo_on_a_camera_stops_on_ctrl_c_with_everything_written(video, tmp_path, monkeypatch,
                                                                 capsys):
    import spgeo.datasets.video as video_mod

    monkeypatch.setattr(video_mod, "open_capture", lambda index: FakeDevice(video, 12))
    out = tmp_path / "o"
    rc = main(["vo", "--dataset", "camera", "0", "--intrinsics",
               f"{CAM.fx},{CAM.fy},{CAM.cx},{CAM.cy}", "--resolution", f"{W}x{H}",
               "--no-progress", "--out", str(out)])
    assert rc == 130
    assert "interrupted" in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    n = report["run"]["n_frames"]
    # the capture ring (issue 41) drops frames a device gives faster than the VO takes them
    assert report["run"]["status"] == "interrupted"
    assert n + report["capture"]["dropped"] == report["capture"]["arrived"] == 11
    assert report["intrinsics"]["source"] == "given"
    assert len((out / "trajectory.txt").read_text().strip().splitlines()) >= n


# ------------------------------------------------------------------ calibration files
COLMAP_CASES = {   # model: (params in COLMAP's pixels, fx, fy, OpenCV distortion)
    "SIMPLE_PINHOLE": ([100.0, 80.0, 60.0], 100.0, 100.0, None),
    "PINHOLE": ([100.0, 101.0, 80.0, 60.0], 100.0, 101.0, None),
    "SIMPLE_RADIAL": ([100.0, 80.0, 60.0, -0.1], 100.0, 100.0, (-0.1, 0.0, 0.0, 0.0)),
    "RADIAL": ([100.0, 80.0, 60.0, -0.1, 0.02], 100.0, 100.0, (-0.1, 0.02, 0.0, 0.0)),
    "OPENCV": ([100.0, 101.0, 80.0, 60.0, -0.1, 0.02, 0.001, -0.002], 100.0, 101.0,
               (-0.1, 0.02, 0.001, -0.002)),
    "FULL_OPENCV": ([100.0, 101.0, 80.0, 60.0, -0.1, 0.02, 0.001, -0.002, 0.003, 0.01, 0.002,
                     0.001], 100.0, 101.0,
                    (-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, 0.002, 0.001)),
}


def write_colmap_cameras(path, *cameras):
    """``cameras.txt`` of ``(id, model, params)`` tuples, at the W x H size."""
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [f"{i} {model} {W} {H} " + " ".join(map(repr, params))
              for i, model, params in cameras]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("model", sorted(COLMAP_CASES))
def test_colmap_cameras_txt_of_each_model(tmp_path, model):
    """Each COLMAP model reads to its OpenCV camera, the principal point shifted by
    -0.5 (COLMAP: the top-left pixel's centre at (0.5, 0.5)); pycolmap's own
    projection of the model agrees with spgeo's camera plus OpenCV's distortion."""
    from spgeo.datasets import read_calibration

    params, fx, fy, dist = COLMAP_CASES[model]
    cal = read_calibration(write_colmap_cameras(tmp_path / "cameras.txt", (7, model, params)))
    cam = cal.camera()
    cx, cy = (params[2], params[3]) if model in ("PINHOLE", "OPENCV", "FULL_OPENCV") else \
        (params[1], params[2])
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (fx, fy, cx - 0.5, cy - 0.5)
    assert cam.size == (W, H) and cam.distortion == (None if dist is None else pytest.approx(dist))
    assert cal.describe() == f"--calibration {tmp_path / 'cameras.txt'}: COLMAP {model} camera 7"
    pycolmap = pytest.importorskip("pycolmap")
    pts = np.array([[0.1, 0.2, 1.0], [-0.3, 0.1, 2.0], [0.4, -0.3, 1.5]])
    ours, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K,
                                np.zeros(4) if cam.distortion is None else
                                np.asarray(cam.distortion))
    theirs = pycolmap.Camera(model=model, width=W, height=H, params=params).img_from_cam(pts)
    assert np.allclose(ours.reshape(-1, 2) + 0.5, theirs, atol=1e-6)


def test_colmap_export_reads_back_equal(tmp_path):
    """A camera written by spgeo's COLMAP export (+0.5) reads back equal."""
    pycolmap = pytest.importorskip("pycolmap")
    from spgeo.camera import PinholeCamera
    from spgeo.datasets import read_calibration
    from spgeo.twoview.backends import colmap_camera

    cam = PinholeCamera(100.5, 101.25, 79.25, 59.75, W, H)
    rec = pycolmap.Reconstruction()
    rec.add_camera(colmap_camera(cam))
    rec.write_text(str(tmp_path))
    assert read_calibration(tmp_path / "cameras.txt").camera() == cam


def test_colmap_several_cameras(tmp_path):
    """Identical cameras count as one; different ones need FILE:ID, else the
    error lists the IDs."""
    from spgeo.datasets import read_calibration

    same = write_colmap_cameras(tmp_path / "same.txt", (1, "PINHOLE", [100, 100, 80, 60]),
                                (2, "PINHOLE", [100, 100, 80, 60]))
    assert read_calibration(same).camera().fx == 100
    two = write_colmap_cameras(tmp_path / "two.txt", (1, "PINHOLE", [100, 100, 80, 60]),
                               (2, "SIMPLE_PINHOLE", [120, 80, 60]))
    with pytest.raises(InputError, match=r"2 different cameras \(1, 2\).*two.txt:ID"):
        read_calibration(two)
    assert read_calibration(f"{two}:2").camera().fx == 120
    with pytest.raises(InputError, match="no camera '3'; its cameras: 1, 2"):
        read_calibration(f"{two}:3")


ORB_OLD = """%YAML:1.0
# ORB-SLAM2 TUM1.yaml
Camera.fx: 517.306408
Camera.fy: 516.469215
Camera.cx: 318.643040
Camera.cy: 255.313989

Camera.k1: 0.262383
Camera.k2: -0.953104
Camera.p1: -0.005358
Camera.p2: 0.002628
Camera.k3: 1.163314

Camera.fps: 30.0
Camera.RGB: 1
ORBextractor.nFeatures: 1000
"""

ORB_V1 = """%YAML:1.0
File.version: "1.0"
Camera.type: "PinHole"
Camera1.fx: 458.654
Camera1.fy: 457.296
Camera1.cx: 367.215
Camera1.cy: 248.375
Camera1.k1: -0.28340811
Camera1.k2: 0.07395907
Camera1.p1: 0.00019359
Camera1.p2: 1.76187114e-05
Camera.width: 752
Camera.height: 480
Camera.fps: 20
"""

KALIBR = """cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [0.999997, 0.002312, 0.000376, -0.110074]
  - [-0.002315, 0.999898, 0.014089, 0.000399]
  - [-0.000344, -0.014090, 0.999901, -0.000853]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.28368365, 0.07451284, -0.00010473, -3.5559e-05]
  distortion_model: radtan
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""


def test_orbslam_settings_old_and_v1(tmp_path):
    """ORB-SLAM2's ``Camera.*`` (no size: the images') and ORB-SLAM3 1.0's
    ``Camera1.*`` with ``Camera.width`` / ``height``, taken as they are."""
    from spgeo.datasets import read_calibration

    (tmp_path / "old.yaml").write_text(ORB_OLD)
    old = read_calibration(tmp_path / "old.yaml")
    cam = old.camera(640, 480)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.size) == (517.306408, 516.469215, 318.64304,
                                                         255.313989, (640, 480))
    assert cam.distortion == pytest.approx((0.262383, -0.953104, -0.005358, 0.002628, 1.163314))
    with pytest.raises(InputError, match="gives no image size"):
        old.camera()
    (tmp_path / "v1.yaml").write_text(ORB_V1)
    cam = read_calibration(tmp_path / "v1.yaml").camera()
    assert (cam.fx, cam.cy, cam.size) == (458.654, 248.375, (752, 480))
    assert cam.distortion == pytest.approx((-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05))
    (tmp_path / "fish.yaml").write_text(ORB_V1.replace('"PinHole"', '"KannalaBrandt8"'))
    with pytest.raises(InputError, match="KannalaBrandt8.*supported: PinHole, Rectified"):
        read_calibration(tmp_path / "fish.yaml")


def test_kalibr_camchain_and_euroc_sensor_yaml(tmp_path, frames):
    """A Kalibr camchain's cameras (cam0 / cam1 picked by ID), and EuRoC's
    one-camera sensor.yaml read as the EuRoC reader reads it."""
    from spgeo.datasets import read_calibration

    path = tmp_path / "camchain.yaml"
    path.write_text(KALIBR)
    with pytest.raises(InputError, match=r"2 different cameras \(cam0, cam1\)"):
        read_calibration(path)
    cam = read_calibration(f"{path}:cam1").camera()
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.size) == (457.587, 456.134, 379.999, 255.238,
                                                         (752, 480))
    assert cam.distortion == pytest.approx((-0.28368365, 0.07451284, -0.00010473, -3.5559e-05))
    assert "Kalibr pinhole-radtan camera cam0" in read_calibration(f"{path}:cam0").describe()
    root = write_euroc(tmp_path / "seq", frames[:1])
    sensor = read_calibration(root / "mav0" / "cam0" / "sensor.yaml").camera()
    assert sensor == EuRoCSequence(root, undistort=False).raw_camera


@pytest.mark.parametrize("text, named", [
    ("1 OPENCV_FISHEYE 160 120 100 100 80 60 0 0 0 0\n", "OPENCV_FISHEYE is not read; "
     "supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV"),
    ("1 OPENCV 160 120 100 100 80 60\n", "OPENCV camera has 8 parameters, got 4"),
    (KALIBR.replace("radtan", "equidistant"), "equidistant is not read; supported: radtan"),
    (KALIBR.replace("pinhole", "omni"), "camera_model omni is not read; supported: pinhole"),
    ("fx: 100\nfy: 100\n", "not a calibration file spgeo reads .COLMAP cameras.txt, "
     "ORB-SLAM settings YAML or Kalibr camchain YAML"),
])
def test_unsupported_calibration_refused_naming_it(tmp_path, text, named):
    from spgeo.datasets import read_calibration

    (tmp_path / "cal.txt").write_text(text)
    with pytest.raises(InputError, match=named) as err:
        read_calibration(tmp_path / "cal.txt")
    assert str(tmp_path / "cal.txt") in str(err.value)


def _distorted_folder(tmp_path, frames, n=3):
    for i, f in enumerate(frames[:n]):
        cv2.imwrite(str(tmp_path / f"{i:04d}.png"), _bgr8(f))
    params = [CAM.fx, CAM.fy, CAM.cx + 0.5, CAM.cy + 0.5, -0.2, 0.05, 0.001, 0.0]
    return write_colmap_cameras(tmp_path.parent / "cameras.txt", (1, "OPENCV", params))


def test_calibration_file_camera_undistorts_a_folder(tmp_path, frames):
    """A folder given a distorted calibration file: the stored camera keeps the
    distortion, the frames are undistorted (their camera has none), and
    ``intrinsics`` names the file and model; a file of another size is refused
    naming both sizes."""
    (tmp_path / "f").mkdir()
    cameras = _distorted_folder(tmp_path / "f", frames)
    seq = open_dataset("folder", tmp_path / "f", given_camera=CameraSpec.from_options(
        calibration=cameras))
    assert seq.raw_camera.distortion == pytest.approx((-0.2, 0.05, 0.001, 0.0))
    assert seq.camera == CAM and seq.camera.distortion is None
    raw = cv2.cvtColor(cv2.imread(str(tmp_path / "f" / "0001.png")), cv2.COLOR_BGR2RGB) / 255.0
    image = seq[1].image
    assert np.abs(image - raw).mean() > 0.01
    assert np.allclose(image, np.clip(seq.raw_camera.undistort_image(raw.astype(np.float32)),
                                      0, 1), atol=1e-5)
    intr = seq.intrinsics
    assert intr["source"] == "given" and intr["detail"] == (
        f"--calibration {cameras}: COLMAP OPENCV camera 1")
    assert intr["cx"] == CAM.cx and intr["distortion"] == pytest.approx([-0.2, 0.05, 0.001, 0.0])
    small = write_colmap_cameras(tmp_path / "small.txt", (1, "PINHOLE", [50, 50, 40, 30]))
    small.write_text(small.read_text().replace(f" {W} {H} ", f" {W // 2} {H // 2} "))
    with pytest.raises(InputError, match=f"is for {W // 2}x{H // 2} images, the images are "
                                         f"{W}x{H}") as err:
        open_dataset("folder", tmp_path / "f", given_camera=CameraSpec.from_options(
            calibration=small))
    assert str(small) in str(err.value)


def test_calibration_file_undistorts_a_reader_without_an_undistort_option(shared_data):
    """ICL-NUIM's reader has no ``undistort`` option: a distorted calibration
    file still undistorts its frames (never a distorted camera left in them)."""
    from spgeo.datasets import Calibration

    cal = Calibration(481.2, 480.0, 319.5, 239.5, (-0.1, 0.0, 0.0, 0.0), (640, 480),
                      shared_data / "x.txt", "COLMAP", "SIMPLE_RADIAL", "1")
    seq = open_dataset("icl", shared_data / "icl_nuim_lr_5", frames="1:2")
    plain = seq[0]
    seq.set_camera(CameraSpec(calibration=cal), cal.describe())
    frame = seq[0]
    assert frame.camera.distortion is None and seq.raw_camera.distortion is not None
    assert np.abs(frame.image - plain.image).mean() > 0.005
    assert not np.allclose(frame.depth, plain.depth, equal_nan=True)     # depth alike


@pytest.mark.slow
def test_vo_with_calibration_file(tmp_path, frames):
    """``spgeo vo --calibration FILE``: report.json's intrinsics say "given" with the
    file, the model and its distortion."""
    (tmp_path / "f").mkdir()
    cameras = _distorted_folder(tmp_path / "f", frames, n=4)
    out = tmp_path / "out"
    rc = main(["vo", "--dataset", "folder", str(tmp_path / "f"), "--calibration", str(cameras),
               "--resolution", f"{W}x{H}", "--no-progress", "--out", str(out)])
    assert rc in (0, 3)
    intr = json.loads((out / "report.json").read_text())["intrinsics"]
    assert intr["source"] == "given" and "COLMAP OPENCV" in intr["detail"]
    assert (intr["fx"], intr["cx"], intr["width"]) == (CAM.fx, CAM.cx, W)
    assert intr["distortion"] == pytest.approx([-0.2, 0.05, 0.001, 0.0])


@pytest.mark.parametrize("extra, said", [
    (["--fov", "60"], "--fov and --calibration given"),
    (["--resolution", f"{W}x{H}"], f"is for {W}x{H // 2} images, the images are {W}x{H}"),
])
def test_vo_calibration_file_refused_before_the_run(tmp_path, frames, capsys, extra, said):
    """Exit 2 naming the problem: --calibration with --fov, a file of another size."""
    (tmp_path / "f").mkdir()
    cameras = _distorted_folder(tmp_path / "f", frames, n=2)
    if "--fov" not in extra:
        cameras.write_text(cameras.read_text().replace(f" {W} {H} ", f" {W} {H // 2} "))
    rc = main(["vo", "--dataset", "folder", str(tmp_path / "f"), "--calibration", str(cameras),
               "--no-progress", "--out", str(tmp_path / "o")] + extra)
    err = capsys.readouterr().err
    assert rc == 2 and said in err and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_vo_on_a_folder_of_timestamp_names_with_a_depth_scale(tmp_path, frames):
    """Issue 53: a folder of EuRoC-style nanosecond names and TUM-scale depth PNGs
    (``--depth-scale 5000``): trajectory.txt carries the names' times and, with the
    depth front-end, metric positions (the ground truth's path length)."""
    folder = tmp_path / "cam0"
    (folder / "depth").mkdir(parents=True)
    t0 = 1403636579763555584
    names = [str(t0 + i * 50_000_000) for i in range(8)]
    for name, f in zip(names, frames):
        assert cv2.imwrite(str(folder / f"{name}.png"), _bgr8(f))
        raw = np.clip(np.round(np.nan_to_num(f.depth) * 5000), 0, 65535).astype(np.uint16)
        assert cv2.imwrite(str(folder / "depth" / f"{name}.png"), raw)
    (folder / "intrinsics.txt").write_text(f"{CAM.fx} {CAM.fy} {CAM.cx} {CAM.cy}\n")
    out = tmp_path / "out"
    assert main(["vo", "--dataset", "folder", str(folder), "--frontend", "depth",
                 "--depth-scale", "5000", "--no-progress", "--out", str(out)]) == 0
    stamps, poses = read_tum_arrays(out / "trajectory.txt")
    assert len(stamps) == 8
    np.testing.assert_allclose(stamps, [int(n) * 1e-9 for n in names], rtol=0, atol=1e-6)
    gt = [f.T_world_cam for f in frames[:8]]
    ratio = (np.linalg.norm(poses[-1][:3, 3] - poses[0][:3, 3])
             / np.linalg.norm(gt[-1][:3, 3] - gt[0][:3, 3]))
    assert 0.9 < ratio < 1.1, ratio
