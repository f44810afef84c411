"""Orientation hypotheses decided by the photometric cost (spgeo.sfm.orientation):
the dominant orientations of a set of primitives, the plane of an orientation
through a given depth, per-primitive costs, and the choice recovering true
orientations from fronto-parallel planes at the true poses."""
import numpy as np
import pytest

import gtsam
from spgeo import synthetic
from spgeo.frontend import make_frontend
from spgeo.geometry import relative_pose
from spgeo.images import gaussian_pyramid, to_gray
from spgeo.graph.builders import build_level_graph
from spgeo.graph.keys import brightness_key, pose_key, scale_key, symbol_index
from spgeo.sfm import SfMConfig
from spgeo.sfm.orientation import (centre_rays, choose_orientations, orientation_ratios,
                                   planes_with_orientation, primitive_costs, scene_orientations)

CAM = synthetic.default_camera(160, 120)


@pytest.fixture(scope="module")
def setup():
    """Depth-front-end primitives of a synthetic view (true shapes and scales), a
    second view, and the finest-level photometric groups at the true poses."""
    scene = synthetic.SyntheticScene.generate(1)
    T_ref, views = synthetic.make_view_set(scene, CAM, 1, 4.0, 0.1, 3)
    r0, r1 = scene.render(CAM, T_ref, supersample=2), scene.render(CAM, views[0], supersample=2)
    prims = make_frontend("depth").primify(r0.rgb, CAM, r0.depth)
    planes = prims.fit_planes()
    cfg = SfMConfig(shape_model="planar")
    values = gtsam.Values()
    values.insert(pose_key(0), gtsam.Pose3())
    values.insert(pose_key(1), gtsam.Pose3(relative_pose(T_ref, views[0])))
    values.insert(brightness_key(1), np.zeros(2))
    for i in range(len(prims)):
        values.insert(scale_key(i), planes[i].copy())
    pyr = [gaussian_pyramid(to_gray(r.rgb).astype(np.float32), CAM, cfg.levels) for r in (r0, r1)]
    rays = CAM.rays().reshape(-1, 3)[prims.pixels]
    _, groups = build_level_graph(prims, rays, pyr[0], pyr[1:], 0, values, cfg)
    return {"prims": prims, "planes": planes, "values": values, "groups": groups}


_index = symbol_index


def test_orientation_ratios_are_the_normals_slopes(setup):
    prims, planes = setup["prims"], setup["planes"]
    r = orientation_ratios(prims)
    big = planes[:, 2] > 0
    np.testing.assert_allclose(r[big], planes[big, :2] / planes[big, 2:3], rtol=1e-12)
    flat = prims.with_scaled_log_depth(np.repeat(prims.log_scales, prims.sizes))
    assert np.abs(orientation_ratios(flat)).max() < 1e-9
    assert scene_orientations(flat, orientation_ratios(flat)) == []


def test_scene_orientations_finds_the_dominant_ones(setup):
    prims = setup["prims"]
    n = len(prims)
    truth = [np.array([0.0, 2.0]), np.array([1.5, 0.0])]       # floor-like, wall-like
    ratios = np.zeros((n, 2))
    ratios[: n // 2] = truth[0] + 1e-3                          # within the tolerance
    ratios[n // 2: n - 2] = truth[1]
    found = scene_orientations(prims, ratios, max_orientations=3)
    assert len(found) == 2
    got = sorted(tuple(np.round(f, 2)) for f in found)
    assert got == sorted(tuple(np.round(t, 2)) for t in truth)


def test_planes_with_orientation_keep_the_centre_depth(setup):
    planes = setup["planes"]
    c = centre_rays(setup["prims"])
    ratios = np.tile([0.3, -0.2], (len(planes), 1))
    out, ok = planes_with_orientation(planes, c, ratios)
    r = np.c_[c, np.ones(len(c))]
    np.testing.assert_allclose(np.einsum("ij,ij->i", out, r)[ok],
                               np.einsum("ij,ij->i", planes, r)[ok], rtol=1e-12)
    np.testing.assert_allclose(out[ok, :2] / out[ok, 2:3], ratios[ok], rtol=1e-12)
    assert ok.mean() > 0.9


def test_choice_recovers_true_orientations(setup):
    prims, planes, values, groups = (setup[k] for k in ("prims", "planes", "values", "groups"))
    c = centre_rays(prims)
    flat, _ = planes_with_orientation(planes, c, np.zeros((len(planes), 2)))
    truth = orientation_ratios(prims)
    cost_true, _ = primitive_costs(groups, values, planes, _index)
    cost_flat, _ = primitive_costs(groups, values, flat, _index)
    seen = np.isfinite(cost_true) & np.isfinite(cost_flat)
    tilted = seen & (np.linalg.norm(truth, axis=1) > 0.3)     # clearly not fronto-parallel
    assert tilted.sum() >= 5
    assert np.median(cost_true[tilted] / cost_flat[tilted]) < 0.9
    best, choice, rep = choose_orientations(groups, values, flat, c, [truth], _index)
    assert np.mean(choice[tilted] == 0) > 0.8
    assert rep["cost_after"] < rep["cost_before"]
    # a primitive keeps its plane unless a hypothesis lowers its own cost
    after, _ = primitive_costs(groups, values, best, _index)
    assert np.all(after[seen] <= cost_flat[seen] + 1e-12)


def test_few_view_sfm_makes_the_choice_and_refines():
    """Planar few-view SfM with non-flat front-end shapes reports the choice and
    solves the finest level once more; flat (classical) shapes make no choice."""
    from spgeo.sfm import few_view_sfm

    scene = synthetic.SyntheticScene.generate(1)
    T_ref, views = synthetic.make_view_set(scene, CAM, 2, 4.0, 0.1, 3)
    r0 = scene.render(CAM, T_ref, supersample=2)
    imgs = [scene.render(CAM, T, supersample=2).rgb for T in views]
    prims = make_frontend("depth").primify(r0.rgb, CAM, r0.depth)
    cfg = SfMConfig(shape_model="planar", levels=3, marginals=False)
    res = few_view_sfm(r0.rgb, imgs, CAM, prims, cfg)
    rep = res.report["orientation_choice"]
    assert rep["cost_after"] <= rep["cost_before"]
    assert len(rep["n_per_hypothesis"]) >= 1
    finest = [lv for lv in res.report["levels"] if lv["level"] == 0]
    assert len(finest) == (2 if rep["n_kept"] < len(prims) else 1)
    flat = few_view_sfm(r0.rgb, imgs, CAM, make_frontend("classical").primify(r0.rgb, CAM), cfg)
    assert "orientation_choice" not in flat.report
    assert len([lv for lv in flat.report["levels"] if lv["level"] == 0]) == 1
