"""Mean depth-consistency factor: Jacobians vs numerical derivatives, its
value on exact geometry, and the scale it fixes after a pure rotation."""
import numpy as np
import pytest

import gtsam
from spgeo import PinholeCamera
from spgeo.factors.depth_consistency import DepthConsistencyFactor
from spgeo.factors.photometric import PlanarShape, ScaledShape
from spgeo.geometry import invert_pose, so3_exp

from numdiff import numerical_jacobian

CAM = PinholeCamera(120.0, 115.0, 63.2, 47.7, 128, 96)
P0, P1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
N_REF, N_TGT = 3, 2
REF_KEYS = [gtsam.symbol("s", i) for i in range(N_REF)]
TGT_KEYS = [gtsam.symbol("t", i) for i in range(N_TGT)]


def pose(rot, trans):
    T = np.eye(4)
    T[:3, :3] = so3_exp(rot)
    T[:3, 3] = trans
    return T


def rays_of(u, v):
    return np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1)


def make_factor(model, T_w0, T_w1, seed=0):
    """Points on the plane z = 2 + 0.1 x of the reference camera, seen from both."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(20, 108, 150), rng.uniform(15, 80, 150)
    r0 = rays_of(u, v)
    depth0 = 2.0 / (1.0 - 0.1 * r0[:, 0])                     # z on the plane along r0
    X1 = (r0 * depth0[:, None]) @ (invert_pose(T_w1) @ T_w0)[:3, :3].T \
        + (invert_pose(T_w1) @ T_w0)[:3, 3]
    r1 = X1 / X1[:, 2:3]
    ref_ids, tgt_ids = rng.integers(0, N_REF, 150), rng.integers(0, N_TGT, 150)
    if model == "scaled":
        # unscaled log-depth = true log-depth - the primitive's true log-scale
        s_ref, s_tgt = np.array([0.3, -0.2, 0.1]), np.array([0.5, -0.4])
        shape0 = ScaledShape(r0, np.log(depth0) - s_ref[ref_ids])
        shape1 = ScaledShape(r1, np.log(X1[:, 2]) - s_tgt[tgt_ids])
        th0, th1 = s_ref[:, None], s_tgt[:, None]
    else:
        # plane 1/z = theta . r: in the reference camera (-0.05, 0, 0.5); in the
        # target from three of its points
        shape0, shape1 = PlanarShape(r0), PlanarShape(r1)
        th0 = np.tile([-0.05, 0.0, 0.5], (N_REF, 1))
        th1_one = np.linalg.lstsq(r1, 1.0 / X1[:, 2], rcond=None)[0]
        th1 = np.tile(th1_one, (N_TGT, 1))
    f = DepthConsistencyFactor(P0, P1, REF_KEYS, shape0, ref_ids, TGT_KEYS, shape1, tgt_ids,
                               sigma=0.02)
    vals = gtsam.Values()
    vals.insert(P0, gtsam.Pose3(T_w0))
    vals.insert(P1, gtsam.Pose3(T_w1))
    for k, th in zip(REF_KEYS, th0):
        vals.insert(k, np.array(th, dtype=float))
    for k, th in zip(TGT_KEYS, th1):
        vals.insert(k, np.array(th, dtype=float))
    return f, vals


T_W0 = pose([0.01, -0.02, 0.015], [0.1, 0.05, -0.02])
T_W1 = T_W0 @ pose([0.02, 0.05, -0.01], [0.15, -0.03, 0.05])


@pytest.mark.parametrize("model", ["scaled", "planar"])
def test_jacobians_match_numerical(model):
    f, vals = make_factor(model, T_W0, T_W1)
    # move away from the exact solution so no Jacobian is trivially small
    vals.update(P1, gtsam.Pose3(T_W1 @ pose([0.01, 0.0, -0.02], [0.02, 0.01, 0.03])))
    A, _ = f.factor.linearize(vals).jacobian()
    A = A * f.sigma                                     # unwhitened
    dims = [6, 6] + [vals.atVector(k).size for k in f.keys[2:]]
    offs = np.concatenate([[0], np.cumsum(dims)])
    for i, key in enumerate(f.keys):
        J_num = numerical_jacobian(f.factor, vals, key, (P0, P1))
        J = A[:, offs[i]:offs[i + 1]]
        assert np.abs(J_num).max() > 1e-4, f"key {i} has no effect"
        np.testing.assert_allclose(J, J_num, atol=1e-7, rtol=1e-5, err_msg=f"{model} key {i}")


@pytest.mark.parametrize("model", ["scaled", "planar"])
def test_zero_on_exact_geometry_and_minus_the_target_scale_error(model):
    f, vals = make_factor(model, T_W0, T_W1)
    assert abs(f.factor.unwhitenedError(vals)[0]) < 1e-9
    # the same scene scaled by 1.5 (scales, translations): still consistent
    T0, T1 = T_W0.copy(), T_W1.copy()
    T0[:3, 3] *= 1.5
    T1[:3, 3] *= 1.5
    f2, vals2 = make_factor(model, T0, T1)
    assert abs(f2.factor.unwhitenedError(vals2)[0]) < 1e-9
    # target depths 10 % too deep: r = -log 1.1
    for k in TGT_KEYS:
        th = vals.atVector(k)
        vals.update(k, th + np.log(1.1) if model == "scaled" else th / 1.1)
    assert f.factor.unwhitenedError(vals)[0] == pytest.approx(-np.log(1.1), abs=1e-9)


def test_fixes_the_target_scale_after_a_pure_rotation():
    """Two keyframes related by a pure rotation: photometry says nothing about
    the target's depth scale, the consistency factor recovers it."""
    T1 = T_W0 @ pose([0.0, 0.12, 0.02], [0.0, 0.0, 0.0])
    f, vals = make_factor("scaled", T_W0, T1)
    truth = np.array([vals.atVector(k)[0] for k in TGT_KEYS])
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f.factor)
    graph.add(gtsam.PriorFactorPose3(P0, gtsam.Pose3(T_W0), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    graph.add(gtsam.PriorFactorPose3(P1, gtsam.Pose3(T1), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for k in REF_KEYS:
        graph.add(gtsam.PriorFactorVector(k, vals.atVector(k), gtsam.noiseModel.Isotropic.Sigma(1, 1e-4)))
    # relative target scales known (sigma 1e-3), their common scale is free (sigma 300)
    graph.add(gtsam.PriorFactorVector(TGT_KEYS[0], np.array([truth[0] + 0.3]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, 300.0)))
    graph.add(gtsam.BetweenFactorVector(TGT_KEYS[0], TGT_KEYS[1], np.array([truth[1] - truth[0]]),
                                        gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
    init = gtsam.Values(vals)
    for k, s in zip(TGT_KEYS, truth):
        init.update(k, np.array([s + 0.3]))               # 35 % too deep
    est = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()
    got = np.array([est.atVector(k)[0] for k in TGT_KEYS])
    np.testing.assert_allclose(got, truth, atol=1e-3)


def test_bad_input():
    r = rays_of(np.array([60.0, 70.0]), np.array([40.0, 50.0]))
    sh = ScaledShape(r, np.zeros(2))
    with pytest.raises(ValueError, match="no correspondence"):
        DepthConsistencyFactor(P0, P1, REF_KEYS, ScaledShape(r[:0], np.zeros(0)), [],
                               TGT_KEYS, ScaledShape(r[:0], np.zeros(0)), [], 0.02)
    with pytest.raises(ValueError, match="out of range"):
        DepthConsistencyFactor(P0, P1, REF_KEYS, sh, [0, 5], TGT_KEYS, sh, [0, 1], 0.02)
    with pytest.raises(ValueError, match="sigma"):
        DepthConsistencyFactor(P0, P1, REF_KEYS, sh, [0, 1], TGT_KEYS, sh, [0, 1], 0.0)
    with pytest.raises(ValueError, match="differ"):
        DepthConsistencyFactor(P0, P0, REF_KEYS, sh, [0, 1], TGT_KEYS, sh, [0, 1], 0.02)
    # only the used shape keys enter the factor
    f = DepthConsistencyFactor(P0, P1, REF_KEYS, sh, [2, 2], TGT_KEYS, sh, [1, 1], 0.02)
    assert f.keys == [P0, P1, REF_KEYS[2], TGT_KEYS[1]]
