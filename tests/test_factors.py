"""Photometric factor: Jacobians vs numerical derivatives, cost vs docs/design.md §4."""
import numpy as np
import pytest

import gtsam
from spgeo import PinholeCamera
from spgeo.factors.photometric import (PhotometricConfig, PlanarShape, PrimitivePhotometricFactor,
                                       ScaledShape)
from spgeo.geometry import so3_exp

from numdiff import numerical_jacobian

CAM = PinholeCamera(120.0, 115.0, 63.2, 47.7, 128, 96)
X_, S_, B_ = gtsam.symbol("x", 0), gtsam.symbol("s", 0), gtsam.symbol("b", 1)
X1 = gtsam.symbol("x", 1)


def smooth_image(seed=0):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(float)
    img = 0.5 + sum(0.1 * np.sin(rng.uniform(0.05, 0.3) * u + rng.uniform(0.05, 0.3) * v
                                 + rng.uniform(0, 6)) for _ in range(6))
    return np.clip(img, 0, 1)


def pose(rot, trans):
    T = np.eye(4)
    T[:3, :3] = so3_exp(rot)
    T[:3, 3] = trans
    return T


def make_factor(model="scaled", brightness=True, robust="none", seed=0):
    rng = np.random.default_rng(seed)
    pix_u = rng.uniform(10, 118, 200)
    pix_v = rng.uniform(10, 86, 200)
    rays = np.stack([(pix_u - CAM.cx) / CAM.fx, (pix_v - CAM.cy) / CAM.fy, np.ones(200)], -1)
    if model == "scaled":
        shape = ScaledShape(rays, 0.1 * np.sin(pix_u / 20.0) + 0.05 * pix_v / 96)
        theta = np.array([np.log(2.0)])
    else:
        shape = PlanarShape(rays)
        theta = np.array([0.05, -0.03, 0.5])
    ref_int = rng.uniform(0.2, 0.8, 200)
    f = PrimitivePhotometricFactor(X_, X1, S_, shape, ref_int, smooth_image(seed), CAM,
                                   B_ if brightness else None, PhotometricConfig(robust=robust))
    vals = gtsam.Values()
    vals.insert(X_, gtsam.Pose3(pose([0.01, -0.02, 0.015], [0.1, 0.05, -0.02])))
    vals.insert(X1, gtsam.Pose3(pose([-0.03, 0.02, 0.01], [-0.08, 0.02, 0.05])))
    vals.insert(S_, theta)
    if brightness:
        vals.insert(B_, np.array([0.1, -0.05]))
    return f, vals


@pytest.mark.parametrize("model", ["scaled", "planar"])
@pytest.mark.parametrize("brightness", [True, False])
def test_jacobians_match_numerical(model, brightness):
    f, vals = make_factor(model, brightness)
    lin = f.factor.linearize(vals)
    A, b = lin.jacobian()
    keys = list(f.keys)
    dims = [6, 6, 1 if model == "scaled" else 3] + ([2] if brightness else [])
    offs = np.concatenate([[0], np.cumsum(dims)])
    valid = f.evaluate(vals.atPose3(X_).matrix(), vals.atPose3(X1).matrix(),
                       vals.atVector(S_), vals.atVector(B_) if brightness else None)["valid"]
    assert valid.mean() > 0.8
    for i, key in enumerate(keys):
        J_num = numerical_jacobian(f.factor, vals, key, (X_, X1))
        J = A[:, offs[i]:offs[i + 1]]
        scale = np.abs(J_num).max()
        assert scale > 0
        np.testing.assert_allclose(J, J_num, atol=1e-6 * scale + 1e-9,
                                   err_msg=f"Jacobian of key {i} ({model}, brightness={brightness})")


def test_huber_jacobian_is_weighted_plain_jacobian():
    f_h, vals = make_factor(robust="huber")
    f_n, _ = make_factor(robust="none")
    args = (vals.atPose3(X_).matrix(), vals.atPose3(X1).matrix(), vals.atVector(S_),
            vals.atVector(B_))
    rh, rn = f_h.evaluate(*args), f_n.evaluate(*args)
    rho = rh["weights"] / np.where(rn["weights"] > 0, rn["weights"], 1)
    assert np.any(rho < 0.999)            # some residuals beyond delta are down-weighted
    for k in ("J_ref", "J_tgt", "J_shape", "J_brightness"):
        np.testing.assert_allclose(rh[k], rho[:, None] * rn[k], atol=1e-12)


def test_error_equals_design_cost_hand_computed():
    """0.5 * mean |I_r(u) - I_t(u')| ^2 over valid pixels, with a hand-made warp:
    pure translation along x of a fronto-parallel primitive at depth 2 shifts
    every pixel by fx * tx / z."""
    img_t = np.tile(np.linspace(0, 1, CAM.width), (CAM.height, 1))  # I_t(u, v) = u / (W - 1)
    pix_u = np.array([20.0, 40.0, 60.0, 126.0])
    pix_v = np.array([30.0, 40.0, 50.0, 60.0])
    rays = np.stack([(pix_u - CAM.cx) / CAM.fx, (pix_v - CAM.cy) / CAM.fy, np.ones(4)], -1)
    ref = np.array([0.1, 0.3, 0.5, 0.2])
    f = PrimitivePhotometricFactor(X_, X1, S_, ScaledShape(rays, np.zeros(4)), ref, img_t, CAM,
                                   config=PhotometricConfig(robust="none"))
    vals = gtsam.Values()
    vals.insert(X_, gtsam.Pose3())
    vals.insert(X1, gtsam.Pose3(pose([0, 0, 0], [-0.1, 0, 0])))   # target camera moved -x
    vals.insert(S_, np.array([np.log(2.0)]))
    shift = CAM.fx * 0.1 / 2.0                                      # pixels, towards +u
    u_t = pix_u + shift                                             # the last one leaves the image
    inside = u_t <= CAM.width - 1
    r = u_t / (CAM.width - 1) - ref
    assert inside.tolist() == [True, True, True, False]
    # default: mean over the pixels valid in the target
    assert f.factor.error(vals) == pytest.approx(0.5 * np.mean(r[inside] ** 2), rel=1e-9)
    f_all = PrimitivePhotometricFactor(X_, X1, S_, ScaledShape(rays, np.zeros(4)), ref, img_t,
                                       CAM, config=PhotometricConfig(robust="none",
                                                                     normalise="all"))
    assert f_all.factor.error(vals) == pytest.approx(0.5 * np.sum(r[inside] ** 2) / 4, rel=1e-9)
    e = f.factor.unwhitenedError(vals)
    assert e.shape == (4,) and e[3] == 0.0                          # fixed length, zero row


def test_bad_input():
    rays = np.ones((3, 3))
    with pytest.raises(ValueError, match="pixels"):
        PrimitivePhotometricFactor(X_, X1, S_, ScaledShape(rays, np.zeros(3)), np.zeros(4),
                                   np.zeros(CAM.shape), CAM)
    with pytest.raises(ValueError, match="target image"):
        PrimitivePhotometricFactor(X_, X1, S_, ScaledShape(rays, np.zeros(3)), np.zeros(3),
                                   np.zeros((5, 5)), CAM)
    with pytest.raises(ValueError, match="NaN"):
        PrimitivePhotometricFactor(X_, X1, S_, ScaledShape(rays, np.zeros(3)),
                                   np.array([0, np.nan, 0]), np.zeros(CAM.shape), CAM)
    with pytest.raises(ValueError, match="differ"):
        PrimitivePhotometricFactor(X_, X_, S_, ScaledShape(rays, np.zeros(3)), np.zeros(3),
                                   np.zeros(CAM.shape), CAM)


def test_points_behind_a_camera_cost_a_penalty_not_zero():
    """A plane flipped behind the reference camera must not make the cost vanish."""
    rng = np.random.default_rng(0)
    rays = np.stack([rng.uniform(-0.4, 0.4, 50), rng.uniform(-0.3, 0.3, 50), np.ones(50)], -1)
    f = PrimitivePhotometricFactor(X_, X1, S_, PlanarShape(rays), rng.uniform(0.4, 0.6, 50),
                                   smooth_image(), CAM, config=PhotometricConfig())
    vals = gtsam.Values()
    vals.insert(X_, gtsam.Pose3())
    vals.insert(X1, gtsam.Pose3(pose([0.01, 0, 0], [0.05, 0, 0])))
    vals.insert(S_, np.array([0.0, 0.0, 0.5]))
    good = f.factor.error(vals)
    vals.update(S_, np.array([0.0, 0.0, -0.5]))            # every point behind the camera
    flipped = f.factor.error(vals)
    assert flipped > good and flipped > 0.01
    lin = f.factor.linearize(vals)
    assert np.all(lin.jacobian()[0] == 0)                   # constant penalty, no gradient


def test_priors_weights_and_gauge():
    from spgeo.factors.priors import (brightness_prior, log_scale_prior, planar_slope_prior,
                                      pose_gauge_prior)

    vals = gtsam.Values()
    vals.insert(S_, np.array([2.0]))
    # the paper's weight: cost weight * (s - s0)^2 (gtsam's error is 0.5 * |r / sigma|^2)
    assert log_scale_prior(S_, 0.0).error(vals) == pytest.approx(0.5 * 1e-5 * 4.0)
    assert log_scale_prior(S_, 2.0).error(vals) == 0.0
    with pytest.raises(ValueError):
        log_scale_prior(S_, 0.0, weight=0.0)
    vals.insert(X_, gtsam.Pose3(pose([0.01, 0, 0], [0, 0, 0])))
    assert pose_gauge_prior(X_).error(vals) > 1e6              # tight gauge
    vals.insert(B_, np.array([0.3, 0.0]))
    assert brightness_prior(B_).error(vals) == pytest.approx(0.5)
    vals.insert(X1, gtsam.Pose3())
    k = gtsam.symbol("p", 0)
    vals.insert(k, np.array([0.2, 0.0, 0.5]))
    assert planar_slope_prior(k, 0.5, slope_sigma=0.2).error(vals) == pytest.approx(0.5)


@pytest.mark.parametrize("model", ["scaled", "planar"])
@pytest.mark.parametrize("normalise", ["valid", "all", "none"])
def test_factor_group_equals_individual_factors(model, normalise):
    """PhotometricFactorGroup: every factor's error and Jacobians equal the
    stand-alone PrimitivePhotometricFactor of that primitive (with pixels
    leaving the image and a primitive behind the camera in the mix), the
    batch is evaluated once per linearisation, and a changed variable is never
    served from the cache."""
    from spgeo.factors.photometric_group import PhotometricFactorGroup

    rng = np.random.default_rng(3)
    cfg = PhotometricConfig(robust="huber", normalise=normalise)
    img = smooth_image(1)
    sizes = [30, 1, 55, 12]
    pix_u = rng.uniform(-20, 140, sum(sizes))          # some project outside the image
    pix_v = rng.uniform(-10, 100, sum(sizes))
    rays = np.stack([(pix_u - CAM.cx) / CAM.fx, (pix_v - CAM.cy) / CAM.fy,
                     np.ones(pix_u.size)], -1)
    ld = 0.1 * np.sin(pix_u / 20.0)
    ref_int = rng.uniform(0.2, 0.8, pix_u.size)
    off = np.concatenate([[0], np.cumsum(sizes)])
    skeys = [gtsam.symbol("s", i) for i in range(len(sizes))]
    if model == "scaled":
        shape = ScaledShape(rays, ld)
        thetas = [np.array([v]) for v in (0.3, -0.2, 0.7, 0.0)]
        sub = [ScaledShape(rays[a:b], ld[a:b]) for a, b in zip(off[:-1], off[1:])]
    else:
        shape = PlanarShape(rays)
        thetas = [np.array([0.05, -0.03, 0.5]), np.array([0.0, 0.0, 0.4]),
                  np.array([0.0, 0.0, -0.5]), np.array([0.1, 0.02, 0.3])]   # one behind
        sub = [PlanarShape(rays[a:b]) for a, b in zip(off[:-1], off[1:])]
    n_all = np.array(sizes, float) * 2
    group = PhotometricFactorGroup(X_, X1, skeys, shape, off, ref_int, img, CAM, B_, cfg,
                                   n_pixels=n_all)
    singles = [PrimitivePhotometricFactor(X_, X1, skeys[i], sub[i], ref_int[a:b], img, CAM, B_,
                                          cfg, n_pixels=int(n_all[i]))
               for i, (a, b) in enumerate(zip(off[:-1], off[1:]))]
    vals = gtsam.Values()
    vals.insert(X_, gtsam.Pose3(pose([0.01, -0.02, 0.015], [0.1, 0.05, -0.02])))
    vals.insert(X1, gtsam.Pose3(pose([-0.03, 0.02, 0.01], [-0.08, 0.02, 0.05])))
    vals.insert(B_, np.array([0.1, -0.05]))
    for k, th in zip(skeys, thetas):
        vals.insert(k, th)
    graph = gtsam.NonlinearFactorGraph()
    for f in group.factors:
        graph.add(f)
    lin = graph.linearize(vals)
    assert group.n_batch_evaluations == 1
    for i, s in enumerate(singles):
        A_g, b_g = lin.at(i).jacobian()
        A_s, b_s = s.factor.linearize(vals).jacobian()
        np.testing.assert_allclose(A_g, A_s, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b_g, b_s, rtol=1e-12, atol=1e-12)
    # change one primitive's variable only: its error must follow
    vals.update(skeys[2], thetas[2] + 0.05)
    np.testing.assert_allclose(group.factors[2].unwhitenedError(vals),
                               singles[2].factor.unwhitenedError(vals), atol=1e-14)
    assert graph.error(vals) == pytest.approx(sum(s.factor.error(vals) for s in singles), rel=1e-12)
    # evaluate_at reads the same variables from a Values: the singles' rows, concatenated
    e_all = group.evaluate_at(vals)["e"]
    np.testing.assert_allclose(e_all, np.concatenate([s.factor.unwhitenedError(vals)
                                                      for s in singles]), atol=1e-14)


@pytest.mark.parametrize("model", ["scaled", "planar"])
@pytest.mark.parametrize("brightness", [True, False])
@pytest.mark.parametrize("backend", ["auto", "numpy"])
def test_factor_group_chunks_give_the_same_cost_and_linear_system(model, brightness, backend):
    """chunk > 1 stacks primitives into one gtsam factor in square-root form:
    same total error, same Hessian / gradient of the linearised system as one
    factor each (pixels outside the image and a primitive behind the camera in
    the mix), and c * dim + m + 1 rows per chunk whatever its pixel count."""
    from spgeo.factors.photometric_group import PhotometricFactorGroup

    rng = np.random.default_rng(5)
    sizes = [9, 14, 1, 20, 7, 40, 3]
    k = sum(sizes)
    u, v = rng.uniform(-10, 140, k), rng.uniform(-5, 100, k)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(k)], -1)
    off = np.concatenate([[0], np.cumsum(sizes)])
    skeys = [gtsam.symbol("s", i) for i in range(len(sizes))]
    vals = gtsam.Values()
    vals.insert(X_, gtsam.Pose3(pose([0.01, -0.02, 0.015], [0.1, 0.05, -0.02])))
    vals.insert(X1, gtsam.Pose3(pose([-0.03, 0.02, 0.01], [-0.08, 0.02, 0.05])))
    bkey = B_ if brightness else None
    if brightness:
        vals.insert(B_, np.array([0.05, 0.01]))
    for i, key in enumerate(skeys):
        if model == "scaled":
            vals.insert(key, np.array([0.1 * i]))
        else:   # primitive 3 lies behind the camera
            vals.insert(key, np.array([0.02 * i, -0.01, -0.4 if i == 3 else 0.3 + 0.02 * i]))
    shape = (ScaledShape(rays, 0.05 * np.sin(u / 9)) if model == "scaled" else PlanarShape(rays))
    m = 12 + (2 if brightness else 0)
    out = {}
    for chunk in (1, 2, 5, 7):
        grp = PhotometricFactorGroup(X_, X1, skeys, shape, off, np.linspace(0.3, 0.7, k),
                                     smooth_image(2), CAM, bkey, PhotometricConfig(backend=backend),
                                     chunk=chunk)
        graph = gtsam.NonlinearFactorGraph()
        for f in grp.factors:
            graph.add(f)
        assert graph.size() == -(-len(sizes) // chunk)
        if chunk > 1:
            c0 = min(chunk, len(sizes))
            assert grp.factors[0].unwhitenedError(vals).size == c0 * shape.dim + m + 1
        lin = graph.linearize(vals)
        order = gtsam.Ordering()
        for key in [X_, X1] + ([B_] if brightness else []) + skeys:
            order.push_back(key)
        b = lin.jacobian(order)[1]
        out[chunk] = (graph.error(vals), lin.hessian(order), 0.5 * float(b @ b))
    H1, g1 = out[1][1]
    scale = np.abs(H1).max()
    for chunk in (2, 5, 7):
        assert out[chunk][0] == pytest.approx(out[1][0], rel=1e-12)
        assert out[chunk][2] == pytest.approx(out[1][2], rel=1e-10)   # linear cost at 0
        np.testing.assert_allclose(out[chunk][1][0], H1, rtol=1e-9, atol=1e-11 * scale)
        np.testing.assert_allclose(out[chunk][1][1], g1, rtol=1e-9, atol=1e-11 * scale)
