"""The bent primitive model (issue 54): a log-scale plus two log-depth slopes per
primitive, recovered from two views of a slanted textured plane."""
import numpy as np
import pytest

import gtsam
from spgeo import PinholeCamera
from spgeo.factors.photometric import BentShape, PhotometricConfig, ScaledShape
from spgeo.factors.photometric_group import PhotometricFactorGroup
from spgeo.factors.priors import pose_gauge_prior
from spgeo.geometry import so3_exp
from spgeo.graph.builders import BEND_SIGMA, add_shape_prior

CAM = PinholeCamera(120.0, 120.0, 79.5, 59.5, 160, 120)
NORMAL = np.array([0.55, 0.25, 1.0]) / np.linalg.norm([0.55, 0.25, 1.0])   # plane n . X = D
D = 2.0


def texture(X):
    """Smooth intensity of a world point (the plane's texture)."""
    return (0.5 + 0.15 * np.sin(9.0 * X[..., 0]) * np.cos(7.0 * X[..., 1])
            + 0.1 * np.sin(5.0 * X[..., 0] + 11.0 * X[..., 1] + 3.0 * X[..., 2]))


def render(T_world_cam):
    """Exact image of the plane (world frame = reference camera) from a camera."""
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(float)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1)
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    dirs = rays @ R.T
    lam = (D - NORMAL @ t) / (dirs @ NORMAL)
    return texture(t + lam[..., None] * dirs)


def solve(model, T_tgt):
    """LM over one primitive (the central 100x70 pixels, flat integrated shape)
    with both poses held: returns the solved shape variable."""
    v, u = np.mgrid[25:95, 30:130]
    u, v = u.ravel(), v.ravel()
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(u.size)], -1)
    anchor = np.argmin((u - 80) ** 2 + (v - 60) ** 2)
    coords = rays[:, :2] - rays[anchor, :2]
    z_anchor = D / (rays[anchor] @ NORMAL)
    shape = (BentShape(rays, np.zeros(u.size), coords) if model == "bent"
             else ScaledShape(rays, np.zeros(u.size)))
    x0, x1, s = gtsam.symbol("x", 0), gtsam.symbol("x", 1), gtsam.symbol("s", 0)
    ref = render(np.eye(4))[v, u]
    group = PhotometricFactorGroup(x0, x1, [s], shape, np.array([0, u.size]), ref,
                                   render(T_tgt), CAM, None, PhotometricConfig())
    graph = gtsam.NonlinearFactorGraph()
    for f in group.factors:
        graph.add(f)
    graph.add(pose_gauge_prior(x0, np.eye(4)))
    graph.add(pose_gauge_prior(x1, T_tgt))
    theta0 = np.array([np.log(z_anchor) + 0.05, 0.0, 0.0])[:shape.dim]
    add_shape_prior(graph, s, theta0, "bent" if model == "bent" else "integrated", 1e-5, 1.0)
    vals = gtsam.Values()
    vals.insert(x0, gtsam.Pose3())
    vals.insert(x1, gtsam.Pose3(T_tgt))
    vals.insert(s, theta0)
    out = gtsam.LevenbergMarquardtOptimizer(graph, vals).optimize()
    true_logz = np.log(D / (rays @ NORMAL))
    A = np.column_stack([np.ones(u.size), coords])
    best = np.linalg.lstsq(A, true_logz, rcond=None)[0]     # the best bent shape
    theta = out.atVector(s)
    fit = A[:, :shape.dim] @ theta
    return theta, best, float(np.sqrt(np.mean((fit - true_logz) ** 2)))


@pytest.mark.parametrize("motion", ["sideways", "forward-and-up"])
def test_bent_primitive_recovers_the_slopes_of_a_slanted_plane_from_two_views(motion):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.array([0.01, -0.04, 0.02]))
    T[:3, 3] = [0.25, 0.02, 0.0] if motion == "sideways" else [0.05, 0.12, 0.25]
    theta, best, rms = solve("bent", T)
    _, _, rms_scaled = solve("scaled", T)
    # the plane's log-depth slopes (about 0.5 and 0.2 per normalised unit)
    np.testing.assert_allclose(theta[1:], best[1:], atol=0.03)
    assert abs(theta[0] - best[0]) < 0.01
    # one log-scale on the flat shape cannot follow the slant
    assert rms < 0.2 * rms_scaled
