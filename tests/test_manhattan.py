"""Vanishing-point (Manhattan) normals: line segments, vanishing directions, per-region normals."""
import numpy as np
import pytest

from spgeo.frontend import FRONTENDS, make_frontend
from spgeo.frontend.classical import ClassicalSegmenter
from spgeo.frontend.lines import LineDetectorConfig, LineSegments, detect_line_segments
from spgeo.frontend.manhattan import ManhattanNormals, ManhattanNormalsConfig, SharedSegmenter
from spgeo.frontend.vanishing import VanishingConfig, estimate_vanishing_directions

from spgeo.synthetic import default_camera

CAM = default_camera(320, 240)


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


def _segments_along(directions, n_per, rng, clutter=0):
    """Projected 3-D segments parallel to ``directions`` plus random clutter."""
    ends = []
    for d in directions:
        for _ in range(n_per):
            p = np.array([rng.uniform(-2, 2), rng.uniform(-1.5, 1.5), rng.uniform(3, 6)])
            q = p + rng.uniform(0.6, 1.2) * np.asarray(d)
            if q[2] < 1:
                continue
            uv = [CAM.fx * x[0] / x[2] + CAM.cx for x in (p, q)], \
                 [CAM.fy * x[1] / x[2] + CAM.cy for x in (p, q)]
            ends.append([uv[0][0], uv[1][0], uv[0][1], uv[1][1]])
    for _ in range(clutter):
        c = rng.uniform([0, 0], [320, 240])
        a = rng.uniform(0, np.pi)
        ends.append([*c, *(c + 20 * np.array([np.cos(a), np.sin(a)]))])
    ends = np.array(ends)
    ends += rng.normal(0, 0.2, ends.shape)
    return LineSegments(ends, 320, 240)


def _rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_vanishing_recovers_manhattan_frame():
    rng = np.random.default_rng(3)
    R = _rotation(rng)
    segs = _segments_along(R.T, 25, rng, clutter=15)
    res = estimate_vanishing_directions(segs, CAM, VanishingConfig(seed=1))
    assert res.manhattan
    frame = res.directions[:3]
    assert np.allclose(frame @ frame.T, np.eye(3), atol=1e-6)
    for axis in R.T:
        assert min(_angle_deg(axis, d) for d in frame) < 1.0
    again = estimate_vanishing_directions(segs, CAM, VanishingConfig(seed=1))
    assert np.array_equal(res.directions, again.directions)


def test_vanishing_tolerates_non_orthogonal_directions():
    rng = np.random.default_rng(5)
    a = np.array([1.0, 0.1, 0.3])
    b = np.array([np.cos(1.0), 0.0, np.sin(1.0)])  # about 40 degrees from a
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    segs = _segments_along([a, b], 30, rng)
    res = estimate_vanishing_directions(segs, CAM)
    for d in (a, b):
        assert min(_angle_deg(d, e) for e in res.directions) < 1.0


def test_no_lines_gives_all_unknown():
    mh = ManhattanNormals()
    seg_er = ClassicalSegmenter()
    rng = np.random.default_rng(0)
    for image in (np.full((240, 320, 3), 0.5, np.float32),
                  rng.uniform(0, 1, (240, 320, 3)).astype(np.float32)):
        seg = seg_er.segment(image, CAM)
        est = mh.analyse(image, CAM, seg)
        assert not est.known.any()
        assert np.all(est.normals == np.array([0, 0, -1], np.float32))
        assert np.all(est.segment_confidence == 0)
        assert est.normals.dtype == np.float32
    assert len(detect_line_segments(np.zeros((240, 320)), LineDetectorConfig())) == 0
    assert len(estimate_vanishing_directions(LineSegments(np.zeros((0, 4)), 320, 240),
                                             CAM)) == 0


def _manhattan_view():
    from spgeo.synthetic import (BoxSpec, SceneConfig, SyntheticScene, TextureConfig,
                                 camera_rotation)

    cfg = SceneConfig(texture=TextureConfig(patterns=("checker",)))
    scene = SyntheticScene.build([BoxSpec((1.5, 1.0, 0.4), (0.8, 0.6, 0.8)),
                                  BoxSpec((1.8, -1.2, 0.6), (0.6, 0.9, 1.2)),
                                  BoxSpec((-0.5, 2.0, 0.3), (1.0, 0.5, 0.6)),
                                  BoxSpec((2.2, 0.0, 1.2), (0.5, 1.2, 0.6))], cfg, seed=1)
    T = np.eye(4)
    T[:3, :3] = camera_rotation(-0.3, -0.35, 0.03)
    T[:3, 3] = [-0.5, 0.0, 1.5]
    return scene.render(CAM, T), T


def test_synthetic_manhattan_room_normals():
    view, T = _manhattan_view()
    seg = ClassicalSegmenter().segment(view.rgb, CAM)
    est = ManhattanNormals().estimate_for_segmentation(view.rgb, CAM, seg)
    # an orthogonal frame is found; the checker textures are rotated in their
    # planes, so only some of its axes need to be room axes (rows of
    # R_world_cam: the world axes in the camera frame)
    assert est.vanishing.manhattan
    assert min(_angle_deg(axis, d) for axis in T[:3, :3] for d in est.directions[:3]) < 3.0
    ok = est.known & view.valid
    assert ok.mean() > 0.25
    err = np.degrees(np.arccos(np.clip(np.sum(est.normals * view.normals, -1), -1, 1)))[ok]
    assert np.median(err) < 10.0
    # unit normals towards the camera
    rays = CAM.rays()
    assert np.allclose(np.linalg.norm(est.normals, axis=-1), 1.0, atol=1e-5)
    assert np.all(np.sum(est.normals * rays, -1)[est.known] < 0)
    # per-region results: normals, confidences, hypothesis lists
    assert est.segment_normals.shape == (len(seg), 3)
    acc = est.segment_confidence > 0
    assert acc.any() and np.all(est.segment_confidence <= 1.0)
    assert all(len(est.segment_hypotheses[i]) > 0 for i in np.flatnonzero(acc))
    assert est.pixel_label.shape == (240, 320) and est.pixel_label.min() >= -1


def test_frontend_manhattan_segments_once():
    assert "manhattan" in FRONTENDS
    view, _ = _manhattan_view()
    fe = make_frontend("manhattan")
    assert not fe.uses_depth
    calls = []
    inner = fe.segmenter.segmenter
    fe.segmenter.segmenter = type("Counting", (), {
        "segment": lambda self, im, cam: calls.append(1) or inner.segment(im, cam)})()
    prims = fe.primify(view.rgb, CAM)
    assert len(prims) > 0 and len(calls) == 1
    assert isinstance(fe.segmenter, SharedSegmenter)
    normals = fe.normal_estimator.estimate(view.rgb, CAM)
    assert normals.shape == (240, 320, 3) and normals.dtype == np.float32


def test_config_validation():
    with pytest.raises(ValueError, match="min_pair_angle_deg"):
        ManhattanNormalsConfig(min_pair_angle_deg=0.0)
    with pytest.raises(ValueError, match="inlier_angle_deg"):
        VanishingConfig(inlier_angle_deg=50.0)
    with pytest.raises(ValueError, match="method"):
        LineDetectorConfig(method="hough")
    with pytest.raises(ValueError, match="segmentation"):
        from spgeo.frontend.base import Segmentation
        ManhattanNormals().analyse(np.zeros((240, 320)), CAM,
                                   Segmentation(10, 10, [np.arange(5)], [0], [1.0]))
