"""Batched normal integration on exact normals of analytic surfaces."""
import numpy as np
import pytest

from analytic import cylinder, plane, scale_fitted_rel_error, sphere
from spgeo import PinholeCamera, integrate_normals
from spgeo.integration import IntegrationConfig, integrate_normals_regions

CAM = PinholeCamera(300.0, 300.0, 159.5, 119.5, 320, 240)
CAM_ANISO = PinholeCamera(320.0, 280.0, 171.3, 108.9, 320, 240)  # fx != fy, off-centre


def _check(z, n, mask, cam, tol=5e-3, **cfg):
    ld = integrate_normals(np.nan_to_num(n), mask[None], cam, IntegrationConfig(**cfg))[0]
    assert np.all(np.isnan(ld[~mask])) and np.all(np.isfinite(ld[mask]))
    err = scale_fitted_rel_error(ld, z, mask)
    assert np.median(err) < tol, np.median(err)
    return err


@pytest.mark.parametrize("cam", [CAM, CAM_ANISO], ids=["iso", "aniso"])
def test_tilted_plane(cam):
    z, n = plane(cam, [0.4, -0.3, -1.0], -2.0)
    mask = np.zeros(cam.shape, bool)
    mask[20:200, 30:290] = True
    err = _check(z, n, mask, cam)
    assert err.max() < 1e-5  # midpoint rule is exact to 3rd order on a plane


@pytest.mark.parametrize("cam", [CAM, CAM_ANISO], ids=["iso", "aniso"])
def test_sphere(cam):
    z, n = sphere(cam, [0.1, -0.05, 2.5], 1.0)
    mask = np.isfinite(z) & (-(n[..., 2]) > 0.3)  # keep away from the grazing rim
    err = _check(z, n, mask, cam)
    assert np.percentile(err, 99) < 2e-3


def test_cylinder():
    z, n = cylinder(CAM, [0.2, 0.0, 3.0], 1.2)
    mask = np.isfinite(z) & (-(n[..., 2]) > 0.3)
    _check(z, n, mask, CAM)


def test_two_planes_edge_mask_per_face():
    z1, n1 = plane(CAM, [0.6, 0.0, -1.0], -2.0)
    z2, n2 = plane(CAM, [-0.6, 0.0, -1.0], -2.0)
    left = z1 < z2  # the two faces of a convex edge meeting in the image
    z = np.where(left, z1, z2)
    n = np.where(left[..., None], n1, n2)
    masks = np.stack([left, ~left])
    ld = integrate_normals(n, masks, CAM)
    for k in range(2):
        err = scale_fitted_rel_error(ld[k], z, masks[k])
        assert np.median(err) < 5e-3 and err.max() < 1e-4
    # one mask across the crease: still one consistent surface (normals are integrable)
    err = _check(z, n, np.ones(CAM.shape, bool), CAM)
    assert np.percentile(err, 95) < 5e-3


def test_holes_thin_parts_and_single_pixels():
    z, n = plane(CAM, [0.3, 0.2, -1.0], -2.5)
    mask = np.zeros(CAM.shape, bool)
    mask[40:120, 40:160] = True
    mask[70:90, 80:100] = False                     # a hole
    mask[80, 160:220] = True                        # 1-pixel-wide horizontal part
    mask[81:140, 219] = True                        # 1-pixel-wide vertical part
    for k in range(10):                             # a 1-pixel diagonal staircase
        mask[140 + k, 219 + k] = True
    mask[200, 300] = True                           # an isolated single pixel
    ld = integrate_normals(n, mask[None], CAM)[0]
    assert np.all(np.isfinite(ld[mask]))
    linked = mask.copy()
    linked[200, 300] = False
    err = scale_fitted_rel_error(ld, z, linked)    # diagonal bridges keep it one surface
    assert err.max() < 1e-4
    res = integrate_normals_regions(n, [np.flatnonzero(mask)], CAM)
    assert res.n_components.tolist() == [2]        # the lone pixel is the only unlinked part


def test_single_pixel_masks_and_overlap():
    z, n = sphere(CAM, [0.0, 0.0, 2.0], 0.8)
    n = np.nan_to_num(n)
    m1 = np.zeros(CAM.shape, bool)
    m1[100:140, 140:180] = True
    m2 = np.zeros(CAM.shape, bool)
    m2[120:160, 160:200] = True                     # overlaps m1
    m3 = np.zeros(CAM.shape, bool)
    m3[120, 160] = True                             # a single pixel mask (on the sphere)
    ld = integrate_normals(n, np.stack([m1, m2, m3]), CAM)
    assert ld[2, 120, 160] == 0.0 and np.isnan(ld[2]).sum() == CAM.width * CAM.height - 1
    for k, m in enumerate([m1, m2]):
        assert np.median(scale_fitted_rel_error(ld[k], z, m)) < 1e-4


def test_anchor_and_mean_constants():
    z, n = plane(CAM, [0.2, 0.1, -1.0], -2.0)
    mask = np.zeros(CAM.shape, bool)
    mask[50:100, 50:120] = True
    anchor = 70 * CAM.width + 90
    ld = integrate_normals(n, mask[None], CAM, anchors=[anchor])[0]
    assert abs(ld.reshape(-1)[anchor]) < 1e-12
    ld_mean = integrate_normals(n, mask[None], CAM, IntegrationConfig(constant="mean"))[0]
    assert abs(np.nanmean(ld_mean)) < 1e-10
    # with the anchor constant, exp(s) with s = true log-depth at the anchor is metric
    s = np.log(z.reshape(-1)[anchor])
    np.testing.assert_allclose(np.exp(ld[mask] + s), z[mask], rtol=1e-6)


def test_cg_matches_direct():
    z, n = sphere(CAM, [0.1, 0.0, 2.0], 0.9)
    n = np.nan_to_num(n)
    rng = np.random.default_rng(0)
    masks = np.zeros((6,) + CAM.shape, bool)
    for k in range(6):
        u0, v0 = rng.integers(100, 180), rng.integers(60, 150)
        masks[k, v0:v0 + 30, u0:u0 + 40] = True
    a = integrate_normals(n, masks, CAM, IntegrationConfig(solver="direct"))
    b = integrate_normals(n, masks, CAM, IntegrationConfig(solver="cg", cg_tol=1e-10,
                                                           cg_maxiter=5000))
    np.testing.assert_allclose(a[masks], b[masks], atol=1e-6)


def test_nan_normals_and_bad_input():
    z, n = plane(CAM, [0.0, 0.3, -1.0], -2.0)
    n = n.copy()
    n[60:62, 60:200] = np.nan                       # a line of unknown normals
    mask = np.zeros(CAM.shape, bool)
    mask[40:100, 50:210] = True
    ld = integrate_normals(n, mask[None], CAM)[0]
    known = mask & np.isfinite(n[..., 0])
    assert np.all(np.isnan(ld[mask & ~known])) and np.all(np.isfinite(ld[known]))
    assert np.median(scale_fitted_rel_error(ld, z, known)) < 1e-4
    filled = integrate_normals(n, mask[None], CAM, IntegrationConfig(unknown_normals="fill"))[0]
    assert np.all(np.isfinite(filled[mask]))
    assert np.median(scale_fitted_rel_error(filled, z, mask)) < 1e-4
    with pytest.raises(ValueError, match="empty"):
        integrate_normals(n, np.zeros((1,) + CAM.shape, bool), CAM)
    with pytest.raises(ValueError, match="masks must be"):
        integrate_normals(n, np.ones((1, 10, 10), bool), CAM)
    with pytest.raises(ValueError, match="normals"):
        integrate_normals(n[:10], mask[None], CAM)
    with pytest.raises(ValueError, match="anchor"):
        integrate_normals(n, mask[None], CAM, anchors=[0])


def test_many_masks_batched_equals_one_by_one():
    from spgeo.evaluation.bench.integration import make_case

    cam, n, z, regions = make_case(40, 160, 120, seed=3)
    res = integrate_normals_regions(n, regions, cam)
    logz = np.log(z).reshape(-1)
    for i in (0, 7, len(regions) - 1):
        single = integrate_normals_regions(n, [regions[i]], cam)
        np.testing.assert_allclose(res.region(i), single.region(0), atol=1e-9)
        d = res.region(i) - logz[regions[i]]
        assert np.ptp(d) < 1e-3   # one scale per mask recovers the true depth


def _random_masks(rng, shape, n):
    """Random blobs, thin strokes, one-pixel masks and masks touching the borders."""
    h, w = shape
    masks = np.zeros((n, h, w), bool)
    for k in range(n):
        kind = k % 4
        if kind == 0:    # blob: thresholded smooth noise, may touch any border
            f = rng.normal(size=(h // 4 + 2, w // 4 + 2))
            f = np.kron(f, np.ones((4, 4)))[:h, :w]
            masks[k] = f > 0.8
        elif kind == 1:  # rectangle clipped by the image borders
            v0, u0 = rng.integers(-5, h), rng.integers(-5, w)
            dv, du = rng.integers(1, h + 1), rng.integers(1, w + 1)
            masks[k, max(v0, 0):v0 + dv, max(u0, 0):u0 + du] = True
        elif kind == 2:  # one pixel, corners included
            v, u = rng.choice([0, h - 1, rng.integers(h)]), rng.choice([0, w - 1, rng.integers(w)])
            masks[k, v, u] = True
        else:            # random scatter (many tiny parts and diagonal bridges)
            masks[k] = rng.random((h, w)) < 0.3
        if not masks[k].any():
            masks[k, rng.integers(h), rng.integers(w)] = True
    return masks


@pytest.mark.parametrize("shape,n_masks,seed", [((7, 9), 12, 0), ((30, 41), 10, 1),
                                                 ((120, 160), 8, 2), ((1, 17), 5, 3),
                                                 ((23, 1), 5, 4)])
@pytest.mark.parametrize("constant", ["anchor", "mean"])
def test_cholesky_matches_direct_random(shape, n_masks, seed, constant):
    rng = np.random.default_rng(seed)
    h, w = shape
    cam = PinholeCamera(0.8 * max(h, w) + 5, 0.7 * max(h, w) + 5, (w - 1) / 2 + 0.3,
                        (h - 1) / 2 - 0.2, w, h)
    n = rng.normal(size=(h, w, 3)) * [0.4, 0.4, 0.3] + [0.0, 0.0, -1.0]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[rng.random((h, w)) < 0.05] = np.nan     # some unknown normals
    masks = _random_masks(rng, shape, n_masks)
    ref = integrate_normals(n, masks, cam, IntegrationConfig(solver="direct", constant=constant))
    for max_band in (64, 3):   # 3: wide parts also take the fallback inside "cholesky"
        got = integrate_normals(n, masks, cam, IntegrationConfig(
            solver="cholesky", constant=constant, cholesky_max_band=max_band))
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        np.testing.assert_allclose(got[masks], ref[masks], atol=1e-6)


def test_cholesky_matches_direct_bench_case_and_wide_masks():
    from spgeo.evaluation.bench.integration import make_case

    cam, n, z, regions = make_case(60, 160, 120, seed=5)
    regions = regions + [np.arange(cam.width * cam.height)]   # one whole-image (wide) mask
    res = {s: integrate_normals_regions(n, regions, cam, None, IntegrationConfig(solver=s))
           for s in ("direct", "cholesky")}
    np.testing.assert_allclose(res["cholesky"].log_depth, res["direct"].log_depth, atol=1e-6)
    np.testing.assert_array_equal(res["cholesky"].n_components, res["direct"].n_components)
    info = res["cholesky"].solver_info
    assert info["band_groups"] >= 2 and info["factor_bytes"] > 0
    assert IntegrationConfig().solver == "cholesky"
    lone = integrate_normals_regions(n, [np.array([5]), np.array([0, 1])], cam)  # no/one edge
    assert lone.log_depth[0] == 0.0 and lone.log_depth[1] == 0.0
    with pytest.raises(ValueError, match="solver"):
        IntegrationConfig(solver="lu")


@pytest.mark.parametrize("solver", ["cholesky", "direct", "cg"])
def test_zero_rhs_parts_are_not_solved(solver):
    """Linked parts whose normals have no image-plane component integrate to 0
    without a solve; the others get what the full solve gives."""
    z, n = plane(CAM, [0.4, -0.3, -1.0], -2.0)
    flat = np.zeros_like(n)
    flat[..., 2] = -1.0
    left, right = np.zeros(CAM.shape, bool), np.zeros(CAM.shape, bool)
    left[10:100, 10:150] = True
    right[10:100, 170:300] = True
    regions = [np.flatnonzero(left), np.flatnonzero(right)]
    cfg = IntegrationConfig(solver=solver)
    res = integrate_normals_regions(flat, regions, CAM, None, cfg)
    assert np.all(res.log_depth == 0.0) and res.solver_info["n_solved_components"] == 0
    mixed = np.where(right[..., None], n, flat)     # only the right region is tilted
    res = integrate_normals_regions(mixed, regions, CAM, None, cfg)
    assert res.solver_info["n_solved_components"] == 1
    assert np.all(res.region(0) == 0.0)
    alone = integrate_normals_regions(n, regions[1:], CAM, None, cfg)
    np.testing.assert_allclose(res.region(1), alone.region(0), atol=1e-9)
    assert np.ptp(res.region(1)) > 0.1
