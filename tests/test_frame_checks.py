"""Input checks of issue 42 where a user's mistake is common: a frame's image
(size against its camera, channels, dtype, range: :func:`spgeo.frame.check_frame_image`),
a frame's camera against the odometry's (:func:`spgeo.vo.processing.checked_frame`),
a negative focal length (ICL-NUIM's flipped y axis) and unnamed frames named by index."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.camera import PinholeCamera
from spgeo.datasets.icl import ICL_CAMERA, icl_pose_to_opencv
from spgeo.frame import MAX_FLOAT_IMAGE_VALUE, Frame, frame_label
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.geometry import so3_exp
from spgeo.validation import CAMERA_MATCH_TOLERANCE, InputError, check_same_camera
from spgeo.vo import Odometry, OdometryConfig
from spgeo.vo.processing import checked_frame

W, H = 32, 24
CAM = synthetic.default_camera(W, H)
BIG = synthetic.default_camera(2 * W, 2 * H)      # an input camera the VO halves
SMALL = BIG.resized(W, H)                          # its processing camera


def _image(h=H, w=W, channels=3, seed=0):
    shape = (h, w) if channels is None else (h, w, channels)
    return np.random.default_rng(seed).random(shape).astype(np.float32)


def _check(frame, index=0, camera=CAM, input_camera=CAM, previous=None):
    return checked_frame(frame, index, camera, input_camera, False, previous)


# ------------------------------------------------------------------ the image
def test_rgba_refused_with_how_to_drop_alpha():
    rgba = _image(channels=4)
    with pytest.raises(InputError, match=r"4 channels.*image\[\.\.\., :3\]") as exc:
        Frame(rgba, CAM, 0.0, name="shot_07")
    assert "Frame 'shot_07' image" in str(exc.value)
    assert Frame(rgba[..., :3], CAM, 0.0).image.shape == (H, W, 3)   # the fix it names
    with pytest.raises(InputError, match="2 channels"):
        Frame(_image(channels=2), CAM, 0.0)


def test_grey_images_kept():
    grey = _image(channels=None)
    assert Frame(grey, CAM, 0.0).image is grey
    assert Frame(grey[..., None], CAM, 0.0).image.shape == (H, W, 1)


def test_uint8_and_uint16_converted_to_float_in_0_1():
    u8 = (_image() * 255).astype(np.uint8)
    f = Frame(u8, CAM, 0.0)
    assert f.image.dtype == np.float32
    np.testing.assert_array_equal(f.image, u8.astype(np.float32) / 255)
    u16 = np.full((H, W), 65535, np.uint16)
    g = Frame(u16, CAM, 0.0)
    assert g.image.dtype == np.float32 and g.image.shape == (H, W) and g.image.max() == 1.0


def test_float_images_kept_as_given():
    img = _image()
    assert Frame(img, CAM, 0.0).image is img
    img64 = img.astype(np.float64)
    assert Frame(img64, CAM, 0.0).image is img64


def test_float_0_255_refused_saying_divide_by_255():
    with pytest.raises(InputError, match="divide by 255") as exc:
        Frame(_image() * 255, CAM, 0.0, name="k17")
    assert "Frame 'k17'" in str(exc.value) and "[0, 1]" in str(exc.value)
    at_bound = np.minimum(_image(), 1.0) * MAX_FLOAT_IMAGE_VALUE   # at the bound: accepted
    assert Frame(at_bound, CAM, 0.0).image is at_bound


@pytest.mark.parametrize("dtype", [np.int32, np.int64, bool])
def test_other_dtypes_refused(dtype):
    with pytest.raises(InputError, match="dtype"):
        Frame(np.zeros((H, W, 3), dtype), CAM, 0.0)


def test_swapped_width_and_height_named():
    swapped = PinholeCamera(CAM.fx, CAM.fy, CAM.cy, CAM.cx, H, W)    # width and height swapped
    with pytest.raises(InputError, match="width and height look swapped") as exc:
        Frame(_image(), swapped, 0.0, name="f0")
    assert "Frame 'f0' image" in str(exc.value)
    with pytest.raises(InputError) as exc:                      # another size: no swap claimed
        Frame(_image(h=H + 1), CAM, 0.0)
    assert "swapped" not in str(exc.value)


def test_unnamed_frame_named_in_messages():
    with pytest.raises(InputError) as exc:
        Frame(_image(channels=4), CAM, 0.0)
    assert "unnamed Frame" in str(exc.value) and "''" not in str(exc.value)
    assert frame_label("", 17) == "frame 17"
    assert frame_label(None, 3) == "frame 3"
    assert frame_label("a", 17) == "frame 17 ('a')"


# ------------------------------------------------------------------ negative focal lengths
def test_negative_fy_says_how_to_convert_as_the_icl_reader_does():
    raw = (481.20, -480.0, 319.5, 239.5, 640, 480)              # ICL-NUIM as published
    with pytest.raises(InputError, match="negative fy") as exc:
        PinholeCamera(*raw)
    msg = str(exc.value)
    assert "fy = 480 (cy unchanged)" in msg and "keep the image unchanged" in msg
    assert "S @ T @ S" in msg and "diag(1, -1, 1, 1)" in msg
    # the conversion the message names is the reader's: its camera, its poses
    assert (ICL_CAMERA.fy, ICL_CAMERA.cy) == (-raw[1], raw[3])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3_exp(np.array([0.1, -0.2, 0.3])), [1.0, 2.0, 3.0]
    S = np.diag([1.0, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(icl_pose_to_opencv(T), S @ T @ S)
    with pytest.raises(InputError, match=r"fx = 481\.2 \(cx unchanged\).*diag\(-1, 1, 1, 1\)"):
        PinholeCamera(-481.2, 480.0, 319.5, 239.5, 640, 480)
    with pytest.raises(InputError) as exc:                      # not a flip: no hint
        PinholeCamera(481.2, float("-inf"), 319.5, 239.5, 640, 480)
    assert "flipped" not in str(exc.value)


# ------------------------------------------------------------------ the odometry's camera
def test_frame_camera_differing_from_the_odometrys_refused():
    other = PinholeCamera(CAM.fx * 1.1, CAM.fy * 1.1, CAM.cx, CAM.cy, W, H)
    with Odometry(CAM, OdometryConfig(), make_frontend("depth", FrontEndConfig())) as vo:
        with pytest.raises(InputError) as exc:
            vo.track(Frame(_image(), other, 0.0))
        assert vo.frames == []                                  # not processed
    msg = str(exc.value)
    assert "frame 0 camera" in msg and "''" not in msg
    assert repr(other) in msg and repr(CAM) in msg and "fx " in msg
    assert "the camera the Odometry was built with" in msg


def test_camera_compared_at_the_frames_size():
    img = _image(h=2 * H, w=2 * W)
    kept = Frame(_image(), SMALL, 1.0, name="small")
    assert _check(kept, 5, SMALL, BIG) is kept                  # processing size, its camera
    resized = _check(Frame(img, BIG, 1.0), 5, SMALL, BIG)       # input size: resized
    assert resized.camera == SMALL and resized.image.shape == (H, W, 3)
    wrong = PinholeCamera(SMALL.fx * 1.05, SMALL.fy * 1.05, SMALL.cx, SMALL.cy, W, H)
    with pytest.raises(InputError, match=r"frame 5 \('small'\).*Odometry\.camera"):
        _check(Frame(_image(), wrong, 1.0, name="small"), 5, SMALL, BIG)


def test_camera_match_tolerates_rounding_not_distortion():
    noisy = PinholeCamera(CAM.fx + 1e-9, CAM.fy, CAM.cx - 1e-9, CAM.cy, W, H)
    check_same_camera(noisy, CAM)
    off = PinholeCamera(CAM.fx, CAM.fy, CAM.cx + 10 * CAMERA_MATCH_TOLERANCE, CAM.cy, W, H)
    with pytest.raises(InputError, match="cx"):
        check_same_camera(off, CAM)
    distorted = PinholeCamera(CAM.fx, CAM.fy, CAM.cx, CAM.cy, W, H, (0.1, 0.0, 0.0, 0.0))
    with pytest.raises(InputError, match="distortion"):
        _check(Frame(_image(), distorted, 0.0), 2)


def test_odometry_camera_with_swapped_size_named():
    swapped = PinholeCamera(CAM.fx, CAM.fy, CAM.cy, CAM.cx, H, W)
    with pytest.raises(InputError, match=r"frame 3 .*width and height look swapped"):
        _check(Frame(_image(), CAM, 0.0), 3, swapped, swapped)


def test_unnamed_frames_named_by_index_in_odometry_messages():
    bad = _image()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match=r"^Odometry\.track: frame 17 image contains NaN"):
        _check(Frame(bad, CAM, 0.0), 17)
    with pytest.raises(InputError, match=r"^Odometry\.track: frame 4 timestamp"):
        _check(Frame(_image(), CAM, 1.0), 4, previous=2.0)
    with pytest.raises(InputError, match=r"frame 4 \('x'\) timestamp"):
        _check(Frame(_image(), CAM, 1.0, name="x"), 4, previous=2.0)


def test_synthetic_frames_pass_unchanged():
    scene = synthetic.SyntheticScene.generate(0)
    frames = synthetic.render_frames(scene, CAM, synthetic.make_trajectory(2, 0))
    for i, f in enumerate(frames):
        assert _check(f, i) is f
