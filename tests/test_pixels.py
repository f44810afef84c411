"""DSO-style pixel selection (spgeo.vo.pixels) and its use by the keyframes
(tracking) and the window mapper (mapping factors)."""
import cv2
import gtsam
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frontend import make_frontend
from spgeo.vo import OdometryConfig, MappingConfig
from spgeo.graph.keys import pose_key, scale_key, support_brightness_key, support_pose_key
from spgeo.vo.map import MapKeyframe
from spgeo.vo.smoother import WindowMapper
from spgeo.vo.pixels import PixelSelectionConfig, gradient_magnitude, select_pixels
from spgeo.vo.tracking import (Keyframe, TrackerConfig, TrackingCost, valid_fraction,
                               track_frame)

H, W, CELL = 240, 320, 40
TEXTURED_COLS = 240       # columns >= this are flat: their primitives have no texture


@pytest.fixture(scope="module")
def image():
    """Smooth noise on the left, a flat area on the right (two primitive columns)."""
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 2.0)
    img = 0.2 + 0.6 * (img - img.min()) / (img.max() - img.min())
    img[:, TEXTURED_COLS - CELL:] = 0.5
    return img


@pytest.fixture(scope="module")
def grid():
    """Every pixel a candidate; primitives are CELL x CELL squares."""
    rr, cc = np.mgrid[0:H, 0:W]
    rows, cols = rr.ravel(), cc.ravel()
    return rows, cols, (rows // CELL) * (W // CELL) + cols // CELL


@pytest.mark.parametrize("budget", [500, 1000, 2000])
def test_budget_spread_and_gradient(image, grid, budget):
    rows, cols, ids = grid
    sel = select_pixels(image, rows, cols, ids, PixelSelectionConfig(budget=budget))
    n = sel.indices.size
    assert 0.7 * budget <= n <= budget
    assert np.all(np.diff(sel.indices) > 0)
    # spread: every 40x40 cell with texture holds selected pixels, and no
    # textured pixel is far from a selected one
    r, c = rows[sel.indices], cols[sel.indices]
    per_cell = np.bincount(ids[sel.indices], minlength=ids.max() + 1)
    textured_cells = np.unique(ids[cols < TEXTURED_COLS - CELL])
    assert np.all(per_cell[textured_cells] > 0)
    mask = np.ones((H, W), np.uint8)
    mask[r, c] = 0
    dist = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    assert dist[:, :TEXTURED_COLS - CELL].max() < 4 * sel.block + 4
    # prefers high gradient
    mag = gradient_magnitude(image)
    assert mag[r, c].mean() > 1.5 * mag[:, :TEXTURED_COLS - CELL].mean()


def test_minimum_per_primitive_and_empty_primitives(image, grid):
    rows, cols, ids = grid
    cfg = PixelSelectionConfig(budget=300, min_per_primitive=10)
    sel = select_pixels(image, rows, cols, ids, cfg)
    flat = np.unique(ids[cols >= TEXTURED_COLS])
    textured = np.setdiff1d(np.arange(ids.max() + 1), flat)
    assert np.all(sel.counts[textured] >= 10)
    np.testing.assert_array_equal(sel.empty, flat)
    # the minima alone exceed this budget: exactly them
    assert sel.indices.size == 10 * textured.size > cfg.budget
    larger = select_pixels(image, rows, cols, ids, PixelSelectionConfig(budget=600,
                                                                         min_per_primitive=10))
    assert np.all(larger.counts[textured] >= 10) and larger.indices.size <= 600
    # deterministic
    again = select_pixels(image, rows, cols, ids, cfg)
    np.testing.assert_array_equal(sel.indices, again.indices)


def test_few_candidates_and_bad_input(image, grid):
    rows, cols, ids = grid
    sub = np.flatnonzero((rows % 8 == 0) & (cols % 8 == 0))
    sel = select_pixels(image, rows[sub], cols[sub], ids[sub], PixelSelectionConfig(budget=10_000))
    assert 0 < sel.indices.size <= sub.size
    empty = select_pixels(image, rows[:0], cols[:0], ids[:0], PixelSelectionConfig(), n_primitives=3)
    assert empty.indices.size == 0 and empty.empty.tolist() == [0, 1, 2]
    with pytest.raises(ValueError):
        select_pixels(image, rows + H, cols, ids, PixelSelectionConfig())
    with pytest.raises(ValueError):
        PixelSelectionConfig(budget=0)
    with pytest.raises(ValueError):
        OdometryConfig(pixel_budget=0)


def make_keyframe_pair(width, height):
    """A synthetic keyframe (depth front-end) and a frame moved by 2 cm."""
    cam = synthetic.default_camera(width, height)
    scene = synthetic.SyntheticScene.generate(2)
    T_kf, _ = synthetic.make_view_set(scene, cam, 1, 7.5, 0.05, 2)
    kv = scene.render(cam, T_kf, supersample=2)
    prims = make_frontend("depth").primify(kv.rgb, cam, kv.depth)
    D = np.eye(4)
    D[:3, 3] = [0.02, -0.01, 0.01]
    frame = scene.render(cam, T_kf @ D, supersample=2).rgb
    return cam, kv.rgb, prims, T_kf, T_kf @ D, frame


@pytest.fixture(scope="module")
def keyframe_pair():
    """:func:`make_keyframe_pair` at 160x120."""
    return make_keyframe_pair(160, 120)


def test_keyframe_levels_use_the_selection(keyframe_pair):
    _, image, prims, T_kf, _, _ = keyframe_pair
    cfg = PixelSelectionConfig(budget=800)
    kf_all = Keyframe.build(image, prims, T_kf, 3)
    kf_sel = Keyframe.build(image, prims, T_kf, 3, cfg)
    for lvl in range(3):
        a, s = kf_all.level_data(lvl), kf_sel.level_data(lvl)
        assert np.all(np.isin(s.entries, a.entries))
        if a.entries.size > cfg.budget:
            assert s.entries.size < a.entries.size
    assert kf_sel.level_data(0).entries.size <= max(cfg.budget,
                                                    len(prims) * cfg.min_per_primitive)
    # "all": coarser levels keep every lattice pixel
    kf_c = Keyframe.build(image, prims, T_kf, 3, PixelSelectionConfig(budget=800,
                                                                      coarse_levels="all"))
    np.testing.assert_array_equal(kf_c.level_data(1).entries, kf_all.level_data(1).entries)
    # a rebuilt keyframe (new scales) keeps its selection
    re = kf_sel.rebuilt(prims.with_log_scales(prims.log_scales + 0.1), T_kf)
    np.testing.assert_array_equal(re.level_data(0).entries, kf_sel.level_data(0).entries)
    with pytest.raises(ValueError):
        kf_sel.rebuilt(prims.subset([0]), T_kf)


@pytest.mark.parametrize("level", [0, 1])
def test_tracker_and_mapping_factors_share_pixels_and_cost(keyframe_pair, level):
    """With the tracker's pixel selection on the keyframe, the tracker's cost on
    all pixels of a level equals the error of the mapper's photometric factors
    (same level, same pixels: mapping uses every pixel of ``mapping.level``)."""
    cam, image, prims, T_kf, T_f, frame = keyframe_pair
    cfg = OdometryConfig(pixel_budget=600, mapping=MappingConfig(level=level))
    kf = Keyframe.build(image, prims, T_kf, cfg.keyframe_levels, cfg.selection)
    mkf = MapKeyframe(0, 0, image, kf)
    mapper = WindowMapper(cfg)
    pyr = kf.frame_pyramid(frame)
    tgt = support_pose_key(1)
    bkey = support_brightness_key(1)
    group = mapper._group(mkf, tgt, pyr.images[level], pyr.cameras[level], bkey)
    values = gtsam.Values()
    values.insert(pose_key(0), gtsam.Pose3(T_kf))
    values.insert(tgt, gtsam.Pose3(T_f))
    ab = np.array([0.02, -0.01])
    values.insert(bkey, ab)
    for i in range(len(prims)):
        values.insert(scale_key(i, keyframe=0), np.array([prims.log_scales[i]]))
    factor_cost = sum(f.error(values) for f in group.factors)
    tc = TrackingCost(kf, pyr.images[level], pyr.cameras[level], level,
                      cfg.tracker, selection=None)
    out = tc.evaluate(T_f, ab, jacobians=False)
    assert tc.n_pixels == mapper._map_pixels(mkf)[0].size > 0
    np.testing.assert_allclose(out["photometric_cost"], factor_cost, rtol=1e-6)


def test_boundary_margin_keeps_block_picks_inside_primitives(image, grid):
    rows, cols, ids = grid
    sel = select_pixels(image, rows, cols, ids, PixelSelectionConfig(budget=1000, boundary_margin=2,
                                                                     min_per_primitive=0))
    r, c = rows[sel.indices], cols[sel.indices]
    # the 40x40 primitives' interiors: at least 2 pixels from another primitive
    inside = (np.minimum(r % CELL, CELL - 1 - r % CELL) >= 2) | (r < 2) | (r >= H - 2)
    inside &= (np.minimum(c % CELL, CELL - 1 - c % CELL) >= 2) | (c < 2) | (c >= W - 2)
    assert sel.indices.size > 500 and inside.all()


@pytest.fixture(scope="module")
def keyframe_pair_320():
    """:func:`make_keyframe_pair` at 320x240 (primitives at 320x240)."""
    return make_keyframe_pair(320, 240)


@pytest.mark.parametrize("pair", ["keyframe_pair", "keyframe_pair_320"])
def test_decision_quantities_do_not_depend_on_the_selection(pair, request):
    """At the same pose, relative cost and valid fraction are the same with
    and without a pixel selection (decision pixels: the level closest to 160
    wide, every lattice pixel); after tracking from a perturbed pose they
    stay close."""
    cam, image, prims, T_kf, T_f, frame = request.getfixturevalue(pair)
    sel = PixelSelectionConfig(budget=500)
    kf_all = Keyframe.build(image, prims, T_kf, 3)
    kf_sel = Keyframe.build(image, prims, T_kf, 3, sel)
    assert kf_sel.level_data(0).entries.size < kf_all.level_data(0).entries.size
    fixed = TrackerConfig(iterations=(0,), decision_iterations=0)   # no step: at T_f
    a = track_frame(kf_all, frame, T_f, (0.0, 0.0), fixed)
    s = track_frame(kf_sel, frame, T_f, (0.0, 0.0), fixed)
    np.testing.assert_array_equal(a.T_world_frame, s.T_world_frame)
    assert a.decision_stride == s.decision_stride == cam.width // 160
    assert a.photometric_cost != s.photometric_cost        # optimised on other pixels
    assert a.relative_cost == s.relative_cost and a.valid_fraction == s.valid_fraction
    assert 0 < a.relative_cost < 0.35 and a.valid_fraction > 0.6
    # converged from a perturbed pose (the poses differ by about a millimetre):
    # the decision quantities agree to a tenth of the keyframe thresholds
    D = np.eye(4)
    D[:3, 3] = [0.01, 0.0, -0.01]
    a = track_frame(kf_all, frame, T_f @ D)
    s = track_frame(kf_sel, frame, T_f @ D)
    assert a.ok and s.ok and a.decision_steps == 0 and s.decision_steps > 0
    assert abs(s.relative_cost - a.relative_cost) < 0.1 * OdometryConfig().keyframe.max_relative_cost
    assert abs(s.valid_fraction - a.valid_fraction) < 0.01


def test_decision_cost_at_160_is_the_finest_level_cost(keyframe_pair):
    """Without selection at 160x120 the decision pixels are the finest
    level's: the relative cost is that level's photometric cost over its
    featureless cost, and the valid fraction is over every primitive pixel."""
    cam, image, prims, T_kf, T_f, frame = keyframe_pair
    kf = Keyframe.build(image, prims, T_kf, 3)
    res = track_frame(kf, frame, T_kf)
    tc = TrackingCost(kf, kf.frame_pyramid(frame).images[0], cam, 0, TrackerConfig())
    out = tc.evaluate(res.T_world_frame, res.brightness, jacobians=False)
    assert res.photometric_cost == out["photometric_cost"]
    assert res.relative_cost == out["photometric_cost"] / tc.featureless_cost(out)
    assert res.valid_fraction == valid_fraction(kf, res.T_world_frame,
                                                 TrackerConfig().photometric.min_depth)
