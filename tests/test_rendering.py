"""Z-buffered rendering of primitives and keyframe scale initialisation."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frontend import make_frontend

from spgeo.rendering import init_scales_from_render, render_depth, render_primitives

CAM = synthetic.default_camera(160, 120)


def test_zbuffer_keeps_nearest_and_ignores_behind():
    cam = CAM
    X = cam.unproject(np.array([[50.0, 40.0], [50.0, 40.0], [10.0, 10.0]]), np.array([2.0, 1.0, 3.0]))
    X = np.vstack([X, [[0.0, 0.0, -1.0]]])             # behind the camera
    d = render_depth(X, cam)
    assert d[40, 50] == pytest.approx(1.0) and d[10, 10] == pytest.approx(3.0)
    assert np.isfinite(d).sum() == 2


def test_render_previous_keyframe_and_init_scales():
    scene = synthetic.SyntheticScene.generate(3)
    poses = synthetic.make_trajectory(12, 3)
    kf0 = scene.render(CAM, poses[0])
    kf1 = scene.render(CAM, poses[11])
    prims0 = make_frontend("depth").primify(kf0.rgb, CAM, kf0.depth)     # metric geometry
    rendered = render_primitives([(prims0, poses[0])], CAM, poses[11], splat=2)
    ok = np.isfinite(rendered) & np.isfinite(kf1.depth)
    assert ok.mean() > 0.5
    # where rendered, the depth matches the true depth of the new view
    assert np.median(np.abs(rendered[ok] / kf1.depth[ok] - 1)) < 0.01
    # the new keyframe's primitives (scales unknown) take their scale from the render
    prims1 = make_frontend("depth").primify(kf1.rgb, CAM, kf1.depth)
    unscaled = prims1.with_log_scales(np.zeros(len(prims1)))
    res = init_scales_from_render(unscaled, rendered)
    d = res.primitives.depth_map()
    good = np.isfinite(d) & np.isfinite(kf1.depth)
    assert np.median(np.abs(d[good] / kf1.depth[good] - 1)) < 0.02
    assert res.fallback.sum() < len(prims1)
    with pytest.raises(ValueError, match="not visible"):
        init_scales_from_render(unscaled, np.full(CAM.shape, np.nan))
