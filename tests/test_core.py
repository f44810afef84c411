"""PinholeCamera, pose helpers, images and PrimitiveSet."""
import numpy as np
import pytest

from analytic import sphere
from spgeo import PinholeCamera, PrimitiveSet
from spgeo import geometry as geo
from spgeo.images import (gaussian_pyramid, load_image, sample_bilinear, scharr_gradients,
                          to_float_image, to_gray)

CAM = PinholeCamera(300.0, 310.0, 160.2, 118.7, 320, 240)


# ------------------------------------------------------------------ camera
def test_project_unproject_round_trip():
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [319, 239], size=(100, 2))
    z = rng.uniform(0.5, 5.0, size=100)
    X = CAM.unproject(uv, z)
    uv2, z2 = CAM.project(X)
    np.testing.assert_allclose(uv2, uv, atol=1e-9)
    np.testing.assert_allclose(z2, z)
    # behind the camera: NaN pixels
    uv3, _ = CAM.project(np.array([[0.0, 0.0, -1.0]]))
    assert np.all(np.isnan(uv3))


def test_camera_validation():
    for bad in [dict(fx=0), dict(fy=-480), dict(cx=np.nan), dict(width=0), dict(height=2.5)]:
        kw = dict(fx=300, fy=300, cx=160, cy=120, width=320, height=240)
        kw.update(bad)
        with pytest.raises(ValueError):
            PinholeCamera(**kw)
    with pytest.raises(ValueError, match="distortion"):
        PinholeCamera(300, 300, 160, 120, 320, 240, distortion=(0.1, 0.2, 0.3))
    with pytest.raises(ValueError, match="shape"):
        CAM.check_image(np.zeros((10, 10)))


def test_resized_matches_cv2_resize_geometry():
    import cv2

    # a bright dot at a known 3-D point must land where the resized camera projects it
    big = PinholeCamera(500.0, 500.0, 319.5, 239.5, 640, 480)
    X = np.array([0.3, -0.2, 2.0])
    uv, _ = big.project(X)
    img = np.zeros((480, 640), np.float32)
    img[int(round(uv[1])) - 2:int(round(uv[1])) + 2, int(round(uv[0])) - 2:int(round(uv[0])) + 2] = 1
    small = big.resized(160, 120)
    out = cv2.resize(img, (160, 120), interpolation=cv2.INTER_AREA)
    v, u = np.unravel_index(np.argmax(cv2.GaussianBlur(out, (3, 3), 0)), out.shape)
    uv_s, _ = small.project(X)
    assert abs(uv_s[0] - u) <= 1 and abs(uv_s[1] - v) <= 1
    assert big.scaled(0.5).size == (320, 240)
    d = big.decimated(2)
    assert (d.fx, d.cx, d.width) == (250.0, 159.75, 320)


def test_undistortion_maps_identity_and_effect():
    cam = PinholeCamera(517.3, 516.5, 318.6, 255.3, 640, 480,
                        distortion=(0.2624, -0.9531, -0.0054, 0.0026, 1.1633))
    mx, my = cam.undistortion_maps()
    u, v = cam.pixel_grid()
    # near the principal point the map is ~identity; towards the corners it moves pixels
    assert abs(mx[255, 318] - 318) < 0.5 and abs(my[255, 318] - 255) < 0.5
    assert np.hypot(mx[0, 0] - u[0, 0], my[0, 0] - v[0, 0]) > 2
    assert cam.undistorted().distortion is None
    plain = PinholeCamera(517.3, 516.5, 318.6, 255.3, 640, 480)
    mx, my = plain.undistortion_maps()
    np.testing.assert_allclose(mx, u, atol=1e-3)


def test_pose_helpers():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = geo.so3_exp(rng.normal(size=3))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = rng.normal(size=3)
        np.testing.assert_allclose(geo.pose_from_tum(geo.pose_to_tum(T)), T, atol=1e-12)
        np.testing.assert_allclose(geo.invert_pose(T) @ T, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(geo.from_pose3(geo.to_pose3(T)), T, atol=1e-12)
    assert abs(geo.rotation_angle_deg(geo.so3_exp([0, 0, np.radians(30)])) - 30) < 1e-9
    with pytest.raises(ValueError):
        geo.check_pose(np.diag([1, 1, -1, 1.0]))
    with pytest.raises(ValueError):
        geo.pose_from_tum([0, 0, 0, 0, 0, 0, 0])


def test_nearest_rotation():
    """A rotation (orthonormal, det +1), the nearest in the Frobenius norm, also for
    inputs that hold a reflection (where ``U @ Vt`` alone is no rotation)."""
    rng = np.random.default_rng(3)

    def is_rotation(R):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert abs(np.linalg.det(R) - 1.0) < 1e-12

    # diag(3, 2, -1): U @ Vt is diag(1, 1, -1); the nearest rotation is I (trace 4 vs 2)
    R = geo.nearest_rotation(np.diag([3.0, 2.0, -1.0]))
    is_rotation(R)
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    flip = np.diag([1.0, 1.0, -1.0])
    candidates = [geo.so3_exp(rng.normal(size=3) * 3) for _ in range(2000)]
    for M in [geo.so3_exp(rng.normal(size=3)) + 1e-3 * rng.normal(size=(3, 3)),  # rounding
              geo.so3_exp(rng.normal(size=3)) @ flip + 0.1 * rng.normal(size=(3, 3)),
              rng.normal(size=(3, 3)), -rng.normal(size=(3, 3)) @ np.diag([4.0, 2.0, 1.0])]:
        R = geo.nearest_rotation(M)
        is_rotation(R)
        d = np.linalg.norm(M - R)
        # no random rotation, and no small turn of R, is closer to M
        assert all(np.linalg.norm(M - C) >= d for C in candidates)
        for _ in range(200):
            assert np.linalg.norm(M - geo.so3_exp(rng.normal(size=3) * 1e-3) @ R) >= d
    # a rotation comes back as itself (to rounding); nearest_rigid keeps the translation
    R0 = geo.so3_exp([0.3, -0.2, 0.1])
    np.testing.assert_allclose(geo.nearest_rotation(R0), R0, atol=1e-15)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R0 + 1e-6, [1.0, 2.0, 3.0]
    Tn = geo.nearest_rigid(T)
    np.testing.assert_array_equal(Tn[:3, :3], geo.nearest_rotation(T[:3, :3]))
    np.testing.assert_array_equal(Tn[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(Tn[:3, 3], [1.0, 2.0, 3.0])


# ------------------------------------------------------------------ images
def test_image_conversions_and_errors(tmp_path):
    u8 = np.full((4, 5, 3), 255, np.uint8)
    assert to_float_image(u8).max() == 1.0 and to_gray(u8).shape == (4, 5)
    with pytest.raises(ValueError, match="NaN"):
        to_float_image(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        to_float_image(np.full((4, 4), 3.0))
    with pytest.raises(FileNotFoundError, match="nothere.png"):
        load_image(tmp_path / "nothere.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="bad.png"):
        load_image(bad)


def test_pyramid_geometry_consistent():
    # a smooth pattern defined in 3-D on a fronto-parallel plane: level l pixel i == level 0 pixel 2^l i
    cam = PinholeCamera(200.0, 200.0, 80.0, 60.0, 160, 120)
    u, v = cam.pixel_grid()
    img = (0.5 + 0.4 * np.sin(u / 9.0) * np.cos(v / 7.0)).astype(np.float32)
    pyr = gaussian_pyramid(img, cam, 3)
    assert [c.width for c in pyr.cameras] == [160, 80, 40]
    c2 = pyr.cameras[2]
    X = cam.unproject(np.array([[100.0, 40.0]]), np.array([2.0]))
    uv2, _ = c2.project(X)
    np.testing.assert_allclose(uv2[0], [25.0, 10.0])
    # blurred value at level 2 ~ original at the corresponding pixel for a smooth image
    assert abs(pyr.images[2][10, 25] - img[40, 100]) < 0.05
    assert [lvl for lvl, _, _ in pyr.coarse_to_fine()] == [2, 1, 0]


def test_bilinear_sampling_and_gradients():
    h, w = 30, 40
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    img = 0.01 * u + 0.02 * v + 0.1        # linear: bilinear is exact
    rng = np.random.default_rng(2)
    su = rng.uniform(-2, w + 1, 500)
    sv = rng.uniform(-2, h + 1, 500)
    val, valid, (gu, gv) = sample_bilinear(img, su, sv, return_gradient=True)
    inside = (su >= 0) & (su <= w - 1) & (sv >= 0) & (sv <= h - 1)
    assert np.array_equal(valid, inside)
    np.testing.assert_allclose(val[valid], 0.01 * su[valid] + 0.02 * sv[valid] + 0.1, atol=1e-12)
    np.testing.assert_allclose(gu[valid], 0.01, atol=1e-12)
    np.testing.assert_allclose(gv[valid], 0.02, atol=1e-12)
    assert np.all(val[~valid] == 0)
    gu_s, gv_s = scharr_gradients(img.astype(np.float32))
    np.testing.assert_allclose(gu_s[5:-5, 5:-5], 0.01, atol=1e-5)
    np.testing.assert_allclose(gv_s[5:-5, 5:-5], 0.02, atol=1e-5)
    rgb = np.stack([img, 2 * img, 3 * img], -1)
    val3, _ = sample_bilinear(rgb, su, sv)
    np.testing.assert_allclose(val3[valid, 2], 3 * val[valid])


# ------------------------------------------------------------------ primitives
def _two_primitive_set():
    cam = PinholeCamera(150.0, 150.0, 79.5, 59.5, 160, 120)
    z, n = sphere(cam, [0.0, 0.0, 2.0], 0.9)
    m1 = np.zeros(cam.shape, bool)
    m1[30:70, 40:90] = True
    m2 = np.zeros(cam.shape, bool)
    m2[50:90, 70:120] = True
    logz = np.log(z)
    masks = np.stack([m1, m2])
    P = PrimitiveSet.from_masks(cam, masks, np.stack([logz, logz]) + np.array([0.3, -0.2])[:, None, None])
    return cam, z, masks, P


def test_primitive_set_scales_depth_cloud():
    cam, z, masks, P = _two_primitive_set()
    assert len(P) == 2 and P.sizes.tolist() == [m.sum() for m in masks]
    # anchor normalisation: unscaled log-depth is 0 at the anchor
    for prim in P:
        k = np.searchsorted(prim.pixels, prim.anchor)
        assert prim.log_depth[k] == 0.0
    s, cnt = P.fit_log_scales(z)
    assert cnt.tolist() == P.sizes.tolist()
    P2 = P.with_log_scales(s)
    d = P2.depth_map()
    cover = masks.any(0)
    np.testing.assert_allclose(d[cover], z[cover], rtol=1e-9)
    assert np.all(np.isnan(d[~cover]))
    assert P2.coverage().max() == 2
    # s is the metric log-depth at the anchor
    np.testing.assert_allclose(s, np.log(z.reshape(-1)[P.anchors]), rtol=1e-12)
    cloud = P2.point_cloud(np.zeros(cam.shape + (3,), np.float32))
    assert cloud.points.shape == (P.pixels.size, 3)
    uv, zz = cam.project(cloud.points)
    np.testing.assert_allclose(zz, z.reshape(-1)[P.pixels], rtol=1e-9)
    # overlapping pixels average along the ray
    P3 = P.with_log_scales(s + np.array([np.log(2.0), 0.0]))
    both = masks[0] & masks[1]
    np.testing.assert_allclose(P3.depth_map()[both], 1.5 * z[both], rtol=1e-9)


def test_primitive_set_sparse_scale_fit_is_robust():
    cam, z, masks, P = _two_primitive_set()
    sparse = np.full(cam.shape, np.nan)
    rng = np.random.default_rng(3)
    idx = rng.choice(cam.width * cam.height, 300, replace=False)
    sparse.reshape(-1)[idx] = z.reshape(-1)[idx] * (1 + 0.01 * rng.normal(size=300))
    sparse.reshape(-1)[idx[:10]] = 50.0     # gross outliers
    s, cnt = P.fit_log_scales(sparse)
    s_true, _ = P.fit_log_scales(z)
    assert np.all(cnt > 5) and np.all(np.abs(s - s_true) < 0.02)
    empty = np.full(cam.shape, np.nan)
    s_e, cnt_e = P.fit_log_scales(empty)
    assert np.all(np.isnan(s_e)) and np.all(cnt_e == 0)


def test_primitive_set_io_and_validation(tmp_path):
    cam, z, masks, P = _two_primitive_set()
    P.log_scales[:] = [0.1, 0.2]
    P.save(tmp_path / "p.npz")
    Q = PrimitiveSet.load(tmp_path / "p.npz")
    assert Q.camera == P.camera and np.array_equal(Q.pixels, P.pixels)
    np.testing.assert_allclose(Q.log_depth, P.log_depth, atol=1e-6)
    np.testing.assert_allclose(Q.log_scales, P.log_scales)
    with pytest.raises(FileNotFoundError):
        PrimitiveSet.load(tmp_path / "missing.npz")
    with pytest.raises(ValueError, match="anchor"):
        PrimitiveSet(cam, P.pixels, P.offsets, P.log_depth, [0, 0])
    with pytest.raises(ValueError, match="NaN"):
        PrimitiveSet(cam, P.pixels, P.offsets, np.full(P.pixels.size, np.nan), P.anchors)
    with pytest.raises(ValueError, match="empty"):
        PrimitiveSet.from_masks(cam, np.zeros((1,) + cam.shape, bool), np.zeros((1,) + cam.shape))
    sub = P.subset([1])
    assert len(sub) == 1 and sub.sizes[0] == P.sizes[1]
    assert np.array_equal(P.masks(), masks)


def test_primitive_set_memory_is_compressed():
    """400 primitives at 640x480 cost memory proportional to covered pixels."""
    cam = PinholeCamera(500.0, 500.0, 319.5, 239.5, 640, 480)
    rng = np.random.default_rng(0)
    regions, lds, anchors = [], [], []
    for _ in range(400):
        u0, v0 = rng.integers(0, 600), rng.integers(0, 440)
        vv, uu = np.mgrid[v0:v0 + 30, u0:u0 + 30]
        r = np.sort((vv * 640 + uu).ravel())
        regions.append(r)
        lds.append(np.zeros(r.size))
        anchors.append(r[r.size // 2])
    P = PrimitiveSet.from_regions(cam, regions, lds, anchors)
    nbytes = P.pixels.nbytes + P.log_depth.nbytes + P.offsets.nbytes
    assert nbytes < 0.1 * 400 * 640 * 480  # dense bool masks would be 123 MB
    assert np.isfinite(P.depth_map()).sum() > 0
