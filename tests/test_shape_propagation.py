"""Shape propagation through the VO map (spgeo.vo.shape_propagation): a keyframe's
fronto-parallel primitives take the shapes of a rendered depth map where it
covers them; the others keep theirs; the option is off by default."""
import numpy as np
import pytest

from analytic import scale_fitted_rel_error
from spgeo import synthetic
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.vo import OdometryConfig
from spgeo.vo.shape_propagation import propagate_shapes

CAM = synthetic.default_camera(160, 120)


@pytest.fixture(scope="module")
def view():
    scene = synthetic.SyntheticScene.generate(0)
    v = scene.render(CAM, synthetic.make_trajectory(1, 0)[0])
    prims = make_frontend("classical", FrontEndConfig(working_size=CAM.size)).primify(
        v.rgb, CAM, None)
    return v, prims


def _errors(prims, depth, ids):
    ld = prims.log_depth
    out = []
    for i in ids:
        mask = np.zeros(CAM.shape, bool)
        mask.reshape(-1)[prims.pixels[prims.offsets[i]:prims.offsets[i + 1]]] = True
        full = np.full(CAM.width * CAM.height, np.nan)
        full[prims.pixels[prims.offsets[i]:prims.offsets[i + 1]]] = \
            ld[prims.offsets[i]:prims.offsets[i + 1]]
        out.append(np.median(scale_fitted_rel_error(full.reshape(CAM.shape), depth, mask)))
    return np.array(out)


def test_exact_render_gives_the_true_shapes(view):
    """With the true depth as the render, covered primitives' scale-fitted depth
    error drops far below the fronto-parallel one; the others are unchanged."""
    v, prims = view
    depth = v.depth.copy()
    depth[:, :40] = np.nan                 # the render does not reach the left quarter
    res = propagate_shapes(prims, depth, min_coverage=0.6)
    assert res.propagated.sum() >= 0.3 * len(prims) and not res.propagated.all()
    took = np.flatnonzero(res.propagated)
    before = _errors(prims, v.depth, took)
    after = _errors(res.primitives, v.depth, took)
    assert np.median(after) < 0.25 * np.median(before)
    assert np.median(after) < 0.01
    kept = ~res.propagated[prims.primitive_ids]
    np.testing.assert_array_equal(res.primitives.log_depth[kept], prims.log_depth[kept])
    np.testing.assert_array_equal(res.primitives.log_scales, prims.log_scales)
    assert np.all(np.isfinite(res.primitives.log_depth))


def test_empty_render_and_bad_arguments(view):
    _, prims = view
    res = propagate_shapes(prims, np.full(CAM.shape, np.nan))
    assert res.primitives is prims and not res.propagated.any()
    with pytest.raises(ValueError, match="min_coverage"):
        propagate_shapes(prims, np.ones(CAM.shape), min_coverage=0.0)
    with pytest.raises(ValueError, match="rendered depth"):
        propagate_shapes(prims, np.ones((10, 10)))


def test_off_by_default_and_validated():
    assert OdometryConfig().propagate_shape is False
    with pytest.raises(ValueError, match="propagate_min_coverage"):
        OdometryConfig(propagate_min_coverage=1.5)
