"""Refinement of the verified loop similarity (spgeo.loop.refine, docs/design.md §5.2)."""
import numpy as np

from spgeo.geometry import rotation_angle_deg
from spgeo.loop import KeyframeFeatures, VerificationConfig, verify_sim3
from spgeo.loop.refine import refine_sim3
from spgeo.similarity import sim3, sim3_parts
from spgeo.synthetic.poses import default_camera


def rot(axis, deg):
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.radians(deg) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def project(P, cam):
    return np.stack([cam.fx * P[:, 0] / P[:, 2] + cam.cx, cam.fy * P[:, 1] / P[:, 2] + cam.cy], 1)


def make_matches(seed=0, n=150, depth_noise=0.04, px_noise=0.3):
    """Query/candidate features of the same points under a known Sim(3), rough depths."""
    rng = np.random.default_rng(seed)
    cam = default_camera(160, 120)
    S_true = sim3(rot([0.3, 1.0, 0.2], 12.0), np.array([0.15, -0.05, 0.1]), 1.3)
    uv_q = rng.uniform([10, 10], [150, 110], (n, 2))
    z_q = rng.uniform(1.0, 3.0, n)
    P_q = np.stack([(uv_q[:, 0] - cam.cx) / cam.fx * z_q, (uv_q[:, 1] - cam.cy) / cam.fy * z_q, z_q], 1)
    P_c = P_q @ S_true[:3, :3].T + S_true[:3, 3]
    uv_c = project(P_c, cam)

    def noisy(uv, P):
        uvn = uv + rng.normal(0, px_noise, uv.shape)
        zn = P[:, 2] * np.exp(rng.normal(0, depth_noise, len(P)))
        X = np.stack([(uvn[:, 0] - cam.cx) / cam.fx * zn, (uvn[:, 1] - cam.cy) / cam.fy * zn, zn], 1)
        return KeyframeFeatures(uvn, None, X, cam)

    return noisy(uv_q, P_q), noisy(uv_c, P_c), S_true


def rotation_error(S, S_true):
    return rotation_angle_deg(sim3_parts(S)[0].T @ sim3_parts(S_true)[0])


def test_loop_edge_accuracy_with_realistic_noise():
    """PnP + refinement recover a known Sim(3) from keypoints (0.3 px noise) and rough
    depths (4 % noise): rotation within 0.3 deg, scale within 2 %, and 150 inliers."""
    cfg = VerificationConfig(reprojection_px=3.0, depth_tolerance=0.15, min_inliers=20)
    for seed in range(3):
        query, cand, S_true = make_matches(seed)
        pairs = np.stack([np.arange(len(query.points))] * 2, 1)
        ver = verify_sim3(query, cand, pairs, cfg)
        assert ver.accepted and ver.n_inliers >= 140, (seed, ver.n_inliers)
        assert rotation_error(ver.S_cand_query, S_true) < 0.3, seed
        assert abs(np.log(sim3_parts(ver.S_cand_query)[2] / 1.3)) < 0.02, seed


def test_information_matches_the_spread_of_the_estimates():
    """The information of the refinement (pixels, sigma 1) predicts the spread of the
    verified similarity over noise draws: the predicted rotation and log-scale standard
    deviations are within a factor 2 of the empirical ones."""
    from spgeo.similarity import sim3_inverse, to_gtsam
    import gtsam

    cfg = VerificationConfig(reprojection_px=6.0, depth_tolerance=0.5, min_inliers=20)
    xis, covs = [], []
    for seed in range(40):
        query, cand, S_true = make_matches(seed + 10, depth_noise=0.07, px_noise=0.7)
        pairs = np.stack([np.arange(len(query.points))] * 2, 1)
        ver = verify_sim3(query, cand, pairs, cfg)
        assert ver.accepted
        xis.append(gtsam.Similarity3.Logmap(to_gtsam(sim3_inverse(S_true) @ ver.S_cand_query)))
        covs.append(np.linalg.inv(ver.information))
    emp = np.std(np.array(xis), axis=0)
    pred = np.sqrt(np.diag(np.mean(covs, axis=0)))
    for i in (0, 1, 2, 6):
        assert 0.5 < pred[i] / emp[i] < 2.0, (i, pred, emp)


def test_refine_sim3_keeps_exact_model():
    query, cand, S_true = make_matches(0, depth_noise=0.0, px_noise=0.0)
    S = refine_sim3(S_true, query.points, cand.points, query.keypoints, cand.keypoints,
                    query.camera, cand.camera)
    assert np.allclose(S, S_true, atol=1e-6)
    assert refine_sim3(S_true, query.points[:3], cand.points[:3], query.keypoints[:3],
                       cand.keypoints[:3], query.camera, cand.camera) is None
