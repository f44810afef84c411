"""Completion shape models (per-primitive planes, lending across weak edges, the
coupled "graph" scales) and the colorization-fill baseline."""
from __future__ import annotations

import time

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.completion import CompletionConfig, complete_depth
from spgeo.completion.graph import solve_log_scales_graph, solve_planes_graph
from spgeo.completion.planes import (MODE_LENT, MODE_NONE, MODE_PLANE, MODE_SCALE,
                                     fit_primitive_planes, lend_across_weak_edges,
                                     pixel_rays, primitive_adjacency)
from spgeo.completion.scales import grouped_median, sparse_point_assignments
from spgeo.evaluation.references.depth_completion import (ColorizationConfig,
                                                          colorization_completion,
                                                          linear_interpolation_completion)
from spgeo.primitives import PrimitiveSet

CAM = PinholeCamera(80.0, 80.0, 31.5, 23.5, 64, 48)
VV, UU = np.mgrid[0:48, 0:64]


def _plane_depth(n, d):
    """Depth of the plane n.X = d seen by CAM: z = d / (n . r)."""
    r = np.stack([(UU - CAM.cx) / CAM.fx, (VV - CAM.cy) / CAM.fy, np.ones_like(UU, float)], -1)
    return d / (r @ np.asarray(n, float))


def _flat_set(masks):
    """Primitives with fronto-parallel (constant) shape on the given masks."""
    return PrimitiveSet.from_masks(CAM, np.stack(masks), np.zeros((len(masks), 48, 64)))


def _assign(prims, sparse):
    v, u = np.nonzero(sparse > 0)
    uv = np.stack([u, v], 1)
    point, prim, l = sparse_point_assignments(prims, uv, CAM)
    return point, prim, l, (v * 64 + u)[point], sparse[v, u][point]


# ============================================================ planes from points
def test_plane_fit_recovers_tilted_plane_from_flat_shape():
    n = np.array([0.3, -0.4, -1.0])
    n /= np.linalg.norm(n)
    depth = _plane_depth(-n, 2.0)  # normals point to the camera: n.X = -2
    assert np.all(depth > 0)
    prims = _flat_set([np.ones((48, 64), bool)])
    rng = np.random.default_rng(0)
    sparse = np.zeros_like(depth)
    idx = rng.choice(depth.size, 12, replace=False)
    sparse.flat[idx] = depth.flat[idx]
    point, prim, l, pix, d = _assign(prims, sparse)
    s, cnt = grouped_median(prim, np.log(d) - l, 1)
    fit = fit_primitive_planes(prims, prim, pix, d, s, cnt, prior=1e-4)
    assert fit.mode.tolist() == [MODE_PLANE]
    np.testing.assert_allclose(np.exp(fit.scaled_log_depth), depth.ravel(), rtol=1e-3)
    # scale only: a fronto-parallel plane, clearly worse
    assert np.abs(np.exp(prims.scaled_log_depth(s)) - depth.ravel()).mean() > 0.05
    # in complete_depth
    res = complete_depth(np.zeros((48, 64, 3)), sparse, CAM, prims,
                         CompletionConfig(shape_model="plane", plane_prior=1e-4))
    np.testing.assert_allclose(res.depth, depth, rtol=1e-3)
    assert res.modes.tolist() == [MODE_PLANE]


def test_plane_prior_keeps_orientation_for_collinear_points_and_bounds_outliers():
    depth = np.full((48, 64), 2.0)  # fronto-parallel wall at 2 m
    prims = _flat_set([np.ones((48, 64), bool)])
    sparse = np.zeros_like(depth)
    sparse[24, [5, 20, 40, 60]] = 2.0 * np.array([1.0, 1.01, 0.99, 1.0])  # one row: collinear
    point, prim, l, pix, d = _assign(prims, sparse)
    s, cnt = grouped_median(prim, np.log(d) - l, 1)
    fit = fit_primitive_planes(prims, prim, pix, d, s, cnt)
    assert fit.mode.tolist() == [MODE_PLANE]
    np.testing.assert_allclose(np.exp(fit.scaled_log_depth), 2.0, rtol=0.02)
    # well-spread points and one gross outlier: the Huber fit stays on the wall
    rng = np.random.default_rng(1)
    sp2 = np.zeros_like(depth)
    sp2.flat[rng.choice(depth.size, 12, replace=False)] = 2.0
    sp2[10, 30] = 3.5
    point, prim, l, pix, d = _assign(prims, sp2)
    s, cnt = grouped_median(prim, np.log(d) - l, 1)
    fit = fit_primitive_planes(prims, prim, pix, d, s, cnt)
    np.testing.assert_allclose(np.exp(fit.scaled_log_depth), 2.0, rtol=0.05)
    assert np.median(np.abs(np.exp(fit.scaled_log_depth) - 2.0)) < 0.03


def test_plane_hypotheses_pick_the_right_normal_and_two_points_fix_only_the_scale():
    # floor-like plane, shape given as fronto-parallel; hypotheses: wrong + right
    n_true = np.array([0.0, -0.8, -0.6])
    depth = _plane_depth(-n_true, 1.5)
    prims = _flat_set([np.ones((48, 64), bool)])
    sparse = np.zeros_like(depth)
    sparse[[5, 40, 30], [10, 15, 55]] = depth[[5, 40, 30], [10, 15, 55]]
    point, prim, l, pix, d = _assign(prims, sparse)
    s, cnt = grouped_median(prim, np.log(d) - l, 1)
    hyp = np.array([[[0.8, 0.0, -0.6], n_true]])
    fit = fit_primitive_planes(prims, prim, pix, d, s, cnt, prior=10.0, hypotheses=hyp)
    assert fit.hypothesis.tolist() == [1]
    np.testing.assert_allclose(np.exp(fit.scaled_log_depth), depth.ravel(), rtol=1e-3)
    # two points: scale of the shape only (no tilt)
    sp2 = np.zeros_like(depth)
    sp2[[5, 40], [10, 15]] = depth[[5, 40], [10, 15]]
    point, prim, l, pix, d = _assign(prims, sp2)
    s, cnt = grouped_median(prim, np.log(d) - l, 1)
    fit2 = fit_primitive_planes(prims, prim, pix, d, s, cnt)
    assert fit2.mode.tolist() == [MODE_SCALE]
    assert np.ptp(fit2.scaled_log_depth) == pytest.approx(0.0)


def test_bad_plane_inputs_raise():
    prims = _flat_set([np.ones((48, 64), bool)])
    with pytest.raises(ValueError, match="min_points"):
        fit_primitive_planes(prims, [0], [0], [1.0], [0.0], [1], min_points=2)
    with pytest.raises(ValueError, match="point_d"):
        fit_primitive_planes(prims, [0], [0], [-1.0], [0.0], [1])
    with pytest.raises(ValueError, match="hypotheses"):
        fit_primitive_planes(prims, [0, 0, 0], [0, 5, 70], [1.0, 1.0, 1.0], [0.0], [3],
                             hypotheses=np.zeros((2, 1, 3)))
    with pytest.raises(ValueError, match="shape_model"):
        CompletionConfig(shape_model="quadric")
    with pytest.raises(ValueError, match="plane_min_points"):
        CompletionConfig(plane_min_points=2)
    with pytest.raises(ValueError, match="plane_prior_flat"):
        CompletionConfig(plane_prior_flat=-1.0)
    with pytest.raises(ValueError, match="graph_coupling"):
        CompletionConfig(graph_coupling=float("nan"))


# ============================================================ weak edges
def _three_strips():
    """Strips u < 20, 20 <= u < 40, u >= 40; image: strips 0 and 1 the same
    grey, strip 2 much brighter (a strong edge)."""
    masks = [UU < 20, (UU >= 20) & (UU < 40), UU >= 40]
    img = np.where(UU < 40, 0.3, 0.9)[..., None].repeat(3, 2)
    return _flat_set(masks), img


def test_adjacency_and_lending_only_across_weak_edges():
    prims, img = _three_strips()
    p, q, a, b = primitive_adjacency(prims, img)
    assert set(zip(a.tolist(), b.tolist())) == {(0, 1), (1, 0), (1, 2), (2, 1)}
    assert np.all(np.abs(p - q) == 1)
    from spgeo.completion.planes import PlaneFit
    L = prims.scaled_log_depth(np.array([np.log(2.0), 0.0, 0.0]))
    fit = PlaneFit(L, np.array([MODE_SCALE, MODE_NONE, MODE_NONE], np.int8), np.full(3, -1))
    out = lend_across_weak_edges(prims, fit, img, edge_threshold=0.1)
    assert out.mode.tolist() == [MODE_SCALE, MODE_LENT, MODE_NONE]  # 2 is behind a strong edge
    ids = prims.primitive_ids
    np.testing.assert_allclose(np.exp(out.scaled_log_depth[ids == 1]), 2.0)


def test_graph_scales_reject_a_border_outlier_and_reach_empty_primitives():
    # strips 0-2 the same grey at 2 m, strip 3 brighter (a strong edge) at 5 m
    masks = [UU < 16, (UU >= 16) & (UU < 32), (UU >= 32) & (UU < 48), UU >= 48]
    prims = _flat_set(masks)
    img = np.where(UU < 48, 0.3, 0.9)[..., None].repeat(3, 2)
    sparse = np.zeros((48, 64))
    sparse[[10, 30, 20, 12], [5, 40, 56, 60]] = [2.0, 2.0, 5.0, 5.0]
    sparse[24, 20] = 5.0  # strip 1's only point carries a wrong (far) depth
    point, prim, l, pix, d = _assign(prims, sparse)
    med, _ = grouped_median(prim, np.log(d) - l, 4)
    np.testing.assert_allclose(np.exp(med), [2.0, 5.0, 2.0, 5.0])  # the median is fooled
    g = solve_log_scales_graph(prims, img, prim, l, d, med)
    np.testing.assert_allclose(np.exp(g.log_scales), [2.0, 2.0, 2.0, 5.0], rtol=0.02)
    assert g.n_edges == 2 and g.point_weights[prim == 1].max() < 0.2
    # an empty strip between weak edges gets its scale through the coupling
    sp2 = sparse.copy()
    sp2[24, 20] = 0.0
    point, prim, l, pix, d = _assign(prims, sp2)
    g2 = solve_log_scales_graph(prims, img, prim, l, d)
    np.testing.assert_allclose(np.exp(g2.log_scales), [2.0, 2.0, 2.0, 5.0], rtol=1e-3)
    res = complete_depth(img, sparse, CAM, prims,
                         CompletionConfig(method="graph", shape_model="scale", residual_clip=None))
    np.testing.assert_allclose(res.depth[:, :48], 2.0, rtol=0.02)
    np.testing.assert_allclose(res.depth[:, 48:], 5.0, rtol=0.02)
    # the residual correction lets the rejected point pull by the clip at most
    clip = CompletionConfig().residual_clip
    res = complete_depth(img, sparse, CAM, prims, CompletionConfig(method="graph",
                                                                   shape_model="scale"))
    near = res.depth[:, :48]
    assert near.max() <= 2.0 * 1.02 * np.exp(clip) and near.min() >= 2.0 * 0.98
    assert res.depth[24, 20] > 2.0 * 1.02  # it does pull where it sits
    np.testing.assert_allclose(res.depth[:, 48:], 5.0, rtol=0.02)


def test_graph_planes_continue_a_plane_across_weak_edges():
    n = np.array([0.0, -0.8, -0.6])  # a floor under three same-coloured strips
    depth = _plane_depth(-n, 1.5)
    prims = _flat_set([UU < 20, (UU >= 20) & (UU < 40), UU >= 40])
    img = np.full((48, 64, 3), 0.5)
    sparse = np.zeros_like(depth)
    pts = [(5, 3), (40, 10), (25, 15), (8, 45), (44, 60), (30, 52), (20, 30)]
    for v, u in pts:
        sparse[v, u] = depth[v, u]
    point, prim, l, pix, d = _assign(prims, sparse)
    med, _ = grouped_median(prim, np.log(d) - l, 3)
    fit = solve_planes_graph(prims, img, prim, pix, d, med, prior=1e-6, coupling=0.1)
    assert fit.mode.tolist() == [MODE_PLANE] * 3
    np.testing.assert_allclose(np.exp(fit.scaled_log_depth), depth.ravel()[prims.pixels],
                               rtol=0.01)
    assert np.all(pixel_rays(prims, np.array([0]))[:, 2] == 1.0)
    # flat (normal-less) shapes: a strong prior keeps them fronto-parallel unless
    # prior_flat releases them
    stiff = solve_planes_graph(prims, img, prim, pix, d, med, prior=10.0, coupling=0.1)
    loose = solve_planes_graph(prims, img, prim, pix, d, med, prior=10.0, coupling=0.1,
                               prior_flat=1e-6)
    truth = depth.ravel()[prims.pixels]
    assert np.abs(np.exp(stiff.scaled_log_depth) - truth).mean() > 0.1
    np.testing.assert_allclose(np.exp(loose.scaled_log_depth), truth, rtol=0.01)
    res = complete_depth(img, sparse, CAM, prims, CompletionConfig(
        method="graph", shape_model="plane", plane_prior=1e-6, plane_coupling=0.1))
    assert not np.any(res.modes == MODE_NONE)
    np.testing.assert_allclose(res.depth, depth, rtol=0.01)


# ============================================================ colorization fill
def test_colorization_fill_beats_linear_on_piecewise_constant_scene():
    """Four colour regions, one depth each: the image-guided fill follows the
    colour edges that linear interpolation smears."""
    h, w = 60, 80
    vv, uu = np.mgrid[0:h, 0:w]
    region = (uu >= 40).astype(int) + 2 * (vv >= 30)
    colours = np.array([[0.9, 0.2, 0.2], [0.2, 0.8, 0.2], [0.2, 0.3, 0.9], [0.9, 0.9, 0.2]])
    depths = np.array([1.0, 3.0, 2.0, 4.0])
    img = colours[region]
    gt = depths[region]
    rng = np.random.default_rng(3)
    sparse = np.zeros((h, w))
    for r in range(4):
        idx = rng.choice(np.flatnonzero(region.ravel() == r), 8, replace=False)
        sparse.flat[idx] = gt.flat[idx]
    col = colorization_completion(img, sparse)
    lin = linear_interpolation_completion(sparse)
    e_col, e_lin = np.abs(col - gt).mean(), np.abs(lin - gt).mean()
    assert e_col < 0.5 * e_lin
    assert col.shape == (h, w) and np.all(np.isfinite(col)) and np.all(col > 0)
    with pytest.raises(ValueError, match="alpha"):
        ColorizationConfig(alpha=0.0)
    with pytest.raises(ValueError, match="shape"):
        colorization_completion(img[:10], sparse)


def test_colorization_fill_is_fast_enough_at_qvga():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (240, 320, 3)).astype(np.float32)
    sparse = np.zeros((240, 320))
    sparse.flat[rng.choice(sparse.size, 150, replace=False)] = rng.uniform(1, 3, 150)
    t = time.perf_counter()
    out = colorization_completion(img, sparse)
    assert time.perf_counter() - t < 15.0
    assert np.all(np.isfinite(out))


# ============================================================ synthetic scenes, keypoint depth
def test_graph_plane_completion_on_synthetic_scenes_with_keypoint_depth():
    """Keypoints sit on region borders; the coupled robust solve must not lose
    to the per-primitive median and must beat linear interpolation clearly
    (depth-normal primitives: the shapes are right, the scales are the test)."""
    from spgeo import synthetic
    from spgeo.evaluation.completion.void import keypoint_sparse_depth, void_metrics
    from spgeo.frontend import make_frontend

    cam = synthetic.default_camera(320, 240)
    fe = make_frontend("depth")
    mae = {"linear": [], "median/scale": [], "graph/plane": []}
    for seed in range(3):
        scene = synthetic.SyntheticScene.generate(seed=seed)
        view = scene.render(cam, synthetic.make_trajectory(1, seed=seed)[0])
        sparse = keypoint_sparse_depth(view.rgb, view.depth, 150, rel_noise=0.01, seed=seed)
        gt = np.nan_to_num(view.depth)
        prims = fe.primify(view.rgb, cam, view.depth)
        mae["linear"].append(void_metrics(linear_interpolation_completion(sparse), gt)["mae_mm"])
        for name, cfg in (("median/scale", CompletionConfig(method="median", shape_model="scale")),
                          ("graph/plane", CompletionConfig(method="graph", shape_model="plane"))):
            res = complete_depth(view.rgb, sparse, cam, prims, cfg)
            assert np.all(np.isfinite(res.depth)) and np.all(res.depth > 0)
            mae[name].append(void_metrics(res.depth, gt)["mae_mm"])
    m = {k: float(np.mean(v)) for k, v in mae.items()}
    assert m["graph/plane"] < m["median/scale"]
    assert m["graph/plane"] < 0.5 * m["linear"]
