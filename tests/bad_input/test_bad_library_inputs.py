"""Bad inputs at the library's boundaries (issue 15): implausible intrinsics, sparse depth
in the wrong unit or type, broken image files, normals that would invent depth, depth
outputs that would clip.  Each case asserts the error class and a message fragment, or
the exact output; valid inputs are checked to still pass."""
import logging
import os

import cv2
import numpy as np
import pytest

from analytic import plane
from spgeo import PinholeCamera, integrate_normals
from spgeo.completion import complete_depth
from spgeo.datasets.files import read_camera_json, read_depth_png, read_rgb
from spgeo.images import load_image, read_raw_image, to_float_image
from spgeo.integration import IntegrationConfig, integrate_normals_regions
from spgeo.io.depth_files import read_sparse_depth, write_depth_png_mm
from spgeo.primitives import PrimitiveSet
from spgeo.validation import InputError, check_intrinsics, check_normals, check_sparse_depth

CAM = PinholeCamera(40.0, 40.0, 19.5, 14.5, 40, 30)     # small: fast integration


# ============================================================ intrinsics
@pytest.mark.parametrize("K,size,fragment", [
    ((0.808, 1.076, 0.498, 0.532), (160, 120), "looks normalised: multiply by the image size"),
    ((0.001, 0.001, 79.3, 63.4), (160, 120), "horizontal field of view"),
    ((150.0, 150.0, 1000.0, 59.5), (160, 120), "principal point cx=1000"),
    ((150.0, 150.0, 79.5, -200.0), (160, 120), "principal point cy=-200"),
    ((500.0, 100.0, 79.5, 59.5), (160, 120), "fx / fy = 5"),
    ((5000.0, 5000.0, 79.5, 59.5), (160, 120), "narrower than 10 deg"),
    ((150.0, 150.0, 79.5, 59.5), (0, 120), "width must be a positive integer"),
    ((150.0, 150.0, 79.5, 59.5), (160, 2.5), "height must be a positive integer"),
    ((np.nan, 150.0, 79.5, 59.5), (160, 120), "fx must be finite and > 0"),
    ((150.0, -150.0, 79.5, 59.5), (160, 120), "fy must be finite and > 0"),
    ((150.0, 150.0, np.inf, 59.5), (160, 120), "cx must be finite"),
    (("abc", 150.0, 79.5, 59.5), (160, 120), "fx must be a number"),
], ids=["normalised", "fx_0.001", "cx_far_outside", "cy_far_outside", "ratio_5", "telephoto",
        "zero_width", "fractional_height", "nan_fx", "negative_fy", "inf_cx", "text_fx"])
def test_implausible_intrinsics_are_refused(K, size, fragment):
    with pytest.raises(InputError, match=fragment):
        check_intrinsics(*K, *size)
    with pytest.raises(InputError, match=fragment):
        PinholeCamera(*K, *size)


@pytest.mark.parametrize("K,size", [
    ((150.0, 150.0, 79.5, 59.5), (160, 120)),         # plausible K for 160x120
    ((517.3, 516.5, 318.6, 255.3), (640, 480)),       # TUM fr1
    ((481.20, 480.00, 319.5, 239.5), (640, 480)),     # ICL-NUIM (fy flipped to +)
    ((585.0, 585.0, 320.0, 240.0), (640, 480)),       # 7-Scenes
    ((18.6, 16.9, 8.3, -0.2), (17, 1)),               # a one-row strip
], ids=["160x120", "tum", "icl", "7scenes", "strip"])
def test_plausible_intrinsics_pass_at_every_pyramid_level(K, size):
    cam = PinholeCamera(*K, *size)
    levels = [cam.resized(2 * cam.width, 2 * cam.height), cam.scaled(0.5)]
    for _ in range(4):
        levels.append(levels[-1].decimated(2))
    assert [(c.width, c.height) for c in levels[2:]] == [
        (-(-levels[1].width // 2 ** k), -(-levels[1].height // 2 ** k)) for k in range(1, 5)]
    assert levels[0].fx / levels[0].fy == pytest.approx(cam.fx / cam.fy)


def test_camera_json_with_normalised_intrinsics_names_the_file(tmp_path):
    path = tmp_path / "camera.json"
    path.write_text('{"fx": 0.808, "fy": 1.076, "cx": 0.498, "cy": 0.532, '
                    '"width": 160, "height": 120}')
    with pytest.raises(InputError, match=r"invalid camera file .*camera\.json.*looks normalised"):
        read_camera_json(path)
    path.write_text('{"fx": 150, "fy": 150, "cx": 79.5}')
    with pytest.raises(InputError, match="missing key.*cy, width, height"):
        read_camera_json(path)


# ============================================================ sparse depth
def _sparse(value=2.0, shape=(30, 40)):
    d = np.zeros(shape)
    d[5, 7] = d[20, 30] = value
    return d


@pytest.mark.parametrize("array,fragment", [
    (_sparse() > 0, "got dtype bool"),
    ((_sparse() * 1000).astype(np.uint16), "integer dtype uint16 looks like raw sensor units"),
    ((_sparse() * 1000).astype(np.int64), "integer dtype int64"),
    (_sparse() * 1000.0, "looks like millimetres"),
    (-_sparse(), "2 values are negative"),
    (np.where(_sparse() > 0, np.inf, 0.0), "2 values are inf"),
    (np.zeros((30, 40)), "no valid point"),
    (np.full((30, 40), np.nan), "no valid point"),
    (np.zeros((30, 40, 1)) + 1.0, r"expected a non-empty \(H, W\) array"),
    (_sparse().astype(np.complex128), "got dtype complex128"),
], ids=["bool", "uint16_mm", "int64", "float_mm", "negative", "inf", "all_zero", "all_nan",
        "3d", "complex"])
def test_bad_sparse_depth_npy(tmp_path, array, fragment):
    path = tmp_path / "sparse.npy"
    np.save(path, array)
    with pytest.raises(InputError, match=fragment):
        read_sparse_depth(path)
    with pytest.raises(InputError, match=fragment):
        check_sparse_depth(array)


def test_sparse_depth_npy_errors_name_the_file(tmp_path):
    path = tmp_path / "mm.npy"
    np.save(path, _sparse() * 1000.0)
    with pytest.raises(InputError, match=r"sparse depth file .*mm\.npy"):
        read_sparse_depth(path)
    pickled = tmp_path / "obj.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match=r"cannot read sparse depth file .*obj\.npy as a \.npy"):
        read_sparse_depth(pickled)
    (tmp_path / "dir.npy").mkdir()
    with pytest.raises(InputError, match="is a folder"):
        read_sparse_depth(tmp_path / "dir.npy")
    with pytest.raises(FileNotFoundError, match="sparse depth file not found"):
        read_sparse_depth(tmp_path / "nothere.npy")


@pytest.mark.parametrize("raw,fragment", [
    (np.full((30, 40), 200, np.uint8), "is a uint8 image"),
    (np.full((30, 40, 3), 2000, np.uint16), "has 3 channels"),
    (np.zeros((30, 40), np.uint16), "no valid point"),
], ids=["8bit_png", "rgb_png", "all_zero_png"])
def test_bad_sparse_depth_png(tmp_path, raw, fragment):
    path = tmp_path / "sparse.png"
    assert cv2.imwrite(str(path), raw)
    with pytest.raises(InputError, match=fragment):
        read_sparse_depth(path)


def test_valid_sparse_depth_png_and_npy_are_metres(tmp_path):
    raw = np.zeros((30, 40), np.uint16)
    raw[3, 4], raw[10, 20] = 1234, 65535
    cv2.imwrite(str(tmp_path / "s.png"), raw)
    d = read_sparse_depth(tmp_path / "s.png")
    assert d.dtype == np.float64 and d[3, 4] == 1.234 and d[10, 20] == 65.535
    assert np.count_nonzero(d) == 2
    sp = _sparse(1.5)
    sp[0, 0] = np.nan                               # NaN = missing -> 0
    np.save(tmp_path / "s.npy", sp.astype(np.float32))
    got = read_sparse_depth(tmp_path / "s.npy")
    assert got[0, 0] == 0.0 and got[5, 7] == 1.5 and np.count_nonzero(got) == 2


# ============================================================ image files
def _jpeg_bytes():
    img = (np.random.default_rng(0).random((60, 80, 3)) * 255).astype(np.uint8)
    return cv2.imencode(".jpg", img)[1].tobytes()


def _png_bytes():
    img = (np.random.default_rng(1).random((60, 80, 3)) * 255).astype(np.uint8)
    return cv2.imencode(".png", img)[1].tobytes()


@pytest.mark.parametrize("name,content,error,fragment", [
    ("half.jpg", _jpeg_bytes()[:len(_jpeg_bytes()) // 2], InputError,
     "is a truncated or corrupt JPEG"),
    ("noeoi.jpg", _jpeg_bytes()[:-2], InputError, "is a truncated or corrupt JPEG"),
    ("half.png", _png_bytes()[:len(_png_bytes()) // 2], InputError,
     "is a truncated or corrupt PNG"),
    ("noiend.png", _png_bytes()[:-12], InputError, "is a truncated or corrupt PNG"),
    ("text.png", b"this is not an image\n", InputError, "cannot decode image file"),
    ("empty.png", b"", InputError, r"is empty \(0 bytes\)"),
], ids=["truncated_jpeg", "jpeg_without_eoi", "truncated_png", "png_without_iend",
        "text_named_png", "empty_file"])
def test_broken_image_files(tmp_path, capfd, name, content, error, fragment):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(error, match=fragment) as info:
        load_image(path)
    assert name in str(info.value)
    with pytest.raises(error, match=fragment):
        read_rgb(path)
    assert capfd.readouterr().err == ""             # no decoder warning naming no file


def test_folder_named_like_an_image(tmp_path):
    (tmp_path / "x.png").mkdir()
    with pytest.raises(InputError, match=r"x\.png is a folder, not a file"):
        load_image(tmp_path / "x.png")
    with pytest.raises(InputError, match="is a folder"):
        read_depth_png(tmp_path / "x.png", 1000.0)


def test_unreadable_image_file(tmp_path):
    path = tmp_path / "locked.png"
    path.write_bytes(_png_bytes())
    path.chmod(0)
    try:
        if os.access(path, os.R_OK):
            pytest.skip("running as a user who can read a chmod 000 file (root)")
        with pytest.raises(InputError, match=r"cannot read image file .*locked\.png "
                                             r"\(permission denied\)"):
            read_raw_image(path)
    finally:
        path.chmod(0o644)


def test_unreadable_file_message_without_root(tmp_path, monkeypatch):
    """The permission check as an unprivileged user sees it (also when tests run as root)."""
    import spgeo.validation as validation

    path = tmp_path / "locked.png"
    path.write_bytes(_png_bytes())
    monkeypatch.setattr(validation.os, "access", lambda *_: False)
    with pytest.raises(InputError, match=r"cannot read image file .*locked\.png "
                                         r"\(permission denied\)"):
        load_image(path)


def test_complete_images_with_trailing_bytes_still_load(tmp_path):
    path = tmp_path / "trailing.jpg"
    path.write_bytes(_jpeg_bytes() + b"\x00" * 16 + b"appended data")
    ref = cv2.imdecode(np.frombuffer(_jpeg_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(read_raw_image(path), ref)
    (tmp_path / "ok.png").write_bytes(_png_bytes())
    assert load_image(tmp_path / "ok.png").shape == (60, 80, 3)


@pytest.mark.parametrize("array,fragment", [
    (np.zeros((4, 4), bool), "unsupported image dtype bool"),
    (np.zeros((4, 4), np.int32), "unsupported image dtype int32"),
    (np.full((4, 4), np.nan, np.float32), "16 NaN or inf values"),
    (np.zeros((0, 4)), "image is empty"),
    (np.zeros((4, 4, 2)), r"must be \(H, W\) or \(H, W, 1\|3\|4\)"),
], ids=["bool", "int32", "nan", "empty", "two_channels"])
def test_bad_image_arrays(array, fragment):
    with pytest.raises(InputError, match=fragment):
        to_float_image(array)


# ============================================================ normal integration
def _mask():
    m = np.zeros(CAM.shape, bool)
    m[5:25, 5:35] = True
    return m


def test_integrate_normals_refuses_a_tuple_camera():
    n = np.zeros(CAM.shape + (3,))
    n[..., 2] = -1.0
    with pytest.raises(TypeError, match="camera must be a spgeo.PinholeCamera, got tuple"):
        integrate_normals(n, _mask()[None], (40.0, 40.0, 19.5, 14.5))
    with pytest.raises(TypeError, match="got tuple"):
        integrate_normals_regions(n, [np.flatnonzero(_mask())], (40.0, 40.0, 19.5, 14.5))


@pytest.mark.parametrize("fill", [np.nan, 0.0], ids=["all_nan", "zero_length"])
def test_unknown_normals_give_nan_not_invented_depth(fill):
    n = np.full(CAM.shape + (3,), fill)
    ld = integrate_normals(n, _mask()[None], CAM)[0]
    assert np.all(np.isnan(ld))
    res = integrate_normals_regions(n, [np.flatnonzero(_mask())], CAM)
    assert np.all(np.isnan(res.log_depth)) and res.n_components.tolist() == [0]
    assert res.solver_info["n_unknown"] == _mask().sum() and not res.known.any()


def test_nan_normal_pixels_come_out_nan():
    z, n = plane(CAM, [0.3, -0.2, -1.0], -2.0)
    n[12:14, 10:30] = np.nan
    mask = _mask()
    ld = integrate_normals(n, mask[None], CAM)[0]
    unknown = np.zeros(CAM.shape, bool)
    unknown[12:14, 10:30] = True
    assert np.all(np.isnan(ld[unknown])) and np.all(np.isfinite(ld[mask & ~unknown]))
    d = ld[mask & ~unknown] - np.log(z[mask & ~unknown])   # the plane's shape, up to scale
    assert np.ptp(d) < 1e-5                         # midpoint rule on a plane
    filled = integrate_normals(n, mask[None], CAM, IntegrationConfig(unknown_normals="fill"))[0]
    assert np.all(np.isfinite(filled[mask]))        # the explicit opt-in fills them


def test_anchor_on_an_unknown_normal_keeps_the_known_pixels():
    _, n = plane(CAM, [0.3, -0.2, -1.0], -2.0)
    mask = _mask()
    anchor = 15 * CAM.width + 20
    n.reshape(-1, 3)[anchor] = np.nan
    ld = integrate_normals(n, mask[None], CAM, anchors=[anchor])[0]
    assert np.isnan(ld.reshape(-1)[anchor])
    assert np.isfinite(ld[mask]).sum() == mask.sum() - 1
    assert abs(np.nanmean(ld[mask])) < 1e-12        # zero mean over the known pixels instead


def test_short_normals_are_normalised(caplog):
    z, n = plane(CAM, [0.3, -0.2, -1.0], -2.0)
    unit = integrate_normals(n, _mask()[None], CAM)[0]
    with caplog.at_level(logging.WARNING, logger="spgeo.validation"):
        short = integrate_normals(0.01 * n, _mask()[None], CAM)[0]
    m = _mask()
    np.testing.assert_allclose(np.exp(short[m]), np.exp(unit[m]), rtol=1e-6)
    assert "1200 normals of length outside [0.5, 2] were normalised" in caplog.text


@pytest.mark.parametrize("masks,fragment", [
    (np.ones((1, 10, 10), bool), r"masks must be \(N, 30, 40\)"),
    (np.full((1, 30, 40), 0.5), "values other than 0 and 1"),
    (np.ones((1, 30, 40), complex), "expected a real numeric array"),
], ids=["wrong_shape", "fractional", "complex"])
def test_bad_masks(masks, fragment):
    _, n = plane(CAM, [0.3, -0.2, -1.0], -2.0)
    with pytest.raises(InputError, match=fragment):
        integrate_normals(n, masks, CAM)


def test_zero_one_masks_and_bad_normals():
    z, n = plane(CAM, [0.3, -0.2, -1.0], -2.0)
    m = _mask()
    np.testing.assert_array_equal(integrate_normals(n, m.astype(np.uint8), CAM),
                                  integrate_normals(n, m, CAM))
    with pytest.raises(InputError, match=r"shape \(10, 40, 3\) differs from the expected "
                                         r"\(30, 40, 3\)"):
        integrate_normals(n[:10], m, CAM)
    with pytest.raises(InputError, match=r"expected shape \(\.\.\., 3\), got \(30, 40, 2\)"):
        integrate_normals(n[:, :, :2], m, CAM)
    with pytest.raises(InputError, match="got dtype bool"):
        check_normals(np.ones((2, 3), bool))


# ============================================================ depth output
@pytest.mark.parametrize("depth,fragment", [
    (np.full((4, 5), 70.0), "exceed the 65.535 m a 16-bit millimetre PNG holds"),
    (np.full((4, 5), -1.0), "20 depths are negative"),
    (np.full((4, 5), np.inf), "20 depths are inf"),
    (np.ones(5), r"expected a non-empty \(H, W\) array"),
], ids=["over_65m", "negative", "inf", "1d"])
def test_depth_png_refuses_values_it_cannot_hold(tmp_path, depth, fragment):
    path = tmp_path / "out.png"
    path.write_bytes(b"previous")
    with pytest.raises(InputError, match=fragment):
        write_depth_png_mm(path, depth)
    assert path.read_bytes() == b"previous" and os.listdir(tmp_path) == ["out.png"]


def test_depth_png_bad_locations(tmp_path):
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(InputError, match=r"dir\.png is a folder"):
        write_depth_png_mm(tmp_path / "dir.png", np.ones((4, 5)))
    (tmp_path / "afile").write_text("x")
    with pytest.raises(InputError, match="a file is in the way"):
        write_depth_png_mm(tmp_path / "afile" / "out.png", np.ones((4, 5)))
    with pytest.raises(InputError, match=r"must end in \.png"):
        write_depth_png_mm(tmp_path / "out.jpg", np.ones((4, 5)))


def test_depth_png_round_trip(tmp_path):
    d = np.array([[1.2344, np.nan, 0.0], [65.535, 0.5, 3.0]])
    path = write_depth_png_mm(tmp_path / "new" / "out.png", d)
    raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.tolist() == [[1234, 0, 0], [65535, 500, 3000]]
    assert sorted(os.listdir(tmp_path / "new")) == ["out.png"]   # no temporary left


# ============================================================ complete_depth
def _completion_inputs():
    cam = PinholeCamera(60.0, 60.0, 31.5, 23.5, 64, 48)
    masks = np.zeros((2, 48, 64), bool)
    masks[0, :, :32] = masks[1, :, 32:] = True
    prims = PrimitiveSet.from_masks(cam, masks, np.zeros((2, 48, 64)))
    sparse = np.zeros((48, 64))
    sparse[10, 10] = sparse[30, 50] = 2.0
    return np.zeros((48, 64, 3), np.float32), sparse, cam, prims


@pytest.mark.parametrize("change,error,fragment", [
    (lambda i, s, c: (i, s[:40], c), InputError, r"shape \(40, 64\) differs from the image's"),
    (lambda i, s, c: (i[:40], s, c), InputError, r"image has shape \(40, 64, 3\)"),
    (lambda i, s, c: (i, s * 1000, c), InputError, "looks like millimetres"),
    (lambda i, s, c: (i, s > 0, c), InputError, "got dtype bool"),
    (lambda i, s, c: (i, s, (60.0, 60.0, 31.5, 23.5)), TypeError, "got tuple"),
    (lambda i, s, c: (np.full_like(i, np.nan), s, c), InputError, "NaN or inf"),
], ids=["sparse_shape", "camera_size", "sparse_mm", "sparse_bool", "tuple_camera", "nan_image"])
def test_complete_depth_validates_up_front(change, error, fragment):
    image, sparse, cam, prims = _completion_inputs()
    with pytest.raises(error, match=fragment):
        complete_depth(*change(image, sparse, cam), prims)
