"""Z-buffered rendering of primitives and keyframe scale initialisation."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frontend import make_frontend

from spgeo.vo.rendering import init_scales_from_render, render_depth, render_primitives

CAM = synthetic.default_camera(160, 120)


def test_zbuffer_keeps_nearest_and_ignores_behind():
    cam = CAM
    X = cam.unproject(np.array([[50.0, 40.0], [50.0, 40.0], [10.0, 10.0]]), np.array([2.0, 1.0, 3.0]))
    X = np.vstack([X, [[0.0, 0.0, -1.0]]])             # behind the camera
    d = render_depth(X, cam)
    assert d[40, 50] == pytest.approx(1.0) and d[10, 10] == pytest.approx(3.0)
    assert np.isfinite(d).sum() == 2


def test_soft_zbuffer_averages_one_surface_and_keeps_occlusion():
    """With a tolerance, estimates within it of the nearest are averaged (geometric
    mean); a surface further behind stays occluded; tolerance 0 is the plain z-buffer."""
    uv = np.array([[50.0, 40.0]] * 3 + [[10.0, 10.0]])
    X = CAM.unproject(uv, np.array([1.0, 1.1, 2.0, 3.0]))
    hard = render_depth(X, CAM)
    soft = render_depth(X, CAM, tolerance=0.2)
    assert hard[40, 50] == pytest.approx(1.0)
    assert soft[40, 50] == pytest.approx(np.sqrt(1.1))
    assert soft[10, 10] == pytest.approx(3.0)
    assert np.isfinite(soft).sum() == 2


def test_soft_zbuffer_removes_the_nearest_estimate_bias():
    """Five noisy estimates (1 % log-depth noise) of a wall at 2 m: the nearest-wins
    render is biased towards the camera by about a noise standard deviation per
    pixel, the tolerant render is not."""
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:CAM.height, 0:CAM.width]
    uv = np.stack([u.ravel(), v.ravel()], 1).astype(float)
    X = np.concatenate([CAM.unproject(uv, 2.0 * np.exp(0.01 * rng.standard_normal(len(uv))))
                        for _ in range(5)])
    hard = np.nanmedian(np.log(render_depth(X, CAM) / 2.0))
    soft = np.nanmedian(np.log(render_depth(X, CAM, tolerance=0.2) / 2.0))
    assert hard < -0.008
    assert abs(soft) < 0.002


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


def test_unrendered_primitives_keep_their_relative_scale():
    """A primitive the render does not reach keeps its own scale shifted by the
    median shift of the rendered ones (the depth front-end's relative depth),
    which for equal incoming scales is the median of the others."""
    scene = synthetic.SyntheticScene.generate(3)
    view = scene.render(CAM, synthetic.make_trajectory(2, 3)[0])
    prims = make_frontend("depth").primify(view.rgb, CAM, view.depth)   # metric scales
    # a render that covers only the left half of the image, at 1.3x the true depth
    rendered = np.where(np.arange(CAM.width)[None, :] < CAM.width // 2, 1.3 * view.depth, np.nan)
    res = init_scales_from_render(prims, rendered)
    fb = res.fallback
    assert fb.any() and (~fb).any()
    np.testing.assert_allclose(res.primitives.log_scales[fb],
                               prims.log_scales[fb] + np.log(1.3), atol=0.02)
    # equal incoming scales: the unrendered ones take the median of the others
    flat = prims.with_log_scales(np.zeros(len(prims)))
    res = init_scales_from_render(flat, rendered)
    np.testing.assert_allclose(res.primitives.log_scales[res.fallback],
                               np.median(res.primitives.log_scales[~res.fallback]))
