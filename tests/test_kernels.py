"""Compiled photometric kernels (spgeo.factors.kernels): equal to the numpy
reference (values and Jacobians) on random inputs, and the tracker's numba
and numpy backends give the same cost, gradient and Hessian."""
from dataclasses import replace

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.factors import kernels
from spgeo.factors.photometric import (PhotometricConfig, PlanarShape, ScaledShape,
                                       photometric_rows, photometric_rows_numba,
                                       photometric_rows_numpy)
from spgeo.geometry import so3_exp

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba not importable")

KEYS = ("e", "r", "valid", "behind", "weights", "J_ref", "J_tgt", "J_shape", "J_brightness")


def random_case(rng, planar: bool, dtype):
    """Random image, primitive pixels (some near / beyond the borders, some
    behind the target camera) and poses."""
    w, h = 64, 48
    cam = PinholeCamera(60.0, 62.0, 31.5, 23.5, w, h)
    img = rng.uniform(0.0, 1.0, size=(h, w)).astype(dtype)
    k = 400
    uv = rng.uniform([-3.0, -3.0], [w + 2.0, h + 2.0], size=(k, 2))
    rays = np.c_[(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(k)]
    if planar:
        shape = PlanarShape(rays)
        theta = np.array([rng.normal(0, 0.4), rng.normal(0, 0.4), 0.5])
    else:
        shape = ScaledShape(rays, rng.normal(0.0, 0.3, k))
        theta = np.array([rng.normal(0, 0.2)])
    T_ref = np.eye(4)
    T_ref[:3, :3] = so3_exp(rng.normal(0, 0.1, 3))
    T_ref[:3, 3] = rng.normal(0, 0.2, 3)
    D = np.eye(4)
    D[:3, :3] = so3_exp(rng.normal(0, 0.05, 3))
    D[:3, 3] = rng.normal(0, 0.1, 3) + [0, 0, rng.uniform(0.0, 1.5)]   # may put points behind
    ids = np.sort(rng.integers(0, 9, k))
    ids = np.unique(ids, return_inverse=True)[1].astype(np.int64)
    return cam, img, shape, theta, T_ref, T_ref @ D, rng.uniform(0, 1, k), ids


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("planar", [False, True])
def test_kernels_equal_numpy_reference(seed, planar):
    rng = np.random.default_rng(seed)
    dtype = np.float32 if seed % 2 else np.float64
    cam, img, shape, theta, T_ref, T_tgt, ref, ids = random_case(rng, planar, dtype)
    X, dX, sv = shape.points(theta)
    n = int(ids.max()) + 1
    saw_behind = saw_invalid = False
    for cfg in (PhotometricConfig(), PhotometricConfig(robust="none", normalise="all"),
                PhotometricConfig(normalise="none", huber_delta=0.01)):
        for br in (None, np.array([rng.normal(0, 0.2), rng.normal(0, 0.05)])):
            for idx, ng, gp in ((None, 1, np.array([float(X.shape[0] + 3)])),
                                (ids, n, rng.uniform(50, 80, n))):
                for jac in (True, False):
                    args = (X, dX, sv, T_ref, T_tgt, img, cam, ref, br, cfg, idx, ng, gp, jac)
                    a = photometric_rows_numpy(*args)
                    b = photometric_rows_numba(*args)
                    assert set(a) <= set(b)
                    for key in KEYS:
                        if key in a:
                            np.testing.assert_allclose(b[key], a[key], rtol=1e-6, atol=1e-9,
                                                       err_msg=key)
                    saw_behind |= bool(a["behind"].any())
                    saw_invalid |= bool((~a["valid"] & ~a["behind"]).any())
    assert saw_invalid


def test_backend_selection(monkeypatch):
    assert kernels.resolve_backend("auto") == "numba"
    assert kernels.resolve_backend("numpy") == "numpy"
    with pytest.raises(ValueError):
        kernels.resolve_backend("cuda")
    with monkeypatch.context() as m:      # without numba every backend is numpy
        m.setattr(kernels, "AVAILABLE", False)
        assert kernels.resolve_backend("numba") == kernels.resolve_backend("auto") == "numpy"
    with pytest.raises(ValueError):
        PhotometricConfig(backend="cuda")
    rng = np.random.default_rng(1)
    cam, img, shape, theta, T_ref, T_tgt, ref, ids = random_case(rng, False, np.float32)
    X, dX, sv = shape.points(theta)
    args = (X, dX, sv, T_ref, T_tgt, img, cam, ref, None)
    rest = (None, 1, np.array([float(X.shape[0])]))
    a = photometric_rows(*args, PhotometricConfig(backend="numpy"), *rest)
    b = photometric_rows(*args, PhotometricConfig(), *rest)
    np.testing.assert_allclose(b["J_tgt"], a["J_tgt"], rtol=1e-6, atol=1e-9)


def test_tracker_backends_agree():
    """TrackingCost with the compiled kernels equals its numpy path (cost,
    residuals, J, H, g), with and without brightness."""
    from spgeo import synthetic
    from spgeo.frontend import make_frontend
    from spgeo.vo.tracking import Keyframe, TrackerConfig, TrackingCost

    cam = synthetic.default_camera(80, 60)
    scene = synthetic.SyntheticScene.generate(3)
    T_kf, _ = synthetic.make_view_set(scene, cam, 1, 7.5, 0.05, 3)
    kv = scene.render(cam, T_kf)
    kf = Keyframe.build(kv.rgb, make_frontend("depth").primify(kv.rgb, cam, kv.depth), T_kf, 2)
    D = np.eye(4)
    D[:3, :3] = so3_exp(np.array([0.01, 0.03, -0.02]))
    D[:3, 3] = [0.05, -0.02, 0.03]
    pyr = kf.frame_pyramid(scene.render(cam, T_kf @ D).rgb)
    for brightness in (True, False):
        for normalise in ("valid", "all"):
            pc = PhotometricConfig(normalise=normalise)
            cfgs = [TrackerConfig(brightness=brightness, photometric=replace(pc, backend=bk))
                    for bk in ("numpy", "numba")]
            for lvl in range(len(pyr)):
                outs = [TrackingCost(kf, pyr.images[lvl], pyr.cameras[lvl], lvl, c)
                        .evaluate(T_kf @ D @ D, (0.1, -0.02)) for c in cfgs]
                a, b = outs
                assert b["cost"] == pytest.approx(a["cost"], rel=1e-9)
                for key in ("e", "r", "valid", "behind", "J", "H", "g"):
                    np.testing.assert_allclose(b[key], a[key], rtol=1e-7,
                                               atol=1e-10 * max(np.abs(a[key]).max(), 1),
                                               err_msg=key)
