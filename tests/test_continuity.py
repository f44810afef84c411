"""The continuity factors of the few-view SfM's depth stage (issue 54)."""
import numpy as np
import pytest

import gtsam
from spgeo import PinholeCamera
from spgeo.factors.priors import log_scale_prior
from spgeo.graph.builders import continuity_factors
from spgeo.primitives import PrimitiveSet

CAM = PinholeCamera(50.0, 50.0, 19.5, 14.5, 40, 30)


def three_strips(steps=(0.0, 0.0)):
    """Three adjacent vertical strips of 10 columns (columns 30-39: no primitive);
    strip 1 has log-depth slope 0.02 per column; image: strips 0 and 1 the same
    grey (a weak edge between them), strip 2 far brighter (a strong edge)."""
    h, w = CAM.height, CAM.width
    v, u = np.mgrid[0:h, 0:w]
    regions = [(u < 10), (u >= 10) & (u < 20), (u >= 20) & (u < 30)]
    pix = [np.flatnonzero(r.ravel()) for r in regions]
    ld = [np.zeros(p.size) for p in pix]
    ld[1] = 0.02 * (pix[1] % w - 10)
    prims = PrimitiveSet(CAM, np.concatenate(pix), np.cumsum([0] + [p.size for p in pix]),
                         np.concatenate(ld), [p[p.size // 2] for p in pix])
    img = np.where(u < 20, 0.5, 0.9).astype(float)
    return prims, img


def solve(prims, img, known):
    """Log-scales with primitive 0 measured at ``known`` and the rest held only
    by the weak scale prior, plus the continuity factors."""
    keys = [gtsam.symbol("s", i) for i in range(len(prims))]
    graph = gtsam.NonlinearFactorGraph()
    for f in continuity_factors(prims, img, keys):
        graph.add(f)
    graph.add(gtsam.PriorFactorVector(keys[0], np.array([known]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
    vals = gtsam.Values()
    for i, k in enumerate(keys):
        graph.add(log_scale_prior(k, 3.0))
        vals.insert(k, np.array([3.0]))
    out = gtsam.LevenbergMarquardtOptimizer(graph, vals).optimize()
    return np.array([out.atVector(k)[0] for k in keys]), graph.size()


def test_an_unconstrained_primitive_takes_its_neighbours_depth_across_a_weak_edge_only():
    prims, img = three_strips()
    s, n_factors = solve(prims, img, known=0.4)
    assert n_factors == 1 + 1 + 3          # one coupled pair (0, 1), priors
    # strip 1's anchor is 5 columns in (log-depth 0.1 there, 0 at its left border,
    # normalised to 0 at the anchor): continuous at the border
    depth = np.exp(prims.with_log_scales(s).scaled_log_depth())
    left_of_border = depth[prims.offsets[0]:prims.offsets[1]][prims.pixels[:prims.offsets[1]] % CAM.width == 9]
    right_of_border = depth[prims.offsets[1]:prims.offsets[2]][
        prims.pixels[prims.offsets[1]:prims.offsets[2]] % CAM.width == 10]
    np.testing.assert_allclose(right_of_border, left_of_border, rtol=0.03)
    # across the strong edge nothing reaches strip 2: its prior keeps it
    assert s[2] == pytest.approx(3.0, abs=1e-3)


def test_continuity_factors_refuse_mismatched_keys_and_image():
    prims, img = three_strips()
    with pytest.raises(ValueError, match="keys"):
        continuity_factors(prims, img, [1, 2])
    with pytest.raises(ValueError):
        continuity_factors(prims, img[:-1], [gtsam.symbol("s", i) for i in range(3)])
