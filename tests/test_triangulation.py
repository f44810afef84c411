"""The one triangulator (spgeo.triangulation, issue 50): exact recovery on noise-free
views (two and more, tracks missing some views), its gates (views, cheirality,
reprojection, parallax), and the three triangulators it replaced, frozen as they were
at 2401dea, on random data."""
import cv2
import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.geometry import invert_pose, ray_angles_deg, so3_exp, transform_points
from spgeo.sfm.init import triangulate_depths
from spgeo.triangulation import dlt_points, max_ray_angle_deg, triangulate

CAM = PinholeCamera(517.3, 516.5, 318.6, 255.3, 640, 480)     # fx != fy (TUM fr1)
SQUARE = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)


def _pose(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.asarray(rotvec, float))
    T[:3, 3] = t
    return T


def _pixels(cam, poses, X):
    """(N, V, 2) pinhole images ``K x / z`` of world points in every pose, also of
    points behind a camera (mirrored: the DLT cannot tell them apart)."""
    out = []
    for T in poses:
        x = transform_points(invert_pose(T), X) @ cam.K.T
        out.append(x[:, :2] / x[:, 2:3])
    return np.stack(out, axis=1)


def _points(rng, n):
    return np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)]


POSES = [np.eye(4), _pose([0, 0.1, 0], [0.4, 0, 0]), _pose([0.05, -0.1, 0], [-0.3, 0.1, 0]),
         _pose([0.02, 0.03, 0.1], [0.1, -0.3, 0.2])]


@pytest.mark.parametrize("n_views", [2, 3, 4])
def test_exact_recovery_on_noise_free_views(n_views):
    X = _points(np.random.default_rng(n_views), 200)
    poses = POSES[:n_views]
    Y = triangulate(CAM, poses, _pixels(CAM, poses, X), 1e-6, 0.5)
    assert np.allclose(Y, X, atol=1e-9)
    # in another world frame (every pose moved by one rigid motion) the points move too
    W = _pose([0.3, -0.2, 0.1], [1.0, 2.0, -0.5])
    Yw = triangulate(CAM, [W @ T for T in poses], _pixels(CAM, poses, X), 1e-6, 0.5)
    assert np.allclose(Yw, transform_points(W, X), atol=1e-9)


def test_tracks_seen_by_some_views_and_by_one():
    rng = np.random.default_rng(0)
    X = _points(rng, 300)
    x = _pixels(CAM, POSES, X)
    x[rng.random(x.shape[:2]) < 0.4] = np.nan
    n_seen = np.sum(np.isfinite(x[..., 0]), axis=1)
    Y = triangulate(CAM, POSES, x, 1e-6)
    assert np.allclose(Y[n_seen >= 2], X[n_seen >= 2], atol=1e-9)
    assert np.all(np.isnan(Y[n_seen < 2])) and np.any(n_seen < 2)
    # zero rows of the unseen views leave the solution: the same as the seen views alone
    for k in np.flatnonzero(n_seen >= 2)[:20]:
        views = np.flatnonzero(np.isfinite(x[k, :, 0]))
        alone = dlt_points(CAM.K, [POSES[v] for v in views], x[k:k + 1, views])
        assert np.allclose(alone, dlt_points(CAM.K, POSES, x[k:k + 1]), atol=1e-9)


def test_cheirality_refuses_points_behind_a_camera():
    rng = np.random.default_rng(1)
    X = _points(rng, 100)
    X[::2, 2] *= -1                          # half of the points behind both cameras
    T2 = _pose([0, 0.05, 0], [0.3, 0, 0])
    Y = triangulate(CAM, [np.eye(4), T2], _pixels(CAM, [np.eye(4), T2], X))
    assert np.allclose(dlt_points(CAM.K, [np.eye(4), T2], _pixels(CAM, [np.eye(4), T2], X)),
                       X, atol=1e-9)        # the DLT finds them; the gate refuses them
    assert np.all(np.isnan(Y[::2])) and np.allclose(Y[1::2], X[1::2], atol=1e-9)
    # in front of the first camera, behind the second (it faces away)
    back = _pose([0, np.pi, 0], [0.3, 0, -3.0])
    assert np.all(np.isnan(triangulate(CAM, [np.eye(4), back],
                                       _pixels(CAM, [np.eye(4), back], X[1::2]))))


def test_parallax_gate_refuses_rays_below_the_angle():
    rng = np.random.default_rng(2)
    X = np.c_[rng.uniform(-20, 20, 400), rng.uniform(-15, 15, 400), rng.uniform(2, 60, 400)]
    T2 = _pose([0, 0.02, 0], [0.5, 0, 0])
    x = _pixels(CAM, [np.eye(4), T2], X)
    angle = ray_angles_deg(X, np.zeros(3), T2[:3, 3])
    assert np.any(angle < 1.0) and np.any(angle > 1.0)
    Y = triangulate(CAM, [np.eye(4), T2], x, 1e-6, 1.0)
    assert np.array_equal(np.isfinite(Y[:, 0]), angle >= 1.0)
    assert np.allclose(Y[angle >= 1.0], X[angle >= 1.0], atol=1e-8)
    # no baseline: no angle, no point
    assert np.all(np.isnan(triangulate(CAM, [np.eye(4), np.eye(4)], x, 4.0, 0.5)))
    # multi-view: the largest angle of the pairs that see the point
    seen = np.ones((len(X), 3), bool)
    seen[:, 1] = False
    three = max_ray_angle_deg(X, np.stack([np.zeros(3), T2[:3, 3], 2 * T2[:3, 3]]), seen)
    assert np.allclose(three, ray_angles_deg(X, np.zeros(3), 2 * T2[:3, 3]))


def test_reprojection_gate_in_every_view_that_sees_the_point():
    X = _points(np.random.default_rng(3), 50)
    x = _pixels(CAM, POSES[:3], X)
    x[:10, 2] += [6.0, 0.0]                  # view 2 disagrees by 6 px
    assert np.all(np.isnan(triangulate(CAM, POSES[:3], x, 2.0)[:10]))
    assert np.all(np.isfinite(triangulate(CAM, POSES[:3], x)))       # no bound
    x[:10, 2] = np.nan                        # without view 2 they agree again
    assert np.allclose(triangulate(CAM, POSES[:3], x, 2.0), X, atol=1e-9)


def test_shapes_and_empty_inputs():
    assert triangulate(CAM, POSES[:2], np.zeros((0, 2, 2))).shape == (0, 3)
    with pytest.raises(ValueError, match="pixels"):
        triangulate(CAM, POSES[:2], np.zeros((5, 3, 2)))
    with pytest.raises(ValueError, match="T_world_cams"):
        triangulate(CAM, np.eye(4), np.zeros((5, 1, 2)))


# ------------------------------------------------------- the triangulators it replaced
def _old_vo(cam, T1, T2, x1, x2, tol, min_parallax_deg):
    """spgeo.vo.landmarks.triangulate and LandmarkMap._match_pair's gates at 2401dea."""
    K = np.asarray(cam.K, dtype=np.float64)
    rows = []
    for T, x in ((T1, x1), (T2, x2)):
        P = K @ np.linalg.inv(T)[:3]
        rows += [x[:, 0:1] * P[2] - P[0], x[:, 1:2] * P[2] - P[1]]
    h = np.linalg.svd(np.stack(rows, 1))[2][:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = np.where(np.abs(h[:, 3:4]) > 1e-12, h[:, :3] / h[:, 3:4], np.nan)
    ok = np.all(np.isfinite(X), 1)
    Xs = np.where(ok[:, None], X, 0.0)
    for T, x in ((T1, x1), (T2, x2)):
        uv, z = cam.project(transform_points(invert_pose(T), Xs))
        ok &= (z > 0) & (np.linalg.norm(uv - x, axis=1) <= tol)
    ok &= ray_angles_deg(Xs, T1[:3, 3], T2[:3, 3]) >= min_parallax_deg
    return np.where(ok[:, None], X, np.nan)


def _old_tracks(cam, poses, x, gate_px=4.0, min_deg=0.5):
    """spgeo.sfm.bundle.triangulate_tracks at 2401dea, on (L, V, 2) pixels."""
    A = np.zeros((len(x), 2 * len(poses), 4))
    for k, T in enumerate(poses):
        P = cam.K @ invert_pose(T)[:3]
        seen = np.isfinite(x[:, k, 0])
        A[seen, 2 * k] = x[seen, k, 0:1] * P[2] - P[0]
        A[seen, 2 * k + 1] = x[seen, k, 1:2] * P[2] - P[1]
    h = np.linalg.svd(A)[2][:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = h[:, :3] / h[:, 3:4]
    ok = (np.sum(np.isfinite(x[..., 0]), axis=1) >= 2) & np.all(np.isfinite(X), axis=1)
    Xs = np.where(ok[:, None], X, 0.0)
    dirs = []
    for k, T in enumerate(poses):
        seen = np.isfinite(x[:, k, 0])
        uv, z = cam.project(transform_points(invert_pose(T), Xs))
        ok &= ~seen | ((z > 0) & (np.linalg.norm(uv - x[:, k], axis=1) <= gate_px))
        d = Xs - T[:3, 3]
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        dirs.append(np.where(seen[:, None], d, np.nan))
    D = np.stack(dirs, 1)
    cos = np.einsum("lvc,lwc->lvw", D, D)
    ok &= np.nanmin(np.where(np.isfinite(cos), cos, np.inf), axis=(1, 2)) <= np.cos(
        np.radians(min_deg))
    return np.where(ok[:, None], X, np.nan)


def _old_depths(T_ref_tgt, cam, pts_ref, pts_tgt):
    """spgeo.sfm.init.triangulate_depths at 2401dea (OpenCV, normalised coordinates)."""
    T_tr = invert_pose(T_ref_tgt)
    x1 = (np.c_[pts_ref, np.ones(len(pts_ref))] @ cam.K_inv.T)[:, :2].T
    x2 = (np.c_[pts_tgt, np.ones(len(pts_tgt))] @ cam.K_inv.T)[:, :2].T
    Xh = cv2.triangulatePoints(np.eye(3, 4), T_tr[:3], x1, x2)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T
        z_tgt = X @ T_tr[2, :3] + T_tr[2, 3]
        return np.where((X[:, 2] > 0) & (z_tgt > 0), X[:, 2], np.nan)


def _random_views(rng, cam, n_views, n=1500, noise=1.0, missing=0.0):
    """Random poses (the first the identity), points near and far, some behind the
    cameras, their noisy (and, with ``missing``, partly unseen) pixels."""
    poses = [np.eye(4)] + [_pose(rng.normal(0, 0.08, 3), rng.normal(0, 0.4, 3))
                           for _ in range(n_views - 1)]
    far = rng.choice([1.0, 1.0, 1.0, 40.0], n)
    X = np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(-1, 8, n) * far]
    x = _pixels(cam, poses, X) + rng.normal(0, noise, (n, n_views, 2))
    x[rng.random((n, n_views)) < missing] = np.nan
    return poses, x


@pytest.mark.parametrize("cam", [CAM, SQUARE])
def test_same_points_as_the_vo_triangulator(cam):
    """The VO's pair: the same points refused; the points differ only by the
    rounding of ``np.linalg.inv`` (then) and ``invert_pose`` (now) of the poses."""
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(10):
        poses, x = _random_views(rng, cam, 2, noise=rng.choice([0.0, 0.5, 2.0]))
        new = triangulate(cam, poses, x, 2.0, 1.0)
        old = _old_vo(cam, poses[0], poses[1], x[:, 0], x[:, 1], 2.0, 1.0)
        assert np.array_equal(np.isnan(new), np.isnan(old)) and np.any(np.isfinite(new))
        worst = max(worst, np.nanmax(np.abs(new - old)))
    assert worst < 1e-10


@pytest.mark.parametrize("cam", [CAM, SQUARE])
def test_identical_to_the_bundle_triangulator(cam):
    rng = np.random.default_rng(5)
    for n_views in (2, 3, 4, 5):
        poses, x = _random_views(rng, cam, n_views, noise=1.0, missing=0.3)
        new = triangulate(cam, poses, x, 4.0, 0.5)
        assert np.any(np.isfinite(new))
        assert np.array_equal(new, _old_tracks(cam, poses, x), equal_nan=True)


def test_depths_as_the_opencv_triangulator_up_to_the_pixel_weighting():
    """The two-view initialisation's depths were OpenCV's DLT in normalised
    coordinates; the pixel rows are those times ``fx`` (u) and ``fy`` (v).  With
    ``fx == fy`` the depths agree to rounding; with TUM's ``fx / fy = 1.0015`` noisy
    matches weigh their u and v residuals differently: the depth of a point with at
    least 1 degree of parallax moves by well under 1 % (measured 3e-4 at 0.5 px noise)."""
    rng = np.random.default_rng(6)
    for cam, noise, tol in ((SQUARE, 1.0, 1e-9), (CAM, 0.0, 1e-9), (CAM, 0.5, 1e-3)):
        poses, x = _random_views(rng, cam, 2, noise=noise)
        new = triangulate_depths(poses[1], cam, x[:, 0], x[:, 1])
        old = _old_depths(poses[1], cam, x[:, 0], x[:, 1])
        ang = ray_angles_deg(dlt_points(cam.K, poses, x), np.zeros(3), poses[1][:3, 3])
        both = np.isfinite(new) & np.isfinite(old) & (ang >= 1.0)
        assert np.sum(np.isnan(new) != np.isnan(old)) <= 1 and both.sum() > 500
        assert np.max(np.abs(new[both] - old[both]) / old[both]) < tol
