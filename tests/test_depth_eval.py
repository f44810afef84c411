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


def test_gap_results_score_each_methods_reference_depth():
    """The gap cases' depth table (sfm_real): a fake SfM whose reference depth is the
    sensor depth times 3 at gap 1 and tilted in log-depth (slope a across the columns) at
    gap 2 scores AbsRel 0 and (cosh a - 1) / a; a method without depth is not in it."""
    from types import SimpleNamespace

    from spgeo.evaluation.sfm.gaps import run_gaps

    a, w = 0.5, 2000
    u = (np.arange(w) + 0.5) / w * 2 - 1
    gt = np.full((4, w), 2.0)
    frames = [SimpleNamespace(timestamp=float(i), T_world_cam=np.eye(4), name=f"f{i}",
                              depth=gt) for i in range(5)]
    seq = type("Seq", (), {"frame_numbers": list(range(5)),
                           "__getitem__": lambda self, i: frames[i]})()

    def fake(ref, views):
        gap = int(views[0].timestamp - ref.timestamp)
        depth = 3 * gt if gap == 1 else gt * np.exp(a * u)[None, :]
        fake.last_result = SimpleNamespace(status="ok", view_status=["ok"] * len(views),
                                           depth=depth, report={})
        return [np.eye(4) for _ in views]

    def no_depth(ref, views):
        return [np.eye(4) for _ in views]

    res = run_gaps(seq, [1, 2], [0], lambda: {"m": fake, "poses only": no_depth}, judge="")
    d = res.depth_summary()
    assert set(d) == {"gap 1", "gap 2"} and set(d["gap 1"]) == {"m"}
    assert d["gap 1"]["m"]["abs_rel"] < 1e-12
    assert d["gap 2"]["m"]["abs_rel"] == pytest.approx((math.cosh(a) - 1) / a, rel=1e-3)
    assert "depth AbsRel" in res.table() and res.to_dict()["depth"] == d


@pytest.mark.slow
def test_sensor_depth_variant_runs_only_where_there_is_depth(tmp_path):
    """vo_long_run's floor variant (the sensor-depth front-end) is planned on the
    sequences with depth only; the others keep every variant."""
    from spgeo.evaluation.vo.long_run import make_jobs, run_config

    jobs = make_jobs(["7scenes", "kitti", "synthetic-loop", "7scenes-foreign"],
                     ["default", "sensor-depth"], 10, tmp_path)
    assert [j.name for j in jobs] == ["7scenes.default", "7scenes.sensor-depth", "kitti.default",
                                      "synthetic-loop.default", "synthetic-loop.sensor-depth",
                                      "7scenes-foreign.default"]
    assert run_config("7scenes", "sensor-depth").frontend == "depth"


@pytest.mark.slow
def test_short_synthetic_vo_keyframe_depth():
    """40 frames of a synthetic room (exact depth): the classical VO's keyframes score
    AbsRel under 0.08 and delta < 1.25 over 0.9 (measured 0.047, 0.945 at 9276954:
    piecewise-constant primitives), the
    sensor-depth front-end's (the floor) under 0.005 (measured 0.0002)."""
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.evaluation.dense_depth import vo_depth_row

    cfg = VORunConfig(progress=False)
    mono = vo_depth_row("synthetic:0:40", cfg)
    floor = vo_depth_row("synthetic:0:40", VORunConfig(progress=False, frontend="depth"))
    assert mono["n_maps"] >= 2 and mono["abs_rel"] < 0.08 and mono["delta_1.25"] > 0.9
    assert mono["coverage"] > 0.9 and floor["n_maps"] >= 1 and floor["abs_rel"] < 0.005


def test_oracles_fit_scales_and_log_depth_planes():
    """A slanted floor seen by two flat primitives: the scale oracle keeps them flat
    (AbsRel > 0), the plane oracle (a scale and two log-depth slopes per primitive: a
    bent primitive) recovers a log-depth plane exactly."""
    from spgeo.evaluation.depth_eval import oracle_depth_maps

    cam = PinholeCamera(100.0, 100.0, 39.5, 29.5, 80, 60)
    y = (np.arange(60)[:, None] - cam.cy) / cam.fy * np.ones((1, 80))
    x = (np.arange(80)[None, :] - cam.cx) / cam.fx * np.ones((60, 1))
    gt = np.exp(0.7 + 0.4 * x - 0.8 * y)              # a log-depth plane
    masks = np.zeros((2, 60, 80), bool)
    masks[0, :30] = True
    masks[1, 30:] = True
    prims = PrimitiveSet.from_masks(cam, masks, np.zeros((2, 60, 80)))
    maps = oracle_depth_maps(prims, gt)
    assert median_scaled_depth(maps["plane"], gt)["abs_rel"] < 1e-9
    assert median_scaled_depth(maps["scale"], gt)["abs_rel"] > 0.05


@pytest.mark.slow
def test_sensor_depth_floor_of_a_rendered_view_is_near_zero():
    """The floor row of the SfM depth tables (the depth front-end's primitives with their
    scales fitted to the depth) on a rendered view with exact depth: AbsRel ~0 (measured
    1.1e-4: the primitives' shapes from the depth's normals are exact up to the edges)."""
    from spgeo.evaluation.dense_depth import sensor_depth_floor
    from spgeo.evaluation.sfm.baselines import view_set_frames

    m = sensor_depth_floor(view_set_frames(5, 0, (320, 240))[0])
    assert m["abs_rel"] < 2e-3 and m["delta_1.25"] == 1.0 and m["coverage"] > 0.9
