"""Tests of the model-free front-end pieces: ClassicalSegmenter, DepthNormalEstimator,
FrontoParallelNormals."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage

from spgeo.camera import PinholeCamera
from spgeo.frontend.base import NormalEstimator, Segmenter
from spgeo.frontend.classical import (METHODS, ClassicalSegmenter, ClassicalSegmenterConfig,
                                      split_connected_labels)
from spgeo.frontend.depth_normals import (DepthNormalEstimator, DepthNormalEstimatorConfig,
                                          FrontoParallelNormals)


# ----------------------------------------------------------------------------- helpers
def rectangles_image(width: int = 160, height: int = 120, n: int = 12, seed: int = 0,
                     noise: float = 0.01):
    """Piecewise-constant colour image of overlapping rectangles and its region ids."""
    rng = np.random.default_rng(seed)
    ids = np.zeros((height, width), np.int32)
    colours = [rng.random(3)]
    for i in range(1, n + 1):
        x0, y0 = rng.integers(0, width - 20), rng.integers(0, height - 20)
        x1 = min(width, x0 + rng.integers(15, width // 2))
        y1 = min(height, y0 + rng.integers(15, height // 2))
        ids[y0:y1, x0:x1] = i
        # well separated colours
        colours.append(np.clip(colours[-1] + rng.choice([-1, 1], 3) * rng.uniform(0.25, 0.5, 3),
                               0, 1) if i % 2 else rng.random(3))
    img = np.asarray(colours, np.float64)[ids]
    img = img + rng.normal(0.0, noise, img.shape)
    return np.clip(img, 0, 1).astype(np.float32), ids


def leakage(seg_regions, ids: np.ndarray) -> float:
    """Fraction of covered pixels outside their region's majority id (1 - ASA)."""
    flat = ids.ravel()
    bad = total = 0
    for r in seg_regions:
        counts = np.bincount(flat[r])
        bad += r.size - counts.max()
        total += r.size
    return bad / total


def is_4connected(mask: np.ndarray) -> bool:
    return ndimage.label(mask)[1] == 1


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def plane_depth(camera: PinholeCamera, n, d: float) -> np.ndarray:
    """Depth of the plane ``n . X = d`` (n towards the camera, d < 0)."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    return d / (camera.rays() @ n), n


CAM_QVGA = PinholeCamera(300.0, 260.0, 171.3, 108.6, 320, 240)  # fx != fy, off-centre


@pytest.fixture(scope="module")
def rect_case():
    img, ids = rectangles_image()
    return img, ids, PinholeCamera(150.0, 150.0, 79.5, 59.5, 160, 120)


# ----------------------------------------------------------------------------- segmenter
def test_protocols():
    assert isinstance(ClassicalSegmenter(), Segmenter)
    assert isinstance(DepthNormalEstimator(), NormalEstimator)
    assert isinstance(FrontoParallelNormals(), NormalEstimator)
    assert DepthNormalEstimator.uses_depth is True
    assert FrontoParallelNormals.uses_depth is False


@pytest.mark.parametrize("method", METHODS)
def test_each_method_partitions_into_connected_regions(method, rect_case):
    img, _, cam = rect_case
    cfg = ClassicalSegmenterConfig(method=method, num_segments=60, small_components="merge")
    seg = ClassicalSegmenter(cfg).segment(img, cam)
    h, w = cam.shape
    assert (seg.height, seg.width) == (h, w)
    assert len(seg) >= 2
    # exact partition ("merge" is the default)
    np.testing.assert_array_equal(seg.coverage(), np.ones((h, w), np.int32))
    assert seg.meta["coverage"] == 1.0
    np.testing.assert_array_equal(seg.scores, 1.0)
    min_area = cfg.min_area_frac * h * w
    for i in range(len(seg)):
        m = seg.mask(i)
        assert is_4connected(m), f"region {i} is not 4-connected"
        assert m.ravel()[seg.anchors[i]], f"anchor {i} outside its region"
        assert seg.regions[i].size >= min_area


def test_anchor_is_interior(rect_case):
    img, _, cam = rect_case
    seg = ClassicalSegmenter().segment(img, cam)
    for i in range(len(seg)):
        m = seg.mask(i)
        dist = cv2.distanceTransform(np.pad(m, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
        # most interior pixel, up to the boundary convention (one pixel)
        assert dist.ravel()[seg.anchors[i]] >= dist.max() - 1.01


@pytest.mark.parametrize("method", ["graph", "seeds"])
def test_drop_small_components_coverage(method):
    rng = np.random.default_rng(3)
    img = rectangles_image(80, 60, n=6, seed=2, noise=0.0)[0]
    img = np.clip(img + rng.normal(0, 0.15, img.shape), 0, 1).astype(np.float32)  # noisy
    cam = PinholeCamera(80.0, 80.0, 39.5, 29.5, 80, 60)
    cfg = ClassicalSegmenterConfig(method=method, num_segments=100, min_area_frac=0.01)
    assert cfg.small_components == "drop"  # the documented default
    seg = ClassicalSegmenter(cfg).segment(img, cam)
    cov = seg.coverage()
    assert cov.max() == 1  # no overlaps
    assert np.isclose(seg.meta["coverage"], cov.mean())
    labels, keep, _, meta = ClassicalSegmenter(cfg).label_image(img, cam)
    area = np.bincount(labels.ravel())
    expected = area >= 0.01 * 80 * 60
    if not expected.any():  # documented fallback: the largest component is kept
        expected[np.argmax(area)] = True
    else:
        assert all(r.size >= 0.01 * 80 * 60 for r in seg.regions)
    for i in range(len(seg)):
        assert is_4connected(seg.mask(i))
        assert seg.mask(i).ravel()[seg.anchors[i]]
    # the uncovered pixels are exactly those of the small components
    np.testing.assert_array_equal(keep, expected)
    np.testing.assert_array_equal(cov.ravel() == 0, ~keep[labels.ravel()])
    assert meta["num_small"] == np.count_nonzero(area < 0.01 * 80 * 60)


def test_default_segmenter_covers_almost_everything(rect_case):
    img, _, cam = rect_case
    seg = ClassicalSegmenter().segment(img, cam)
    cov = seg.coverage()
    assert cov.max() == 1
    assert cov.mean() > 0.97
    min_area = 1e-3 * cam.width * cam.height
    assert all(r.size >= min_area for r in seg.regions)


def test_deterministic(rect_case):
    img, _, cam = rect_case
    for method in ("graph", "slic", "seeds"):
        a = ClassicalSegmenter(method=method).segment(img, cam)
        b = ClassicalSegmenter(method=method).segment(img, cam)
        assert len(a) == len(b)
        np.testing.assert_array_equal(a.anchors, b.anchors)
        for ra, rb in zip(a.regions, b.regions):
            np.testing.assert_array_equal(ra, rb)


def test_default_low_undersegmentation_on_piecewise_constant_image(rect_case):
    img, ids, cam = rect_case
    seg = ClassicalSegmenter().segment(img, cam)
    assert leakage(seg.regions, ids) < 0.01
    assert len(seg) < 300


def test_working_width_downscales_640():
    img, ids = rectangles_image(640, 480, n=20, seed=1)
    cam = PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480)
    segmenter = ClassicalSegmenter()  # working_width=320
    segmenter.segment(img, cam)
    seg = segmenter.segment(img, cam)
    assert seg.meta["working_size"] == (320, 240)
    assert seg.coverage().max() == 1 and seg.coverage().mean() > 0.97
    assert leakage(seg.regions, ids) < 0.02
    labels = np.full(640 * 480, -1)
    for i, r in enumerate(seg.regions):
        labels[r] = i
    assert np.all(labels[seg.anchors] == np.arange(len(seg)))
    comp, _ = split_connected_labels(labels.reshape(480, 640))
    # every region is one 4-connected component
    assert np.unique(comp.ravel()[labels >= 0]).size == len(seg)
    assert seg.meta["time_s"] < 2.0  # generous bound


def test_grey_image_and_full_resolution(rect_case):
    img, _, cam = rect_case
    grey = img.mean(axis=2)
    seg = ClassicalSegmenter(working_width=None, small_components="merge").segment(grey, cam)
    np.testing.assert_array_equal(seg.coverage(), 1)


def test_split_connected_labels():
    labels = np.array([[0, 0, 1, 0],
                       [1, 1, 1, 0],
                       [2, 1, 2, 2]])
    comp, n = split_connected_labels(labels)
    # label 0: {(0,0),(0,1)} and {(0,3),(1,3)}; label 1: one piece; label 2: two pieces
    assert n == 5
    assert comp[0, 0] == comp[0, 1] != comp[0, 3] == comp[1, 3]
    assert comp[2, 0] != comp[2, 2] == comp[2, 3]
    # diagonal contact does not connect
    comp, n = split_connected_labels(np.array([[0, 1], [1, 0]]))
    assert n == 4


def test_merge_small_into_longest_boundary_neighbour():
    from spgeo.frontend.classical import _merge_small

    labels = np.zeros((20, 20), np.int32)
    labels[:, 10:] = 1
    labels[5:7, 9:12] = 2    # 6 px: shares 2 px of boundary with 0, 4 with... 1 more
    labels[15:17, 0:2] = 3   # 4 px in the corner of region 0
    labels[0, 19] = 4        # 1 px in the corner of region 1
    merged, n = _merge_small(labels, 5, min_area=10)
    assert n == 2
    np.testing.assert_array_equal(merged[labels == 3], merged[0, 0])
    np.testing.assert_array_equal(merged[labels == 4], merged[0, 10])
    # blob 2: boundary with label 1 (right side + top/bottom of columns 10-11)
    # is longer than with label 0 (left side + top/bottom of column 9)
    np.testing.assert_array_equal(merged[labels == 2], merged[0, 10])
    assert merged[0, 0] != merged[0, 10]


def test_segmenter_bad_input(rect_case):
    img, _, cam = rect_case
    s = ClassicalSegmenter()
    bad = img.copy()
    bad[3, 4, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        s.segment(bad, cam)
    with pytest.raises(ValueError, match="shape"):
        s.segment(img[:100], cam)
    with pytest.raises(ValueError):
        s.segment(np.zeros((120, 160, 2), np.float32), cam)
    with pytest.raises(ValueError, match="method"):
        ClassicalSegmenterConfig(method="watershed")
    with pytest.raises(ValueError):
        ClassicalSegmenterConfig(small_components="keep")
    with pytest.raises(ValueError):
        ClassicalSegmenterConfig(min_area_frac=-1)


# ----------------------------------------------------------------------------- normals
@pytest.mark.parametrize("method", ["pca", "differences"])
def test_plane_normal_exact_with_anisotropic_offcentre_camera(method):
    z, n = plane_depth(CAM_QVGA, [0.35, -0.45, -0.8], -2.0)
    assert np.all(z > 0)
    normals = DepthNormalEstimator(method=method).estimate(None, CAM_QVGA, z)
    assert normals.dtype == np.float32 and normals.shape == (240, 320, 3)
    assert np.all(np.isfinite(normals))
    assert angle_deg(normals, n).max() < 0.1
    # towards the camera
    assert np.all(np.sum(normals * CAM_QVGA.rays(), axis=-1) < 0)


def test_normal_orientation_flips_towards_camera():
    # same plane, normal given pointing away: the estimate still faces the camera
    z, n = plane_depth(CAM_QVGA, [0.1, 0.2, -1.0], -3.0)
    normals = DepthNormalEstimator().estimate(None, CAM_QVGA, z)
    assert np.median(angle_deg(normals, n)) < 0.1
    assert np.all(normals[..., 2] < 0)


def sphere_scene(camera: PinholeCamera, centre=(0.3, -0.2, 3.0), radius=1.0, wall=6.0):
    rays = camera.rays()
    c = np.asarray(centre, float)
    rc = rays @ c
    rr = np.sum(rays * rays, axis=-1)
    disc = rc ** 2 - rr * (c @ c - radius ** 2)
    hit = disc > 0
    t = np.where(hit, (rc - np.sqrt(np.where(hit, disc, 0))) / rr, np.inf)
    z = np.where(hit, t, wall)
    pts = rays * z[..., None]
    n_true = np.where(hit[..., None], (pts - c) / radius, np.array([0.0, 0.0, -1.0]))
    return z, n_true, hit


def test_sphere_normals_and_silhouette():
    z, n_true, hit = sphere_scene(CAM_QVGA)
    for method in ("pca", "differences"):
        normals = DepthNormalEstimator(method=method).estimate(None, CAM_QVGA, z)
        err = angle_deg(normals, n_true)
        # away from the silhouette (depth discontinuity)
        edge = ndimage.binary_dilation(hit ^ ndimage.binary_erosion(hit), iterations=3)
        inner = hit & ~edge
        assert np.median(err[inner]) < 1.0, method
        assert np.percentile(err[inner], 95) < 3.0, method
        # background wall next to the sphere is not tilted beyond 2 px
        bg = ~hit & ~ndimage.binary_dilation(hit, iterations=2)
        assert err[bg].max() < 0.1, method


@pytest.mark.parametrize("method", ["pca", "differences"])
def test_step_edge_does_not_tilt_normals(method):
    cam = PinholeCamera(150.0, 140.0, 82.0, 57.0, 160, 120)
    z = np.full((120, 160), 2.0)
    z[:, 80:] = 2.6
    z[60:, :40] = 1.5
    normals = DepthNormalEstimator(method=method).estimate(None, cam, z)
    err = angle_deg(normals, np.array([0.0, 0.0, -1.0]))
    step = np.zeros_like(z, dtype=bool)
    step[:, 78:82] = True
    step[58:62, :40] = True
    step[60:, 38:42] = True
    far = ~ndimage.binary_dilation(step, iterations=1)  # > 1-2 px from the edge
    assert err[far].max() < 0.1
    assert np.all(np.isfinite(normals))


@pytest.mark.parametrize("method", ["pca", "differences"])
def test_holes_do_not_spread(method):
    z, n = plane_depth(CAM_QVGA, [0.2, -0.3, -0.9], -2.5)
    hole = np.zeros(z.shape, bool)
    yy, xx = np.mgrid[0:240, 0:320]
    hole |= (yy - 100) ** 2 + (xx - 150) ** 2 < 12 ** 2
    hole[30:40, 250:270] = True
    hole[200:, :5] = True  # at the image border
    z_nan = z.copy()
    z_nan[hole] = np.nan
    z_nan[30:40, 250:270] = 0.0  # zero depth = invalid too
    normals = DepthNormalEstimator(method=method).estimate(None, CAM_QVGA, z_nan)
    unknown = ~np.isfinite(normals).all(axis=-1)
    assert np.all(unknown[hole])
    # at most a 1-pixel border of unknown normals around the holes
    assert not np.any(unknown & ~ndimage.binary_dilation(hole, iterations=1))
    known = ~unknown
    assert angle_deg(normals[known], n).max() < 0.1
    filled = DepthNormalEstimator(method=method, fill_holes=True).estimate(None, CAM_QVGA, z_nan)
    assert np.all(np.isfinite(filled))
    assert angle_deg(filled, n).max() < 0.1


def test_noisy_plane_pca_is_robust():
    z, n = plane_depth(CAM_QVGA, [0.2, -0.1, -1.0], -2.0)
    rng = np.random.default_rng(0)
    z_noisy = z * (1 + rng.normal(0, 5e-4, z.shape))
    pca = DepthNormalEstimator(method="pca", window=7).estimate(None, CAM_QVGA, z_noisy)
    diff = DepthNormalEstimator(method="differences").estimate(None, CAM_QVGA, z_noisy)
    e_pca = np.median(angle_deg(pca, n))
    assert e_pca < 5.0
    assert e_pca < np.median(angle_deg(diff, n))


def test_differences_smoothing_and_no_edge_test_options():
    z, n = plane_depth(CAM_QVGA, [0.2, -0.1, -1.0], -2.0)
    rng = np.random.default_rng(1)
    z_noisy = z * (1 + rng.normal(0, 5e-4, z.shape))
    raw = DepthNormalEstimator(method="differences").estimate(None, CAM_QVGA, z_noisy)
    smooth = DepthNormalEstimator(method="differences", smooth=True).estimate(None, CAM_QVGA,
                                                                             z_noisy)
    assert np.median(angle_deg(smooth, n)) < np.median(angle_deg(raw, n))
    for method in ("pca", "differences"):
        out = DepthNormalEstimator(method=method, max_incidence_deg=None).estimate(
            None, CAM_QVGA, z)
        assert angle_deg(out, n).max() < 0.1


def test_depth_normals_bad_input():
    est = DepthNormalEstimator()
    z = np.full((240, 320), 2.0)
    with pytest.raises(ValueError, match="depth"):
        est.estimate(None, CAM_QVGA, None)
    with pytest.raises(ValueError, match="shape"):
        est.estimate(None, CAM_QVGA, z[:100])
    with pytest.raises(ValueError):
        est.estimate(None, CAM_QVGA, np.zeros((240, 320, 3)))
    with pytest.raises(ValueError, match="valid"):
        est.estimate(None, CAM_QVGA, np.full((240, 320), np.nan))
    with pytest.raises(ValueError, match="valid"):
        est.estimate(None, CAM_QVGA, np.zeros((240, 320)))
    with pytest.raises(ValueError, match="shape"):
        est.estimate(np.zeros((10, 10, 3), np.float32), CAM_QVGA, z)
    with pytest.raises(ValueError):
        DepthNormalEstimatorConfig(window=4)
    with pytest.raises(ValueError):
        DepthNormalEstimatorConfig(method="sobel")


def test_fronto_parallel_normals():
    img = np.zeros((240, 320, 3), np.float32)
    out = FrontoParallelNormals().estimate(img, CAM_QVGA)
    assert out.dtype == np.float32 and out.shape == (240, 320, 3)
    np.testing.assert_array_equal(out, np.broadcast_to([0, 0, -1], out.shape))
    with pytest.raises(ValueError):
        FrontoParallelNormals().estimate(img[:10], CAM_QVGA)


# ----------------------------------------------------------------------------- synthetic
def test_depth_normals_on_synthetic_render():
    synthetic = pytest.importorskip("spgeo.synthetic")
    scene = synthetic.SyntheticScene.generate(0)
    cam = synthetic.default_camera(160, 120)
    T = synthetic.make_trajectory(1, 0)[0]
    view = scene.render(cam, T)
    normals = DepthNormalEstimator().estimate(view.rgb, cam, view.depth)
    valid = view.valid & np.isfinite(normals).all(axis=-1)
    assert valid.mean() > 0.95
    err = angle_deg(normals[valid], view.normals[valid].astype(np.float64))
    assert np.median(err) < 2.0
    # segmenter on the same render: partition, low leakage across surfaces
    seg = ClassicalSegmenter().segment(view.rgb, cam)
    assert seg.coverage().max() == 1 and seg.coverage().mean() > 0.9
    assert leakage(seg.regions, view.surface_ids + 1) < 0.05
