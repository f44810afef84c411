"""Front-end pipeline on synthetic scenes: connectivity split, depth-jump split,
and accuracy of integrated primitives after one scale per primitive."""
import numpy as np
import pytest

from analytic import plane, sphere
from spgeo import PinholeCamera
from spgeo.evaluation.metrics import primitive_fit_errors
from spgeo.frontend import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd, make_frontend
from spgeo.frontend.pipeline import split_regions


class _GivenNormals:
    uses_depth = False

    def __init__(self, normals):
        self.normals = normals

    def estimate(self, image, camera, depth=None):
        return self.normals


def test_split_regions_connectivity_and_min_area():
    w, h = 20, 10
    m = np.zeros((h, w), bool)
    m[1:4, 1:6] = True          # part A (15 px)
    m[6:9, 10:15] = True        # part B (15 px)
    m[0, 19] = True             # a single pixel: below min_area
    m[5, 6] = True              # diagonal-only contact with nothing: isolated
    parts, parent = split_regions([np.flatnonzero(m)], w, h, min_area=2)
    assert sorted(p.size for p in parts) == [15, 15] and parent.tolist() == [0, 0]
    for p in parts:
        assert np.all(np.diff(p) > 0)


def test_rim_of_sphere_splits_from_wall():
    cam = PinholeCamera(300.0, 300.0, 159.5, 119.5, 320, 240)
    zw, nw = plane(cam, [0.3, 0.0, -1.0], -2.0)
    zs, ns = sphere(cam, [0.0, 0.0, 1.2], 0.3)
    front = np.isfinite(zs) & (zs < zw)
    z = np.where(front, zs, zw)
    n = np.where(front[..., None], ns, nw)
    fe = PrimitiveFrontEnd(LabelSegmenter(np.zeros(cam.shape, int)), _GivenNormals(n))
    prims = fe.primify(np.zeros(cam.shape), cam)
    assert len(prims) == 2                                  # one segment, split at the rim
    m = primitive_fit_errors(prims, z)
    assert m["median_rel"] < 1e-4 and m["coverage"] > 0.98
    # without the split a single scale cannot fit both surfaces
    fe_nosplit = PrimitiveFrontEnd(LabelSegmenter(np.zeros(cam.shape, int)), _GivenNormals(n),
                                   FrontEndConfig(split_depth_jumps=False))
    assert primitive_fit_errors(fe_nosplit.primify(np.zeros(cam.shape), cam), z)["mean_rel"] > 0.05


@pytest.fixture(scope="module")
def room_view():
    from spgeo import synthetic

    scene = synthetic.SyntheticScene.generate(1)
    cam = synthetic.default_camera(320, 240)
    pose = synthetic.make_trajectory(1, 1)[0]
    return cam, scene.render(cam, pose)


def test_oracle_frontend_recovers_depth(room_view):
    """Exact normals + ground-truth surface ids: integrated depth equals the true
    depth up to one scale per primitive (< 0.5% median)."""
    cam, view = room_view
    fe = PrimitiveFrontEnd(LabelSegmenter(view.surface_ids), _GivenNormals(view.normals))
    prims = fe.primify(view.rgb, cam)
    m = primitive_fit_errors(prims, view.depth)
    assert m["median_rel"] < 5e-3 and m["coverage"] > 0.95, m


def test_depth_frontend_on_synthetic(room_view):
    """Classical segments + normals from depth (uses depth): scales fitted to the
    same depth reproduce it closely; the fronto-parallel front-end is worse."""
    cam, view = room_view
    depth_fe = make_frontend("depth")
    prims = depth_fe.primify(view.rgb, cam, view.depth)
    assert prims.meta["uses_depth"] is True
    m_depth = primitive_fit_errors(prims, view.depth)
    # scales were already fitted to the given depth by the front-end
    direct = prims.depth_map()
    ok = np.isfinite(direct)
    assert np.median(np.abs(direct[ok] / view.depth[ok] - 1)) < 0.01
    classical = make_frontend("classical").primify(view.rgb, cam)
    assert classical.meta["uses_depth"] is False
    m_cls = primitive_fit_errors(classical, view.depth)
    assert m_depth["median_rel"] < 0.01 and m_depth["coverage"] > 0.9, m_depth
    assert m_cls["median_rel"] > 2 * m_depth["median_rel"]


def test_classical_frontend_never_reads_depth(room_view):
    cam, view = room_view

    class Untouchable:
        """Any attempt to read it as an array fails the test."""

        def __array__(self, *a, **k):
            raise AssertionError("the classical front-end read depth")

        def __getattr__(self, name):
            raise AssertionError(f"the classical front-end touched depth.{name}")

    fe = make_frontend("classical")
    prims = fe.primify(view.rgb, cam, depth=Untouchable())
    assert len(prims) > 10 and prims.coverage_fraction() > 0.95
    with pytest.raises(ValueError, match="uses depth"):
        make_frontend("depth").primify(view.rgb, cam, None)


def test_working_size_and_bad_input(room_view):
    cam, view = room_view
    fe = make_frontend("depth", FrontEndConfig(working_size=(160, 120)))
    prims = fe.primify(view.rgb, cam, view.depth)
    assert prims.camera.size == (160, 120)
    with pytest.raises(ValueError, match="shape"):
        fe.primify(view.rgb[:100], cam, view.depth)
    with pytest.raises(ValueError, match="NaN"):
        fe.primify(np.full_like(view.rgb, np.nan), cam, view.depth)
    with pytest.raises(ValueError, match="no valid"):
        fe.primify(view.rgb, cam, np.full_like(view.depth, np.nan))
    with pytest.raises(ValueError, match="unknown front-end"):
        make_frontend("sam9000")


def test_fronto_parallel_fast_path_equals_the_solve(room_view):
    """Fronto-parallel normals skip the integration (log-depth 0 exactly); the
    result equals what the solve gives for the same segments."""
    from spgeo.frontend.depth_normals import FrontoParallelNormals
    from spgeo.integration import integrate_normals_regions

    cam, view = room_view
    fe = make_frontend("classical")
    assert isinstance(fe.normal_estimator, FrontoParallelNormals)
    prims = fe.primify(view.rgb, cam)
    assert len(prims) > 10 and np.all(prims.log_depth == 0.0)
    normals = fe.normal_estimator.estimate(None, cam).astype(np.float64)
    regions = [prims.pixels[prims.offsets[i]:prims.offsets[i + 1]] for i in range(len(prims))]
    res = integrate_normals_regions(normals, regions, cam, prims.anchors,
                                    fe.config.integration)
    np.testing.assert_allclose(res.log_depth, prims.log_depth, atol=1e-9)


def test_connected_segments_skip_the_split_identically(room_view):
    """A segmentation that declares 4-connected regions of at least the minimum
    area is used as it is; the result equals splitting it."""
    cam, view = room_view
    fe = make_frontend("classical")
    seg = fe.segmenter.segment(view.rgb.astype(np.float32) / 255.0, fe.working_camera(cam))
    wcam = fe.working_camera(cam)
    assert seg.meta["regions_4connected"] and seg.meta["min_region_pixels"] >= np.ceil(
        fe.config.min_area_frac * wcam.width * wcam.height)

    class Plain:
        def segment(self, image, camera):
            s = fe.segmenter.segment(image, camera)
            s.meta.pop("regions_4connected")
            return s

    a = fe.primify(view.rgb, cam)
    b = PrimitiveFrontEnd(Plain(), fe.normal_estimator, fe.config).primify(view.rgb, cam)
    np.testing.assert_array_equal(a.pixels, b.pixels)
    np.testing.assert_array_equal(a.offsets, b.offsets)
    np.testing.assert_array_equal(a.anchors, b.anchors)
    np.testing.assert_array_equal(a.log_depth, b.log_depth)
