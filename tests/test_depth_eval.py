"""Dense depth in the evaluation (issue 54): the median-scaled metrics of
:mod:`spgeo.evaluation.depth_eval` on known depth maps, and on a short synthetic VO run."""
import math

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.evaluation.depth_eval import (DepthMapScore, median_scaled_depth, merge_breakdowns,
                                         primitive_breakdown, resize_depth, summarize)
from spgeo.primitives import PrimitiveSet


def _wall(w=640, h=480, depth=2.0):
    return np.full((h, w), depth)


def test_exact_depth_scores_zero_whatever_its_scale():
    """A depth map equal to the sensor's up to one factor: AbsRel 0, delta 1, full coverage."""
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.5, 4.0, (120, 160))
    m = median_scaled_depth(0.37 * gt, gt)
    assert m["abs_rel"] < 1e-12 and m["delta_1.25"] == 1.0 and m["coverage"] == 1.0
    assert m["scale"] == pytest.approx(1 / 0.37)


def test_tilted_log_depth_scores_its_analytic_value():
    """pred = gt * exp(a u), u uniform in [-1, 1] across the columns (a log-depth slope, what
    a bent primitive corrects): after the median scale (1: the median of u is 0)
    AbsRel = (cosh a - 1) / a and delta_1.25 = ln(1.25) / a (for a > ln 1.25)."""
    a, w = 0.5, 4000
    u = (np.arange(w) + 0.5) / w * 2 - 1
    gt = np.tile(np.linspace(1.0, 3.0, 7)[:, None], (1, w))     # any depth: errors are relative
    m = median_scaled_depth(gt * np.exp(a * u)[None, :], gt)
    assert m["scale"] == pytest.approx(1.0, abs=1e-3)
    assert m["abs_rel"] == pytest.approx((math.cosh(a) - 1) / a, rel=1e-3)
    assert m["delta_1.25"] == pytest.approx(math.log(1.25) / a, abs=1e-3)


def test_holes_range_and_coverage():
    """Pixels without a prediction lower the coverage only; sensor pixels outside the
    range or invalid are not judged; nothing valid gives NaN and coverage 0."""
    gt = _wall(100, 10)
    gt[:, :10] = 0.0                       # invalid sensor pixels (10 %)
    gt[:, 10:20] = 50.0                    # beyond max_depth
    pred = gt.copy()
    pred[:, 20:60] = np.nan                # 40 of the 80 judged columns unpredicted
    m = median_scaled_depth(pred, gt)
    assert m["coverage"] == pytest.approx(0.5) and m["abs_rel"] < 1e-12
    none = median_scaled_depth(np.full_like(gt, np.nan), gt)
    assert none["coverage"] == 0.0 and math.isnan(none["abs_rel"])
    with pytest.raises(ValueError):
        median_scaled_depth(pred[:, :5], gt)


def test_resize_is_nearest():
    """Resizing never mixes depths across an edge."""
    d = np.where(np.arange(64)[None, :] < 32, 1.0, 3.0) * np.ones((48, 1))
    r = resize_depth(d, (32, 24))
    assert r.shape == (24, 32) and set(np.unique(r)) == {1.0, 3.0}


def test_summary_mean_and_pooled():
    scores = [DepthMapScore("a", 0, {"abs_rel": 0.1, "median_rel": 0.1, "delta_1.25": 1.0,
                                     "coverage": 1.0, "n_pixels": 300}),
              DepthMapScore("b", 1, {"abs_rel": 0.3, "median_rel": 0.3, "delta_1.25": 0.5,
                                     "coverage": 0.5, "n_pixels": 100}),
              DepthMapScore("c", 2, {"n_pixels": 0, "coverage": 0.0})]
    s = summarize(scores)
    assert s["n_maps"] == 2 and s["abs_rel"] == pytest.approx(0.2)
    assert s["abs_rel_pooled"] == pytest.approx(0.15) and s["delta_1.25"] == pytest.approx(0.75)


def test_breakdown_of_two_primitives():
    """Two side-by-side primitives, the larger exact, the other 10 % too deep: the breakdown's bins hold
    every entry once, the pooled error equals the depth map's AbsRel, and the error sits
    in the right half of the image."""
    cam = PinholeCamera(100.0, 100.0, 39.5, 29.5, 80, 60)
    masks = np.zeros((2, 60, 80), bool)
    masks[0, :, :50] = True          # the larger one: the median scale is its
    masks[1, :, 50:] = True
    gt = _wall(80, 60, 2.0)
    prims = PrimitiveSet.from_masks(cam, masks, np.zeros((2, 60, 80)),
                                    log_scales=np.log([2.0, 2.2]))
    m = median_scaled_depth(prims.depth_map(), gt)
    b = merge_breakdowns([primitive_breakdown(prims, gt, m["scale"])])
    for key in ("size", "anchor", "region"):
        assert sum(b[key]["n"]) == 80 * 60
        pooled = np.nansum(np.array(b[key]["abs_rel"]) * np.array(b[key]["n"])) / (80 * 60)
        assert pooled == pytest.approx(m["abs_rel"])
    reg = np.array(b["region"]["abs_rel"]).reshape(3, 3)
    assert np.all(reg[:, 0] < 1e-12) and np.all(reg[:, 2] > 0.09)


def test_absurd_depths_are_clipped_to_the_range():
    """1 % of the pixels at 10 km (a primitive the views never constrained) cost what a
    prediction at max_depth costs: AbsRel 0.01 * (10 - 2) / 2, and ``clipped`` says 1 %;
    unclipped they would dominate (AbsRel ~50)."""
    gt = _wall(100, 100, 2.0)
    pred = gt.copy()
    pred[:1, :] = 1e4
    m = median_scaled_depth(pred, gt)
    assert m["abs_rel"] == pytest.approx(0.01 * 8 / 2) and m["clipped"] == pytest.approx(0.01)
    assert median_scaled_depth(pred, gt, clip=False)["abs_rel"] > 40
