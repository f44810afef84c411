"""Sim(3) helpers and the Sim(3) pose graph of spgeo.loop (known-answer toy loops)."""
import numpy as np
import pytest

from spgeo.geometry import so3_exp
from spgeo.loop import Sim3Edge, odometry_edges, optimise_sim3_pose_graph
from spgeo.similarity import (check_sim3, from_gtsam, sim3, sim3_difference, sim3_inverse,
                              sim3_parts, to_gtsam, umeyama)

N = 20


def circle(n=N, radius=2.0):
    """Ground-truth camera-to-world poses on a loop (the camera turns with the path)."""
    out = []
    for k in range(n):
        a = 2 * np.pi * k / n
        out.append(sim3(so3_exp(np.array([0.0, a, 0.0])),
                        [radius * np.sin(a), 0.1 * np.sin(2 * a), radius * np.cos(a) - radius]))
    return out


def drifted(gt, sigma, dR, dt):
    """True keyframe similarities (rigid ground truth, depth factor ``sigma``: true depth over
    the VO's depth) and the VO's rigid poses composed from relative motions measured in each
    keyframe's own depth units (scale drift hidden) with rotation / translation errors."""
    S_true = [sim3(*sim3_parts(G)[:2], s) for G, s in zip(gt, sigma)]
    E = [gt[0]]
    for i in range(len(gt) - 1):
        R, t, _ = sim3_parts(sim3_inverse(S_true[i]) @ S_true[i + 1])
        E.append(E[-1] @ sim3(R @ so3_exp(dR[i]), t + dt[i]))
    return S_true, E


def exact_loop(S_true):
    n = len(S_true)
    return Sim3Edge(n - 1, 0, sim3_inverse(S_true[n - 1]) @ S_true[0], loop=True)


def test_sim3_gtsam_convention_and_umeyama():
    rng = np.random.default_rng(1)
    S = sim3(so3_exp(np.array([0.3, -0.2, 0.5])), [1.0, -2.0, 0.5], 1.7)
    check_sim3(S)
    p = rng.normal(size=(10, 3))
    mapped = p @ S[:3, :3].T + S[:3, 3]
    S_g = to_gtsam(S)
    assert np.allclose([S_g.transformFrom(q) for q in p], mapped, atol=1e-12)
    assert np.allclose(from_gtsam(S_g), S, atol=1e-12)
    assert np.allclose(sim3_inverse(S) @ S, np.eye(4), atol=1e-12)
    fit = umeyama(p, mapped)
    assert fit is not None and np.allclose(fit, S, atol=1e-9)
    assert umeyama(np.zeros((5, 3)), mapped[:5]) is None
    with pytest.raises(ValueError):
        check_sim3(np.diag([1.0, 1.0, -1.0, 1.0]))


def test_single_drift_edge_known_answer():
    """Drift in rotation, translation and scale enters at one odometry edge that the caller
    marks uncertain; the exact loop edge then determines every keyframe: the corrected
    similarities equal the truth (poses and per-keyframe depth factors)."""
    gt = circle()
    sigma = np.where(np.arange(N) >= 10, 1.25, 1.0)
    dR, dt = np.zeros((N - 1, 3)), np.zeros((N - 1, 3))
    dR[9], dt[9] = [0.02, 0.05, -0.03], [0.1, -0.05, 0.08]
    S_true, E = drifted(gt, sigma, dR, dt)
    edges = odometry_edges(E)
    edges[9] = Sim3Edge(9, 10, edges[9].S_i_j, sigmas=np.full(7, 10.0))
    before = max(np.linalg.norm(E[k][:3, 3] - gt[k][:3, 3]) for k in range(N))
    assert before > 0.5
    res = optimise_sim3_pose_graph(E, edges + [exact_loop(S_true)])
    for k in range(N):
        rot, trans, dlog = sim3_difference(S_true[k], res.S_world_kf[k])
        assert rot < 1e-3 and trans < 1e-4 and dlog < 1e-5, k
        assert np.allclose(res.T_world_kf[k][:3, 3], gt[k][:3, 3], atol=1e-4)
    assert np.allclose(res.scales, sigma, rtol=1e-5)
    assert res.final_error < 1e-2 * res.initial_error


def test_growing_drift_is_reduced():
    """Drift on every edge (scale drift of 1.5 % per keyframe, rotation and translation
    biases): one exact loop edge removes the scale drift at the loop's end and most of the
    position error."""
    gt = circle()
    rng = np.random.default_rng(0)
    sigma = np.exp(0.015 * np.arange(N))
    dR = rng.normal(0, 0.01, (N - 1, 3)) + [0.0, 0.01, 0.0]
    dt = rng.normal(0, 0.01, (N - 1, 3)) + [0.01, 0.0, 0.0]
    S_true, E = drifted(gt, sigma, dR, dt)
    res = optimise_sim3_pose_graph(E, odometry_edges(E) + [exact_loop(S_true)])
    err_before = np.array([np.linalg.norm(E[k][:3, 3] - gt[k][:3, 3]) for k in range(N)])
    err_after = np.array([np.linalg.norm(res.T_world_kf[k][:3, 3] - gt[k][:3, 3])
                          for k in range(N)])
    assert err_before.max() > 0.5
    assert err_after.max() < 0.25 * err_before.max()
    assert np.sqrt(np.mean(err_after ** 2)) < 0.25 * np.sqrt(np.mean(err_before ** 2))
    scale_err = np.abs(np.log(res.scales / sigma))
    assert abs(np.log(sigma[-1])) > 0.25 and scale_err.max() < 0.03
    assert res.scales[0] == pytest.approx(1.0, abs=1e-6)
    assert np.allclose(res.T_world_kf[0], E[0], atol=1e-6)


def test_no_loop_returns_input():
    gt = circle()
    rng = np.random.default_rng(2)
    _, E = drifted(gt, np.exp(0.02 * np.arange(N)), rng.normal(0, 0.01, (N - 1, 3)),
                   rng.normal(0, 0.01, (N - 1, 3)))
    res = optimise_sim3_pose_graph(E, odometry_edges(E))
    assert np.allclose(res.T_world_kf, np.array(E), atol=1e-9)
    assert np.allclose(res.scales, 1.0, atol=1e-9)
    assert res.final_error < 1e-12


def test_bad_edges_raise():
    gt = circle(3)
    with pytest.raises(ValueError):
        optimise_sim3_pose_graph(gt, [Sim3Edge(0, 5, np.eye(4))])
    with pytest.raises(ValueError):
        optimise_sim3_pose_graph(gt, [Sim3Edge(0, 1, np.eye(4), sigmas=np.ones(6))])
    with pytest.raises(ValueError):
        optimise_sim3_pose_graph([], [])
