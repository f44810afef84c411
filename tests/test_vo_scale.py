"""Monocular scale of the VO map: the two-view start of the initialisation
(spgeo.vo.initialisation.twoview_start, init_rejection) and the keyframe scale
check by reverse tracking (spgeo.vo.scale_check)."""
from types import SimpleNamespace

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frontend import make_frontend
from spgeo.geometry import invert_pose, relative_pose, rotation_angle_deg
from spgeo.vo.initialisation import init_rejection, twoview_start
from spgeo.vo.keyframe import Keyframe
from spgeo.vo.scale_check import reverse_scale_check

CAM = synthetic.default_camera(320, 240)


def _pair(baseline_frac):
    """Two views of a synthetic room (baseline ``baseline_frac`` of the median
    depth) with depth-front-end primitives of the second (metric shape and scales)."""
    scene = synthetic.SyntheticScene.generate(2)
    T_a, views = synthetic.make_view_set(scene, CAM, 1, 3.0, baseline_frac, 2)
    T_b = views[0]
    ra, rb = scene.render(CAM, T_a, supersample=2), scene.render(CAM, T_b, supersample=2)
    prims_b = make_frontend("depth").primify(rb.rgb, CAM, rb.depth)
    return {"T_a": T_a, "T_b": T_b, "a": ra, "b": rb, "prims_b": prims_b}


@pytest.fixture(scope="module")
def pair():
    """A small baseline (8 %): the features see no parallax there."""
    return _pair(0.08)


@pytest.fixture(scope="module")
def wide():
    """A 15 % baseline: the feature-based two-view geometry is "ok"."""
    return _pair(0.15)


def _keyframe(pair, q):
    """Keyframe b with its depths multiplied by ``q`` (wrong units for q != 1)."""
    prims = pair["prims_b"]
    prims = prims.with_log_scales(prims.log_scales + np.log(q))
    return Keyframe.build(pair["b"].rgb, prims, pair["T_b"], levels=3)


@pytest.mark.parametrize("q", [0.9, 1.0, 1.1])
def test_scale_check_measures_the_keyframe_units(pair, q):
    check = reverse_scale_check(_keyframe(pair, q), pair["a"].rgb, pair["T_a"])
    assert check.reason == ""
    assert check.parallax > 0.05
    # depths q times too large: the tracked translation is q times the known one
    assert check.ratio == pytest.approx(q, rel=0.03)
    assert check.log_correction == pytest.approx(-np.log(q), abs=0.03)


def test_scale_check_is_limited_and_needs_parallax(pair):
    check = reverse_scale_check(_keyframe(pair, 0.6), pair["a"].rgb, pair["T_a"],
                                max_change=0.2)
    assert check.ratio == pytest.approx(0.6, rel=0.05)
    assert check.log_correction == pytest.approx(np.log(1.2), abs=1e-12)
    kf = _keyframe(pair, 1.0)
    none = reverse_scale_check(kf, pair["b"].rgb, pair["T_b"])
    assert (none.reason, none.ratio, none.log_correction) == ("parallax", None, 0.0)
    with pytest.raises(ValueError, match="max_change"):
        reverse_scale_check(kf, pair["a"].rgb, pair["T_a"], max_change=0.0)


def test_twoview_start_pose_and_scales(wide):
    pair = wide
    prims_a = make_frontend("classical").primify(pair["a"].rgb, CAM)
    out = twoview_start(pair["a"].rgb, pair["b"].rgb, CAM, prims_a)
    assert out is not None
    T, prims = out
    T_gt = relative_pose(pair["T_a"], pair["T_b"])
    assert rotation_angle_deg(T[:3, :3].T @ T_gt[:3, :3]) < 0.5
    cos = T[:3, 3] @ T_gt[:3, 3] / (np.linalg.norm(T[:3, 3]) * np.linalg.norm(T_gt[:3, 3]))
    assert np.degrees(np.arccos(min(cos, 1.0))) < 5.0
    # units: keyframe 0's median depth is 1, the baseline in the same units
    depth = np.exp(prims.scaled_log_depth())
    assert np.median(depth) == pytest.approx(1.0, rel=1e-9)
    gt = pair["a"].depth.reshape(-1)[prims.pixels]
    ok = np.isfinite(gt) & (gt > 0)
    s = np.median(gt[ok]) / 1.0
    assert np.linalg.norm(T[:3, 3]) * s == pytest.approx(np.linalg.norm(T_gt[:3, 3]), rel=0.25)
    assert np.median(np.abs(depth[ok] * s / gt[ok] - 1)) < 0.25


def test_twoview_start_without_parallax_or_texture(pair):
    prims_a = make_frontend("classical").primify(pair["a"].rgb, CAM)
    T, prims = twoview_start(pair["a"].rgb, pair["a"].rgb, CAM, prims_a)
    assert np.allclose(T, np.eye(4), atol=1e-6)        # rotation-only estimate, zero translation
    assert np.all(prims.log_scales == 0)
    # the small baseline: the rotation-only estimate, zero translation, unscaled primitives
    T, prims = twoview_start(pair["a"].rgb, pair["b"].rgb, CAM, prims_a)
    assert np.all(T[:3, 3] == 0) and rotation_angle_deg(T[:3, :3]) > 0.5
    assert np.all(prims.log_scales == 0)
    blank = np.full_like(pair["a"].rgb, 0.5)
    assert twoview_start(blank, blank, CAM, prims_a) is None


def test_init_rejection():
    def sfm(view="ok", status="ok", T=np.eye(4)):
        return SimpleNamespace(T_ref_view=[T], view_status=[view], report={"parallax": [0.01]},
                               status=status)
    assert init_rejection(sfm(), tracked=True) is None
    # an untracked keyframe 1 whose SfM is ok initialises (its parallax is checked by the
    # caller only before init.max_gap)
    assert init_rejection(sfm(), tracked=False) is None
    assert "low_parallax" in init_rejection(sfm(view="low_parallax"), tracked=True)
    assert "status flagged" in init_rejection(sfm(status="flagged"), tracked=False)
    assert "non-finite" in init_rejection(sfm(T=np.full((4, 4), np.nan)), tracked=True)
