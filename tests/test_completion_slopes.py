"""Primitives that bend in completion (issue 54): log-depth slopes per primitive
(:mod:`spgeo.completion.slopes`, ``shape_model="slope"``)."""
from __future__ import annotations

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.completion import CompletionConfig, complete_depth
from spgeo.completion.scales import sparse_point_assignments, working_pixels
from spgeo.completion.slopes import fit_log_slopes
from spgeo.primitives import PrimitiveSet

CAM = PinholeCamera(80.0, 80.0, 31.5, 23.5, 64, 48)
VV, UU = np.mgrid[0:48, 0:64]
X, Y = (UU - CAM.cx) / CAM.fx, (VV - CAM.cy) / CAM.fy


def _one_flat_primitive():
    return PrimitiveSet.from_masks(CAM, np.ones((1, 48, 64), bool), np.zeros((1, 48, 64)))


def _fit(prims, uv, d, s0, **kw):
    point, prim, _ = sparse_point_assignments(prims, uv, CAM)
    pix = working_pixels(uv, CAM, prims.camera)[point]
    return fit_log_slopes(prims, prim, pix, d[point], s0, **kw)


@pytest.mark.parametrize("n_points", [3, 12])
def test_slopes_recover_a_known_tilt_from_three_or_more_points(n_points):
    """A flat primitive whose true log-depth is ``log 2 + 0.8 x - 0.5 y``: the fit
    from ``n_points`` exact points gives the slopes within the prior's pull (the
    prior's weight against one point is (sigma / sigma_slope)^2 ~ 1e-3)."""
    prims = _one_flat_primitive()
    rng = np.random.default_rng(0)
    idx = rng.choice(48 * 64, n_points - 3, replace=False)
    uv = np.concatenate([[[5, 5], [58, 10], [20, 42]], np.stack([idx % 64, idx // 64], 1)])
    true = np.log(2.0) + 0.8 * X - 0.5 * Y
    d = np.exp(true[uv[:, 1], uv[:, 0]])
    fit = _fit(prims, uv, d, np.array([np.log(2.0)]))
    assert fit.bent[0]
    np.testing.assert_allclose(fit.slopes[0], [0.8, -0.5], atol=0.05)
    err = np.abs(fit.scaled_log_depth - true.ravel()[prims.pixels])
    assert err.max() < 0.02


def test_two_points_keep_the_scale_and_an_outlier_is_rejected():
    prims = _one_flat_primitive()
    uv = np.array([[10, 10], [50, 30]])
    fit = _fit(prims, uv, np.array([2.0, 3.0]), np.array([0.5]))
    assert not fit.bent[0] and fit.log_scales[0] == 0.5 and np.all(fit.slopes == 0)
    np.testing.assert_allclose(fit.scaled_log_depth, 0.5)
    # a tilted plane with 15 points, one of them 50 % off: Huber keeps the slopes
    rng = np.random.default_rng(1)
    idx = rng.choice(48 * 64, 15, replace=False)
    uv = np.stack([idx % 64, idx // 64], 1)
    true = np.log(2.0) + 0.6 * X + 0.3 * Y
    d = np.exp(true[uv[:, 1], uv[:, 0]])
    d[0] *= 1.5
    fit = _fit(prims, uv, d, np.array([np.log(2.0)]))
    np.testing.assert_allclose(fit.slopes[0], [0.6, 0.3], atol=0.1)


def test_slope_model_in_complete_depth_beats_scale_on_a_tilted_plane():
    """The classical front-end sees a textureless image (flat primitives): one
    scale cannot follow a tilted floor, the slopes do."""
    img = np.full((48, 64, 3), 0.5)
    true = np.exp(np.log(2.0) + 0.7 * X + 0.4 * Y)
    rng = np.random.default_rng(2)
    sparse = np.zeros((48, 64))
    idx = rng.choice(48 * 64, 40, replace=False)
    sparse.flat[idx] = true.flat[idx]
    err = {}
    for sm in ("scale", "slope"):
        cfg = CompletionConfig(shape_model=sm, choose="none", residual_clip=None,
                               method="median")
        r = complete_depth(img, sparse, CAM, frontend=_one_flat_primitive(), config=cfg)
        err[sm] = np.mean(np.abs(r.depth - true))
    assert err["slope"] < 0.2 * err["scale"]


def test_fit_log_slopes_bad_input():
    prims = _one_flat_primitive()
    with pytest.raises(ValueError):
        fit_log_slopes(prims, np.zeros(3, int), np.zeros(3, int), np.ones(3), np.zeros(2))
    with pytest.raises(ValueError):
        fit_log_slopes(prims, np.zeros(3, int), np.zeros(3, int), np.ones(3), np.zeros(1),
                       min_points=2)
    with pytest.raises(ValueError):
        CompletionConfig(slope_sigma=0.0)
