"""Tests of spgeo.datasets: the bundled TUM sample (always available), the
shared real samples (skipped when ../shared/data is absent), bad input and
the folder reader."""
from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.datasets import (ICL_CAMERA, FolderSequence, ICLSequence, SevenScenesSequence,
                            TUMSequence, associate, bundled_tum_path, interpolate_poses,
                            load_bundled_tum, open_dataset, parse_frame_range, photometric_error,
                            read_tum_groundtruth, select_frames, tum_camera, warp_image)
from spgeo.datasets.files import stamp_from_name, stamped_files
from spgeo.datasets.icl import icl_pose_to_opencv, read_icl_poses
from spgeo.datasets.tum import detect_tum_calibration
from spgeo.frame import Frame
from spgeo.geometry import pose_from_tum, relative_pose, rotation_angle_deg
from spgeo.validation import InputError


# --------------------------------------------------------------------- helpers
def shared_data_dir() -> Path:
    env = os.environ.get("SPGEO_SHARED_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared(name: str) -> Path:
    path = shared_data_dir() / name
    if not path.is_dir():
        pytest.skip(f"shared sample data not available: {path}")
    return path


def rel(fa: Frame, fb: Frame) -> np.ndarray:
    """T_b_a: maps points of frame a's camera into frame b's camera."""
    return relative_pose(fb.T_world_cam, fa.T_world_cam)


def err(fa: Frame, fb: Frame, T_b_a: np.ndarray, depth=None) -> float:
    e, frac = photometric_error(fa.image, fb.image, fa.depth if depth is None else depth,
                                fa.camera, T_b_a)
    assert frac > 0.1, f"too few valid pixels ({frac:.2f})"
    return e


@pytest.fixture(scope="module")
def tum():
    return load_bundled_tum()


@pytest.fixture(scope="module")
def tum_frames(tum):
    return tum[:]


# ---------------------------------------------------------------- frame ranges
def test_parse_frame_range():
    assert parse_frame_range("10:20") == slice(10, 20, None)
    assert parse_frame_range("0:100:5") == slice(0, 100, 5)
    assert parse_frame_range(":50") == slice(None, 50, None)
    assert parse_frame_range("100:") == slice(100, None, None)
    assert parse_frame_range("::2") == slice(None, None, 2)
    assert parse_frame_range(" 7 ") == slice(7, 8, None)
    for bad in ["", "a:b", "1:2:0", "1:2:3:4", "-1:5", "1.5:3"]:
        with pytest.raises(ValueError):
            parse_frame_range(bad)


def test_select_frames_by_number():
    numbers = [100, 101, 102, 103, 104, 105, 110]
    assert select_frames(numbers, None) == list(range(7))
    assert select_frames(numbers, "101:105") == [1, 2, 3, 4]
    assert select_frames(numbers, "100:200:5") == [0, 5, 6]
    assert select_frames(numbers, slice(None, None, 2)) == [0, 2, 4, 6]  # relative to first number
    assert select_frames(numbers, slice(101, None, 2)) == [1, 3, 5]
    assert select_frames(numbers, range(102, 104)) == [2, 3]
    assert select_frames(numbers, [110, 100]) == [6, 0]
    with pytest.raises(ValueError, match="unknown frame numbers"):
        select_frames(numbers, [7])
    with pytest.raises(ValueError, match="selects no frames"):
        select_frames(numbers, "200:300")


def test_a_selection_past_the_last_frame_is_said(caplog):
    """Issue 53: ``--frames 250:400`` on a clip ending at 299 selects 50 frames, with a
    warning; a selection within the clip says nothing."""
    import logging

    numbers = list(range(300))
    with caplog.at_level(logging.WARNING):
        assert len(select_frames(numbers, "0:300")) == 300
        assert not caplog.records
        assert len(select_frames(numbers, "250:400")) == 50
    assert "past the last frame (299): 50 frames" in caplog.text


# ---------------------------------------------------------------- bundled TUM
def test_bundled_sample_files():
    root = bundled_tum_path()
    assert (root / "ATTRIBUTION.md").is_file()
    assert len(list((root / "rgb").glob("*.png"))) == 9
    assert len(list((root / "depth").glob("*.png"))) == 9
    lines = (root / "groundtruth.txt").read_text().splitlines()
    assert all(line.startswith("#") for line in lines[:3])
    stamps, _ = read_tum_groundtruth(root / "groundtruth.txt")
    # trimmed to the frames' span +- ~1 s, still covering every frame
    assert 150 < len(stamps) < 300
    assert stamps[0] < 1305031453.359684 - 0.9 and stamps[-1] > 1305031453.627706 + 0.9


def test_bundled_tum_basics(tum, tum_frames):
    assert len(tum) == 9 and tum.name == "tum_fr1_desk_9"
    assert tum.raw_camera == tum_camera("fr1")
    assert tum.camera.distortion is None and tum.camera.fx == pytest.approx(517.3)
    assert tum.frame_numbers == list(range(9))
    assert np.all(np.diff(tum.timestamps) > 0)
    f = tum_frames[0]
    assert f.image.dtype == np.float32 and f.image.shape == (480, 640, 3)
    assert 0.0 <= f.image.min() and f.image.max() <= 1.0
    assert f.depth.dtype == np.float32 and f.depth.shape == (480, 640)
    assert np.isnan(f.depth).any() and np.nanmin(f.depth) > 0 and np.nanmax(f.depth) < 10
    assert f.camera == tum.camera
    assert f.name == "1305031453.359684" and f.timestamp == pytest.approx(1305031453.359684)
    assert all(fr.T_world_cam is not None for fr in tum_frames)
    # sequence protocol
    assert tum[-1].name == tum_frames[8].name
    assert [fr.name for fr in tum[2:5]] == [fr.name for fr in tum_frames[2:5]]
    assert [fr.name for fr in tum] == [fr.name for fr in tum_frames]
    with pytest.raises(IndexError):
        tum[9]
    with pytest.raises(TypeError):
        tum["0"]


def test_tum_association(tum_frames):
    rgb_t = np.array([f.timestamp for f in tum_frames])
    depth_t = np.array([f.meta["depth_timestamp"] for f in tum_frames])
    assert np.all(np.abs(rgb_t - depth_t) < 0.02)
    assert len(set(depth_t)) == 9
    assert tum_frames[0].meta["depth_path"].endswith("depth/1305031453.374112.png")
    # greedy one-to-one, like associate.py: the closer pair wins
    assert list(associate([0.0, 0.012, 1.0], [0.01, 0.5], 0.02)) == [-1, 0, -1]
    assert list(associate([0.0, 0.1], [0.105, 0.005], 0.02)) == [1, 0]


def test_tum_frame_selection():
    seq = load_bundled_tum(frames="2:8:3", load_depth=False)
    assert seq.frame_numbers == [2, 5] and len(seq) == 2
    f = seq[1]
    assert f.depth is None and f.meta["frame_number"] == 5
    assert f.name == load_bundled_tum()[5].name
    assert len(open_dataset("tum", bundled_tum_path(), frames=parse_frame_range("4:"))) == 5


def test_tum_undistortion_changes_image(tum_frames):
    raw = load_bundled_tum(undistort=False)
    assert raw.camera.distortion is not None
    f_raw = raw[0]
    diff = np.abs(f_raw.image - tum_frames[0].image).mean()
    assert diff > 0.02
    # the centre moves little, the corners a lot (barrel distortion of fr1)
    c = np.abs(f_raw.image[200:280, 280:360] - tum_frames[0].image[200:280, 280:360]).mean()
    assert c < diff
    # undistortion equals the camera's own maps
    expected = np.clip(raw.camera.undistort_image(f_raw.image), 0, 1)
    np.testing.assert_allclose(tum_frames[0].image, expected, atol=1e-6)
    # depth is resampled with nearest neighbour: only values of the raw map appear
    vals_raw = set(np.unique(f_raw.depth[np.isfinite(f_raw.depth)]).tolist())
    vals_und = set(np.unique(tum_frames[0].depth[np.isfinite(tum_frames[0].depth)]).tolist())
    assert vals_und <= vals_raw


def test_tum_gt_interpolation():
    gt_stamps, gt_tum = read_tum_groundtruth(bundled_tum_path() / "groundtruth.txt")
    k = 57
    exact = interpolate_poses(gt_stamps, gt_tum, [gt_stamps[k]])[0]
    np.testing.assert_allclose(exact, pose_from_tum(gt_tum[k]), atol=1e-12)
    mid_t = 0.5 * (gt_stamps[k] + gt_stamps[k + 1])
    mid = interpolate_poses(gt_stamps, gt_tum, [mid_t])[0]
    T0, T1 = pose_from_tum(gt_tum[k]), pose_from_tum(gt_tum[k + 1])
    # (mid_t carries ~1e-7 s of rounding at 1.3e9 s: tolerances are loose accordingly)
    np.testing.assert_allclose(mid[:3, 3], 0.5 * (T0[:3, 3] + T1[:3, 3]), atol=1e-6)
    a0 = rotation_angle_deg(T0[:3, :3].T @ mid[:3, :3])
    a1 = rotation_angle_deg(mid[:3, :3].T @ T1[:3, :3])
    assert a0 == pytest.approx(a1, abs=1e-4) and a0 > 0.01
    assert a0 == pytest.approx(0.5 * rotation_angle_deg(T0[:3, :3].T @ T1[:3, :3]), abs=1e-4)
    # outside the range, and across a gap larger than max_gap: no pose
    assert interpolate_poses(gt_stamps, gt_tum, [gt_stamps[0] - 0.01])[0] is None
    assert interpolate_poses(gt_stamps, gt_tum, [gt_stamps[-1] + 0.01])[0] is None
    # a real slerp: 90 degrees about z, a quarter of the way -> 22.5 degrees
    q90 = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]
    two = np.array([[0, 0, 0, 0, 0, 0, 1.0], [4.0, 0, 0, *q90]])
    T = interpolate_poses(np.array([0.0, 0.04]), two, [0.01])[0]
    assert rotation_angle_deg(T) == pytest.approx(22.5, abs=1e-9)
    np.testing.assert_allclose(T[:3, 3], [1.0, 0, 0], atol=1e-12)
    assert T[1, 0] > 0  # rotation sense kept
    gapped_s = np.array([0.0, 0.01, 0.2])
    gapped = np.tile(gt_tum[:1], (3, 1))
    assert interpolate_poses(gapped_s, gapped, [0.005])[0] is not None
    assert interpolate_poses(gapped_s, gapped, [0.1], max_gap=0.05)[0] is None


def _copy_tum(tmp_path: Path, name: str = "rgbd_dataset_freiburg1_test", n: int = 3) -> Path:
    src = bundled_tum_path()
    dst = tmp_path / name
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    rgb_lines = [line for line in (src / "rgb.txt").read_text().splitlines()
                 if not line.startswith("#")][:n]
    depth_lines = [line for line in (src / "depth.txt").read_text().splitlines()
                   if not line.startswith("#")][:n]
    for line in rgb_lines + depth_lines:
        rel_path = line.split()[1]
        shutil.copy(src / rel_path, dst / rel_path)
    (dst / "rgb.txt").write_text("# rgb\n" + "\n".join(rgb_lines) + "\n")
    (dst / "depth.txt").write_text("# depth\n" + "\n".join(depth_lines) + "\n")
    shutil.copy(src / "groundtruth.txt", dst / "groundtruth.txt")
    return dst


def test_tum_reader_pose_at_exact_gt_stamp(tmp_path):
    root = _copy_tum(tmp_path, n=1)
    gt_stamps, gt_tum = read_tum_groundtruth(root / "groundtruth.txt")
    k = int(np.argmin(np.abs(gt_stamps - 1305031453.36)))
    img = (root / "rgb.txt").read_text().splitlines()[1].split()[1]
    (root / "rgb.txt").write_text(f"{float(gt_stamps[k])!r} {img}\n")
    f = TUMSequence(root)[0]
    np.testing.assert_allclose(f.T_world_cam, pose_from_tum(gt_tum[k]), atol=1e-9)


def test_tum_warp_validates_camera_to_world(tum_frames):
    """Warping with depth + GT relative pose must beat the no-motion warp clearly."""
    for a, b in [(0, 4), (4, 0), (0, 8), (2, 6)]:
        fa, fb = tum_frames[a], tum_frames[b]
        e_gt, e_id = err(fa, fb, rel(fa, fb)), err(fa, fb, np.eye(4))
        e_inv = err(fa, fb, rel(fb, fa))
        assert e_gt < 0.5 * e_id, (a, b, e_gt, e_id)
        assert e_gt < 0.75 * e_inv, (a, b, e_gt, e_inv)


def test_warp_image_identity(tum_frames):
    f = tum_frames[0]
    warped, valid = warp_image(f.image, f.depth, f.camera, np.eye(4))
    assert valid.sum() == np.isfinite(f.depth).sum()
    np.testing.assert_allclose(warped[valid], f.image[valid], atol=1e-5)
    assert np.all(warped[~valid] == 0)


# ------------------------------------------------------------------ calibration
def test_tum_calibration_selection(tmp_path, caplog):
    assert detect_tum_calibration("/x/rgbd_dataset_freiburg2_desk") == "fr2"
    assert detect_tum_calibration("tum_fr1_desk_9") == "fr1"
    assert detect_tum_calibration("fr3_office") == "fr3"
    assert detect_tum_calibration("frames_7") is None
    root = _copy_tum(tmp_path, name="my_sequence", n=1)
    with caplog.at_level(logging.WARNING, logger="spgeo.datasets.tum"):
        seq = TUMSequence(root)
    assert seq.raw_camera == tum_camera("ros")
    assert any("ROS default" in r.getMessage() for r in caplog.records)
    assert TUMSequence(root, calibration="fr3").camera == tum_camera("fr3")
    cam = PinholeCamera(500.0, 501.0, 320.0, 240.0, 640, 480)
    assert TUMSequence(root, calibration=cam).camera == cam
    (root / "camera.json").write_text(json.dumps(cam.to_dict()))
    seq = TUMSequence(root)
    assert seq.camera == cam and seq[0].camera == cam
    with pytest.raises(ValueError, match="unknown TUM calibration"):
        TUMSequence(root, calibration="fr9")


# ------------------------------------------------------------------ bad input
def test_tum_missing_listed_file(tmp_path):
    root = _copy_tum(tmp_path)
    victim = sorted((root / "rgb").glob("*.png"))[1]
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=victim.name):
        TUMSequence(root)
    seq = TUMSequence(root, check_files=False)  # lazily: fails on access only
    seq[0]
    with pytest.raises(FileNotFoundError, match=victim.name):
        seq[1]


def test_tum_missing_rgb_txt_and_rgb_folder(tmp_path):
    root = _copy_tum(tmp_path)
    (root / "rgb.txt").unlink()
    shutil.rmtree(root / "rgb")
    with pytest.raises(FileNotFoundError, match="rgb.txt"):
        TUMSequence(root)


def _same_frames(got, want):
    for a, b in zip(got, want):
        assert (a.name, a.timestamp, a.meta["depth_timestamp"]) == \
            (b.name, b.timestamp, b.meta["depth_timestamp"])
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.depth, b.depth)      # NaN where invalid, both
        np.testing.assert_array_equal(a.T_world_cam, b.T_world_cam)


def test_tum_without_rgb_txt_times_frames_by_their_file_names(tmp_path, caplog):
    """Issue 53: a TUM folder without rgb.txt / depth.txt lists rgb/ and depth/ and takes
    each stamp from the file name: the same frames, stamps, images, depth association
    and ground-truth poses as with the list files; non-image files are ignored."""
    root = _copy_tum(tmp_path, n=5)
    listed = TUMSequence(root)
    want = listed[:]
    assert sum(f.depth is not None for f in want) == 5
    (root / "rgb.txt").unlink()
    (root / "depth.txt").unlink()
    (root / "rgb" / "README").write_text("not an image")
    with caplog.at_level(logging.INFO, logger="spgeo.datasets.tum"):
        seq = TUMSequence(root)
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "no rgb.txt: the 5 images of rgb/ are timed by their file names" in said
    assert "no depth.txt: the 5 images of depth/" in said
    np.testing.assert_array_equal(seq.timestamps, listed.timestamps)
    assert seq.timestamps[0] == 1305031453.359684
    _same_frames(seq[:], want)
    # rgb.txt back, depth/ listed: the same association
    (root / "rgb.txt").write_text("".join(f"{f.timestamp:.6f} rgb/{f.name}.png\n" for f in want))
    _same_frames(TUMSequence(root)[:], want)
    # a name that is not a timestamp is named
    shutil.copy(root / "depth" / f"{want[0].meta['depth_path'].split('/')[-1]}",
                root / "depth" / "frame7.png")
    with pytest.raises(InputError, match=r"depth/frame7\.png: its name is not a timestamp"):
        TUMSequence(root)
    assert len(TUMSequence(root, load_depth=False)) == 5    # depth/ not read


def test_stamped_file_names():
    assert stamp_from_name("1305031102.175304") == 1305031102.175304
    assert stamp_from_name("1403636579763555584") == 1403636579763555584 * 1e-9
    for not_a_time in ("000123", "12345678901234567", "img1", "1e9", "-1.5", "1.5.0", ""):
        assert stamp_from_name(not_a_time) is None, not_a_time
    paths, times = stamped_files([Path("b/2.5.png"), Path("b/1.25.png")], "rgb")
    assert paths == [Path("b/1.25.png"), Path("b/2.5.png")] and list(times) == [1.25, 2.5]
    with pytest.raises(InputError, match=r"1\.5\.png and .*1\.50\.png"):
        stamped_files([Path("1.5.png"), Path("1.50.png")], "rgb")


def test_tum_corrupt_image(tmp_path):
    root = _copy_tum(tmp_path)
    victim = sorted((root / "rgb").glob("*.png"))[0]
    victim.write_bytes(b"this is not a png")
    seq = TUMSequence(root)
    with pytest.raises(ValueError, match=victim.name):
        seq[0]
    dvictim = sorted((root / "depth").glob("*.png"))[1]
    dvictim.write_bytes(b"\x89PNG garbage")
    with pytest.raises(ValueError, match=dvictim.name):
        seq[1]


def test_tum_non_monotonic_timestamps(tmp_path):
    root = _copy_tum(tmp_path)
    lines = (root / "rgb.txt").read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="not strictly increasing"):
        TUMSequence(root)


def test_tum_malformed_line(tmp_path):
    root = _copy_tum(tmp_path)
    with open(root / "rgb.txt", "a") as f:
        f.write("1305031460.0\n")
    with pytest.raises(ValueError, match=r"rgb\.txt:5"):
        TUMSequence(root)
    (root / "rgb.txt").write_text("# c\nnot_a_time rgb/x.png\n")
    with pytest.raises(ValueError, match=r"rgb\.txt:2.*timestamp"):
        TUMSequence(root)
    root2 = _copy_tum(tmp_path / "b")
    with open(root2 / "groundtruth.txt", "a") as f:
        f.write("1305031499.0 1 2 3\n")
    with pytest.raises(ValueError, match="groundtruth.txt"):
        TUMSequence(root2)


def test_tum_wrong_image_shape(tmp_path):
    root = _copy_tum(tmp_path)
    victim = sorted((root / "rgb").glob("*.png"))[2]
    cv2.imwrite(str(victim), np.zeros((240, 320, 3), np.uint8))
    seq = TUMSequence(root)
    seq[0]
    with pytest.raises(ValueError, match=victim.name):
        seq[2]


def test_open_dataset_errors():
    with pytest.raises(ValueError, match="unknown data-set kind"):
        open_dataset("nuscenes", bundled_tum_path())
    with pytest.raises(TypeError, match="unknown option"):
        open_dataset("tum", bundled_tum_path(), undistrot=False)
    with pytest.raises(FileNotFoundError):
        open_dataset("tum", bundled_tum_path() / "nope")


# ------------------------------------------------------------------ 7-Scenes
def test_seven_scenes():
    root = shared("7scenes_redkitchen_dev")
    seq = open_dataset("7scenes", root, frames="0:300:10")
    assert isinstance(seq, SevenScenesSequence)
    assert len(seq) == 30 and seq.frame_numbers[:3] == [0, 10, 20]
    assert seq.camera == PinholeCamera(585.0, 585.0, 320.0, 240.0, 640, 480)
    f0, f1, f2 = seq[0], seq[1], seq[2]
    assert f1.timestamp == 10.0 and f1.name == "frame-000010"
    assert f1.meta["depth_registered"] is False
    raw = cv2.imread(str(root / "frame-000010.depth.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(np.isnan(f1.depth), (raw == 0) | (raw == 65535))
    ok = np.isfinite(f1.depth)
    np.testing.assert_allclose(f1.depth[ok], raw[ok] / 1000.0, rtol=1e-6)
    stored = np.loadtxt(root / "frame-000010.pose.txt")
    np.testing.assert_allclose(f1.T_world_cam, stored, atol=1e-3)
    assert len(SevenScenesSequence(root)) == 300
    # camera-to-world check (depth is only approximately registered)
    for fa, fb in [(f0, f1), (f0, f2), (f2, f0)]:
        e_gt, e_id = err(fa, fb, rel(fa, fb)), err(fa, fb, np.eye(4))
        assert e_gt < 0.5 * e_id, (fa.name, fb.name, e_gt, e_id)


# ------------------------------------------------------------------ ICL-NUIM
@pytest.fixture(scope="module")
def icl():
    root = shared("icl_nuim_lr_5")
    seq = open_dataset("icl", root)
    return root, seq, seq[:]


ICL_PAIRS = [(4, 2), (1, 2), (4, 1), (5, 4), (2, 4), (5, 1)]  # frame numbers, overlapping views


def test_icl_reader(icl):
    root, seq, frames = icl
    assert isinstance(seq, ICLSequence) and len(seq) == 5
    assert seq.frame_numbers == [1, 2, 3, 4, 5]
    assert seq.camera == ICL_CAMERA and seq.camera.fy == pytest.approx(480.0)
    f = frames[0]
    assert f.timestamp == 1.0 and f.name == "1" and f.image.shape == (480, 640, 3)
    raw = cv2.imread(str(root / "depth" / "1.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_allclose(f.depth, raw / 5000.0, rtol=1e-6)
    # pose.txt: line k <-> frame k + 1
    lines = (root / "pose.txt").read_text().split("\n")
    file_pose = pose_from_tum([float(x) for x in lines[3].split()])
    np.testing.assert_allclose(frames[3].T_world_cam, icl_pose_to_opencv(file_pose), atol=1e-12)
    assert np.linalg.det(frames[3].T_world_cam[:3, :3]) == pytest.approx(1.0)


def test_icl_convention_by_photometric_warp(icl):
    """The conversion S T S (fy -> +480, images unchanged) is what the pixels say.

    Alternatives: the file's pose unchanged (only fy negated), and the inverse
    relative pose (camera-to-world misread as world-to-camera).  Flipping the
    images upside down instead is equivalent to using the file's poses unchanged
    on unflipped images, so it is covered.
    """
    root, seq, frames = icl
    by_num = dict(zip(seq.frame_numbers, frames))
    file_poses = read_icl_poses(root / "pose.txt")
    S = np.diag([1.0, -1.0, 1.0, 1.0])
    for a, b in ICL_PAIRS:
        fa, fb = by_num[a], by_num[b]
        T = rel(fa, fb)
        T_file = relative_pose(file_poses[b], file_poses[a])
        np.testing.assert_allclose(T, S @ T_file @ S, atol=1e-9)
        e_gt = err(fa, fb, T)
        e_id = err(fa, fb, np.eye(4))
        e_file = err(fa, fb, T_file)
        assert e_gt < 0.03, (a, b, e_gt)
        assert e_gt < 0.25 * e_id, (a, b, e_gt, e_id)
        assert e_gt < 0.33 * e_file, (a, b, e_gt, e_file)
        e_inv, frac_inv = photometric_error(fa.image, fb.image, fa.depth, fa.camera,
                                            np.linalg.inv(T))
        assert frac_inv < 0.1 or e_gt < 0.5 * e_inv, (a, b, e_gt, e_inv)


def test_icl_depth_is_z_depth(icl):
    _, seq, frames = icl
    by_num = dict(zip(seq.frame_numbers, frames))
    cam = seq.camera
    ray_norm = np.linalg.norm(cam.rays(), axis=-1).astype(np.float32)
    # 1. warp consistency summed over pairs
    e_z = sum(err(by_num[a], by_num[b], rel(by_num[a], by_num[b])) for a, b in ICL_PAIRS)
    e_ray = sum(err(by_num[a], by_num[b], rel(by_num[a], by_num[b]),
                    depth=by_num[a].depth / ray_norm) for a, b in ICL_PAIRS)
    assert e_z < 0.85 * e_ray, (e_z, e_ray)

    # 2. planarity of the back wall facing the camera in frame 1
    def plane_residual(points):
        p = points.reshape(-1, 3)
        keep = np.ones(len(p), bool)
        for _ in range(10):  # robust re-fit (ignores the picture frame on the wall)
            c = p[keep].mean(0)
            n = np.linalg.svd(p[keep] - c, full_matrices=False)[2][-1]
            r = np.abs((p - c) @ n)
            keep = r < max(3 * np.median(r), 1e-4)
        return float(np.median(r[keep]))

    wall = np.s_[90:170, 170:630]
    d = by_num[1].depth
    res_z = plane_residual(cam.unproject_depth_map(d)[wall])
    res_ray = plane_residual(cam.unproject_depth_map(d / ray_norm)[wall])
    assert res_z < 0.002 and res_ray > 10 * res_z, (res_z, res_ray)


# ------------------------------------------------------------------ folder
def _write_folder(tmp_path: Path, rng) -> Path:
    root = tmp_path / "imgs"
    (root / "depth").mkdir(parents=True)
    images = {}
    for stem in ["img1", "img2", "img10"]:
        img = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        cv2.imwrite(str(root / f"{stem}.png"), img)
        images[stem] = img[..., ::-1].astype(np.float32) / 255.0
    depth_mm = rng.integers(0, 5000, (24, 32)).astype(np.uint16)
    depth_mm[0, 0] = 0
    cv2.imwrite(str(root / "depth" / "img1.png"), depth_mm)
    depth_m = rng.uniform(0.5, 3.0, (24, 32))
    depth_m[1, 1] = -1.0
    np.save(root / "depth" / "img10.npy", depth_m)
    (root / "intrinsics.txt").write_text("30 31 15.5 11.5\n")
    (root / "times.txt").write_text("# t\n0.5\n0.75\n1.0\n")
    (root / "notes.txt").write_text("ignored")
    return root, images, depth_mm, depth_m


def test_folder_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    root, images, depth_mm, depth_m = _write_folder(tmp_path, rng)
    seq = open_dataset("folder", root)
    assert isinstance(seq, FolderSequence) and len(seq) == 3
    assert seq.camera == PinholeCamera(30, 31, 15.5, 11.5, 32, 24)
    frames = seq[:]
    assert [f.name for f in frames] == ["img1", "img2", "img10"]  # natural order
    np.testing.assert_allclose(seq.timestamps, [0.5, 0.75, 1.0])
    for f in frames:
        np.testing.assert_allclose(f.image, images[f.name], atol=1e-6)
        assert f.T_world_cam is None
    d0 = frames[0].depth
    assert np.isnan(d0[0, 0])
    np.testing.assert_allclose(d0[1:], depth_mm[1:] / 1000.0, rtol=1e-6)
    assert frames[1].depth is None
    assert np.isnan(frames[2].depth[1, 1])
    np.testing.assert_allclose(frames[2].depth[2:], depth_m[2:], rtol=1e-6)
    # 3x3 K, no times.txt -> timestamps are indices; selection by index
    (root / "times.txt").unlink()
    (root / "intrinsics.txt").write_text("30 0 15.5\n0 31 11.5\n0 0 1\n")
    seq = FolderSequence(root, frames="1:3", load_depth=False)
    assert seq.frame_numbers == [1, 2] and list(seq.timestamps) == [1.0, 2.0]
    assert seq.camera.fy == 31 and seq[1].depth is None
    # camera.json with distortion wins and images are undistorted
    cam = PinholeCamera(30, 31, 15.5, 11.5, 32, 24, (0.1, -0.05, 0.0, 0.0, 0.0))
    (root / "camera.json").write_text(json.dumps(cam.to_dict()))
    seq = FolderSequence(root)
    assert seq.raw_camera == cam and seq.camera == cam.undistorted()
    assert not np.allclose(seq[0].image, images["img1"])
    assert FolderSequence(root, undistort=False).camera == cam


def test_folder_errors(tmp_path):
    rng = np.random.default_rng(1)
    root, *_ = _write_folder(tmp_path, rng)
    (root / "intrinsics.txt").unlink()     # no calibration: guessed and flagged (issue 25)
    assert FolderSequence(root).intrinsics["source"] == "guessed"
    (root / "intrinsics.txt").write_text("1 2 3\n")
    with pytest.raises(ValueError, match="intrinsics.txt"):
        FolderSequence(root)
    (root / "intrinsics.txt").write_text("30 31 15.5 11.5\n")
    (root / "times.txt").write_text("1\n2\n")
    with pytest.raises(ValueError, match="times.txt"):
        FolderSequence(root)
    (root / "times.txt").unlink()
    (root / "img2.png").write_bytes(b"junk")
    seq = FolderSequence(root)
    with pytest.raises(ValueError, match="img2.png"):
        seq[1]


def test_folder_of_timestamp_names_is_in_time_order(tmp_path, caplog):
    """Issue 53: when every image name is a time (TUM's seconds, EuRoC's 19-digit
    nanoseconds) the frames are in time order and timed by their names, so that
    trajectory.txt matches the data set's ground truth; otherwise nothing changes."""
    rng = np.random.default_rng(4)
    root = tmp_path / "secs"
    root.mkdir()
    # natural name order would put .2 (2) before .175304 (175304)
    stems = ["1305031102.2", "1305031102.175304", "1305031103.0"]
    for stem in stems:
        cv2.imwrite(str(root / f"{stem}.png"), rng.integers(0, 256, (24, 32, 3), np.uint8))
    (root / "intrinsics.txt").write_text("30 31 15.5 11.5\n")
    with caplog.at_level(logging.INFO, logger="spgeo.datasets.folder"):
        seq = FolderSequence(root)
    assert "the 3 image names are timestamps" in caplog.text
    np.testing.assert_array_equal(seq.timestamps, [1305031102.175304, 1305031102.2, 1305031103.0])
    assert [f.name for f in seq[:]] == [stems[1], stems[0], stems[2]]
    assert [f.timestamp for f in seq[:]] == list(seq.timestamps)
    assert FolderSequence(root, frames="1:").timestamps[0] == 1305031102.2
    ns = tmp_path / "ns"
    ns.mkdir()
    for stem in ["1403636579813555456", "1403636579763555584"]:
        cv2.imwrite(str(ns / f"{stem}.png"), rng.integers(0, 256, (24, 32, 3), np.uint8))
    np.testing.assert_array_equal(FolderSequence(ns).timestamps,      # as EuRoC's reader
                                  [1403636579763555584 * 1e-9, 1403636579813555456 * 1e-9])
    # one name that is not a time, or frame-number names: positions as before
    cv2.imwrite(str(root / "extra.png"), rng.integers(0, 256, (24, 32, 3), np.uint8))
    assert list(FolderSequence(root).timestamps) == [0.0, 1.0, 2.0, 3.0]
    nums = tmp_path / "nums"
    nums.mkdir()
    for stem in ["000010", "000011"]:
        cv2.imwrite(str(nums / f"{stem}.png"), rng.integers(0, 256, (24, 32, 3), np.uint8))
    assert list(FolderSequence(nums).timestamps) == [0.0, 1.0]


def test_folder_depth_scale(tmp_path):
    """Issue 53: depth PNGs read back as raw / depth_scale (TUM's 5000, the default 1000
    = millimetres); a scale that is not a finite number > 0 is refused naming it."""
    rng = np.random.default_rng(2)
    root, _, depth_raw, _ = _write_folder(tmp_path, rng)
    d_mm = FolderSequence(root)[0].depth
    d_tum = FolderSequence(root, depth_scale=5000)[0].depth
    np.testing.assert_allclose(d_mm[1:], depth_raw[1:] / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(d_tum[1:], depth_raw[1:] / 5000.0, rtol=1e-6)
    assert np.isnan(d_tum[0, 0])
    for bad in (0, -5000, float("nan"), float("inf")):
        with pytest.raises(InputError, match=f"depth scale must be a finite number > 0.*{bad}"):
            FolderSequence(root, depth_scale=bad)
    with pytest.raises(InputError, match="got 0"):
        TUMSequence(bundled_tum_path(), depth_scale=0)
