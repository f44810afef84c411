"""Two-view relative pose (spgeo.twoview), the COLMAP few-view cross-check
(spgeo.evaluation.references.colmap) and the pose metrics (spgeo.evaluation.pose_metrics).

Accuracy bounds are measured values with margin (deterministic: one thread,
fixed seeds; fixtures: synthetic scene 0, view set seed 0, 640x480; the TUM
fr1/desk sample, frames 0 (ref), 4, 8; the ICL-NUIM lr sample, frames 1 (ref),
3, 5, where frame 5 shares no features with frame 1 and stays unregistered);
the measurements are in docs/results_parts/baselines.md.
"""
from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest

from spgeo.frame import Frame
from spgeo.geometry import invert_pose, relative_pose, so3_exp
from spgeo.evaluation.references.colmap import (ColmapConfig, colmap_estimator, main,
                                               run_colmap_fewview)
from spgeo.evaluation.pose_compare import compare_fewview, compare_on_dataset, format_comparison
from spgeo.evaluation.pose_metrics import (compare_pose_lists, relative_pose_errors,
                                           rotation_error_deg, translation_direction_defined,
                                           translation_direction_error_deg)
from spgeo.twoview import TWO_VIEW_STATUSES, TwoViewConfig, estimate_relative_pose

pycolmap = pytest.importorskip("pycolmap")


# ================================================================ fixtures
@pytest.fixture(scope="module")
def synthetic():
    """Reference + 2 views (7.5 deg, baseline 7 % of depth) and a pure rotation."""
    from spgeo.synthetic import SyntheticScene, default_camera, make_view_set

    scene = SyntheticScene.generate(0)
    cam = default_camera(640, 480)
    T_ref, views = make_view_set(scene, cam, n_views=2, rotation_deg=7.5, baseline_frac=0.07,
                                 seed=0)
    ref = scene.render(cam, T_ref).rgb
    imgs = [scene.render(cam, T).rgb for T in views]
    T_rot = T_ref.copy()
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    T_rot[:3, :3] = T_ref[:3, :3] @ so3_exp(np.radians(5.0) * axis)
    pure_rotation = scene.render(cam, T_rot).rgb
    return {
        "camera": cam, "ref": ref, "views": imgs, "T_world_ref": T_ref, "T_world_views": views,
        "gt": [relative_pose(T_ref, T) for T in views],
        "pure_rotation": pure_rotation, "gt_pure_rotation": relative_pose(T_ref, T_rot),
    }


@pytest.fixture(scope="module")
def colmap_synthetic(synthetic):
    s = synthetic
    return run_colmap_fewview([s["ref"]] + s["views"], s["camera"])


# ============================================================ pose metrics
def test_rotation_error_deg_known_angles():
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    R = so3_exp(np.radians(3.0) * axis)
    assert rotation_error_deg(R, np.eye(3)) == pytest.approx(3.0, abs=1e-9)
    assert rotation_error_deg(np.eye(3), R) == pytest.approx(3.0, abs=1e-9)
    T = np.eye(4)
    T[:3, :3] = R
    assert rotation_error_deg(T, T) == pytest.approx(0.0, abs=1e-9)
    tiny = so3_exp(np.radians(1e-5) * axis)
    assert rotation_error_deg(tiny, np.eye(3)) == pytest.approx(1e-5, rel=1e-3)
    assert rotation_error_deg(so3_exp(np.pi * axis), np.eye(3)) == pytest.approx(180.0, abs=1e-6)
    with pytest.raises(ValueError):
        rotation_error_deg(np.full((3, 3), np.nan), np.eye(3))
    with pytest.raises(ValueError):
        rotation_error_deg(2 * np.eye(3), np.eye(3))
    with pytest.raises(ValueError):
        rotation_error_deg(np.eye(2), np.eye(3))


def test_translation_direction_error(caplog):
    assert translation_direction_error_deg([1, 0, 0], [5, 0, 0]) == pytest.approx(0.0, abs=1e-9)
    assert translation_direction_error_deg([1, 0, 0], [0, 2, 0]) == pytest.approx(90.0)
    assert translation_direction_error_deg([1, 0, 0], [-3, 0, 0]) == pytest.approx(180.0)
    T = np.eye(4)
    T[:3, 3] = [0, 0, 2]
    assert translation_direction_error_deg(T, [0, 0.1, 0.1]) == pytest.approx(45.0)
    with caplog.at_level(logging.WARNING):
        assert math.isnan(translation_direction_error_deg([0, 0, 0], [1, 0, 0]))
    assert "undefined" in caplog.text
    assert not translation_direction_defined(np.zeros(3))
    with pytest.raises(ValueError):
        translation_direction_error_deg([np.inf, 0, 0], [1, 0, 0])


def test_relative_pose_errors_and_lists():
    T_gt = np.eye(4)
    T_gt[:3, :3] = so3_exp(np.radians([0, 5.0, 0]))
    T_gt[:3, 3] = [0.1, 0, 0]
    T_est = T_gt.copy()
    T_est[:3, :3] = T_gt[:3, :3] @ so3_exp(np.radians([0, 0, 1.0]))
    T_est[:3, 3] = [3.0, 3.0 * math.tan(math.radians(2.0)), 0]  # other scale, 2 deg off
    e = relative_pose_errors(T_est, T_gt)
    assert e["rotation_error_deg"] == pytest.approx(1.0, abs=1e-9)
    assert e["translation_direction_error_deg"] == pytest.approx(2.0, abs=1e-9)
    assert e["translation_defined"] and e["gt_rotation_deg"] == pytest.approx(5.0)
    # zero translation: NaN and flagged, rotation still compared
    T0 = T_est.copy()
    T0[:3, 3] = 0
    e0 = relative_pose_errors(T0, T_gt)
    assert not e0["translation_defined"] and math.isnan(e0["translation_direction_error_deg"])
    assert e0["rotation_error_deg"] == pytest.approx(1.0, abs=1e-9)
    cmp = compare_pose_lists([T_est, None, T_gt], [T_gt, T_gt, T_gt], names=["a", "b", "c"])
    assert cmp.n_missing == 1 and not cmp.rows[1]["available"]
    assert cmp.max_rotation_error_deg == pytest.approx(1.0, abs=1e-9)
    assert cmp.median_rotation_error_deg == pytest.approx(0.5, abs=1e-9)
    assert json.dumps(cmp.to_dict())  # JSON-friendly
    with pytest.raises(ValueError):
        compare_pose_lists([T_gt], [T_gt, T_gt])


# ================================================================ two-view
TWO_VIEW_CASES = {
    # name: (config, rotation bound deg, translation-direction bound deg)
    "opencv-sift": (TwoViewConfig(backend="opencv", features="sift"), 0.5, 3.0),
    "pycolmap": (TwoViewConfig(backend="pycolmap"), 0.5, 3.0),
    "opencv-orb": (TwoViewConfig(backend="opencv", features="orb"), 1.0, 5.0),
}


@pytest.mark.parametrize("case", sorted(TWO_VIEW_CASES))
def test_two_view_synthetic_accuracy(synthetic, case):
    config, rot_bound, tdir_bound = TWO_VIEW_CASES[case]
    s = synthetic
    for img, T_gt in zip(s["views"], s["gt"]):
        res = estimate_relative_pose(s["ref"], img, s["camera"], config)
        assert res.status == "ok", res.message
        assert res.ok and res.backend == config.backend
        T = res.T_ref_tgt
        assert T.shape == (4, 4) and np.linalg.norm(T[:3, 3]) == pytest.approx(1.0)
        e = relative_pose_errors(T, T_gt)
        assert e["rotation_error_deg"] < rot_bound, (case, e)
        assert e["translation_direction_error_deg"] < tdir_bound, (case, e)
        # convention: the estimate is T_ref_tgt, not its inverse
        e_inv = relative_pose_errors(T, invert_pose(T_gt))
        assert e_inv["rotation_error_deg"] > 10.0
        assert res.num_inliers >= config.min_inliers and 0 < res.inlier_ratio <= 1
        assert res.median_parallax_deg > config.min_parallax_deg
        assert res.points_ref.shape == res.points_tgt.shape == (res.num_inliers, 2)
        assert res.translation_std_deg < config.max_translation_std_deg
        assert json.dumps(res.summary())


@pytest.mark.parametrize("backend", ["opencv", "pycolmap"])
def test_two_view_swapped_images_give_inverse(synthetic, backend):
    s = synthetic
    cfg = TwoViewConfig(backend=backend)
    fwd = estimate_relative_pose(s["ref"], s["views"][0], s["camera"], cfg)
    bwd = estimate_relative_pose(s["views"][0], s["ref"], s["camera"], cfg)
    assert fwd.ok and bwd.ok
    e = relative_pose_errors(invert_pose(bwd.T_ref_tgt), fwd.T_ref_tgt)
    assert e["rotation_error_deg"] < 0.3 and e["translation_direction_error_deg"] < 3.0


@pytest.mark.parametrize("backend", ["opencv", "pycolmap"])
def test_two_view_identical_images_flagged(synthetic, backend):
    s = synthetic
    res = estimate_relative_pose(s["ref"], s["ref"].copy(), s["camera"],
                                 TwoViewConfig(backend=backend))
    assert res.status == "low_parallax" and not res.ok
    assert res.translation_direction is None
    assert np.allclose(res.T_ref_tgt, np.eye(4), atol=1e-9)  # rotation-only, zero translation
    assert res.median_flow_px < 0.5 and "no motion" in res.message


@pytest.mark.parametrize("backend", ["opencv", "pycolmap"])
def test_two_view_pure_rotation_flagged(synthetic, backend):
    s = synthetic
    res = estimate_relative_pose(s["ref"], s["pure_rotation"], s["camera"],
                                 TwoViewConfig(backend=backend))
    assert res.status == "low_parallax", res.message
    assert np.all(res.T_ref_tgt[:3, 3] == 0)
    # the rotation-only estimate is still accurate
    assert rotation_error_deg(res.T_ref_tgt, s["gt_pure_rotation"]) < 0.1


@pytest.mark.parametrize("backend", ["opencv", "pycolmap"])
def test_two_view_blank_image_too_few_matches(synthetic, backend):
    s = synthetic
    for blank in (np.zeros((480, 640, 3), np.float32), np.full((480, 640), 128, np.uint8)):
        res = estimate_relative_pose(s["ref"], blank, s["camera"], TwoViewConfig(backend=backend))
        assert res.status == "too_few_matches" and res.T_ref_tgt is None
        assert res.num_keypoints[1] == 0 and res.status in TWO_VIEW_STATUSES


def test_two_view_bad_input(synthetic):
    s = synthetic
    cam = s["camera"]
    with pytest.raises(ValueError):
        estimate_relative_pose(s["ref"], s["ref"][:240], cam)
    bad = s["ref"].copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError):
        estimate_relative_pose(s["ref"], bad, cam)
    with pytest.raises(ValueError):
        estimate_relative_pose(s["ref"], s["ref"] * 255.0, cam)
    with pytest.raises(TypeError):
        estimate_relative_pose(s["ref"], s["ref"], cam.K)
    with pytest.raises(ValueError):
        TwoViewConfig(backend="magic")
    with pytest.raises(ValueError):
        TwoViewConfig(min_inliers=3)


# ========================================================= COLMAP few-view
def test_colmap_fewview_synthetic(synthetic, colmap_synthetic):
    s, res = synthetic, colmap_synthetic
    assert res.status == "ok", res.message
    assert res.view_method == ["incremental", "incremental"] and res.scale_consistent
    assert res.num_images == 3 and res.num_registered == 3 and res.num_points3D > 100
    assert res.mean_reprojection_error < 1.0
    assert all(n > 100 for n in res.num_verified_matches)
    assert all(d < 0.5 for d in res.two_view_disagreement_deg)
    assert res.workdir is None
    cmp = compare_pose_lists(res.T_ref_view, s["gt"])
    assert cmp.max_rotation_error_deg < 0.5, cmp.rows
    assert cmp.max_translation_direction_error_deg < 3.0, cmp.rows
    # convention: COLMAP's world-to-camera poses converted to camera-to-reference
    assert compare_pose_lists([invert_pose(T) for T in res.T_ref_view],
                              s["gt"]).max_rotation_error_deg > 10.0
    # both views' translations share one scale: their ratio is the true one
    ratio = np.linalg.norm(res.T_ref_view[0][:3, 3]) / np.linalg.norm(res.T_ref_view[1][:3, 3])
    true = np.linalg.norm(s["gt"][0][:3, 3]) / np.linalg.norm(s["gt"][1][:3, 3])
    assert ratio == pytest.approx(true, rel=0.05)


@pytest.mark.slow
def test_colmap_fewview_paths_uint8_deterministic(synthetic, colmap_synthetic, tmp_path):
    import cv2

    s = synthetic
    paths = []
    for i, img in enumerate([s["ref"]] + s["views"]):
        p = tmp_path / f"im{i}.png"
        u8 = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
        cv2.imwrite(str(p), cv2.cvtColor(u8, cv2.COLOR_RGB2BGR))
        paths.append(p if i % 2 else str(p))
    workdir = tmp_path / "colmap"
    res = run_colmap_fewview(paths, s["camera"], workdir=workdir)
    assert res.status == "ok" and res.workdir == str(workdir)
    assert (workdir / "database.db").is_file() and (workdir / "images").is_dir()
    # same pixels, same seeds, one thread: bit-identical poses
    for a, b in zip(res.T_ref_view, colmap_synthetic.T_ref_view):
        np.testing.assert_array_equal(a, b)
    # a second run in the same folder replaces the database
    res2 = run_colmap_fewview(paths, s["camera"], workdir=workdir)
    for a, b in zip(res2.T_ref_view, res.T_ref_view):
        np.testing.assert_array_equal(a, b)


def test_colmap_fewview_blank_view_partial_and_failed(synthetic):
    s = synthetic
    blank = np.zeros_like(s["ref"])
    res = run_colmap_fewview([s["ref"], s["views"][0], blank], s["camera"])
    assert res.status == "partial" and res.registered == [True, False]
    assert res.view_method == ["incremental", None] and "view 2" in res.message
    assert res.num_keypoints[2] == 0
    assert relative_pose_errors(res.T_ref_view[0], s["gt"][0])["rotation_error_deg"] < 0.5
    failed = run_colmap_fewview([s["ref"], blank], s["camera"])
    assert failed.status == "failed" and failed.T_ref_view == [None]
    assert failed.num_registered == 0


@pytest.mark.slow
def test_colmap_two_view_fallback(synthetic):
    """With the mapper unable to start (impossible initial-pair requirement) the
    views are posed from two-view geometry, with unit translations."""
    s = synthetic
    cfg = ColmapConfig(init_min_num_inliers=100000)
    res = run_colmap_fewview([s["ref"]] + s["views"], s["camera"], config=cfg)
    assert res.status == "ok" and res.view_method == ["two_view", "two_view"]
    assert not res.scale_consistent and res.num_points3D == 0
    for T, T_gt in zip(res.T_ref_view, s["gt"]):
        assert np.linalg.norm(T[:3, 3]) == pytest.approx(1.0)
        e = relative_pose_errors(T, T_gt)
        assert e["rotation_error_deg"] < 0.5 and e["translation_direction_error_deg"] < 3.0
    res = run_colmap_fewview([s["ref"]] + s["views"], s["camera"],
                             config=ColmapConfig(init_min_num_inliers=100000,
                                                 fallback_two_view=False))
    assert res.status == "failed" and "not registered" in res.message


def test_colmap_bad_input(synthetic):
    s = synthetic
    with pytest.raises(ValueError):
        run_colmap_fewview([s["ref"]], s["camera"])
    with pytest.raises(ValueError):
        run_colmap_fewview([s["ref"], s["ref"][:100]], s["camera"])
    with pytest.raises(FileNotFoundError):
        run_colmap_fewview([s["ref"], "/nonexistent/image.png"], s["camera"])
    with pytest.raises(TypeError):
        run_colmap_fewview([s["ref"], s["ref"]], s["camera"].K)
    with pytest.raises(ValueError):
        ColmapConfig(max_ratio=0)


# ============================================================== comparison
def test_compare_fewview_and_table(synthetic, colmap_synthetic):
    s = synthetic
    # a fake "spgeo" estimate: ground truth with a 1 deg rotation error on view 1
    spgeo_est = [s["gt"][0].copy(), None]
    spgeo_est[0][:3, :3] = spgeo_est[0][:3, :3] @ so3_exp(np.radians([1.0, 0, 0]))
    out = compare_fewview(spgeo_est, colmap_synthetic.T_ref_view, s["gt"])
    sp = out["vs_gt"]["spgeo"]
    assert sp["rows"][0]["rotation_error_deg"] == pytest.approx(1.0, abs=1e-9)
    assert sp["summary"]["n_missing"] == 1
    assert out["vs_gt"]["colmap"]["summary"]["max_rotation_error_deg"] < 0.5
    pair = out["pairwise"]["spgeo_vs_colmap"]["rows"][0]
    assert 0.5 < pair["rotation_error_deg"] < 1.5
    assert out["gt_motion"][0]["rotation_deg"] == pytest.approx(7.5, abs=1e-6)
    table = format_comparison(out)
    assert "spgeo vs gt rot" in table and "spgeo_vs_colmap" in table
    assert len(table.splitlines()) == 2 + 2 + 1
    json.dumps(out)
    # without ground truth only the pairwise comparison exists
    out2 = compare_fewview(spgeo_est, colmap_synthetic.T_ref_view)
    assert out2["vs_gt"] == {} and "spgeo_vs_colmap" in out2["pairwise"]
    with pytest.raises(ValueError):
        compare_fewview(spgeo_est, colmap_synthetic.T_ref_view[:1])


def test_compare_on_dataset_with_pluggable_estimators(synthetic):
    s = synthetic
    cam = s["camera"]
    frames = [Frame(image=img, camera=cam, timestamp=float(i), T_world_cam=T, name=f"f{i}")
              for i, (img, T) in enumerate(zip([s["ref"]] + s["views"],
                                               [s["T_world_ref"]] + list(s["T_world_views"])))]

    def oracle(ref, views):
        return [relative_pose(ref.T_world_cam, v.T_world_cam) for v in views]

    def broken(ref, views):
        raise RuntimeError("boom")

    def identity(ref, views):
        return [np.eye(4) for _ in views]

    out = compare_on_dataset(frames, {"oracle": oracle, "broken": broken, "identity": identity})
    assert out["frames"] == ["f0", "f1", "f2"] and out["views"] == ["f1", "f2"]
    assert out["vs_gt"]["oracle"]["summary"]["max_rotation_error_deg"] < 1e-6
    assert out["errors"]["broken"].startswith("RuntimeError")
    assert out["vs_gt"]["broken"]["summary"]["n_missing"] == 2
    ident = out["vs_gt"]["identity"]["rows"][0]
    assert ident["rotation_error_deg"] == pytest.approx(7.5, abs=1e-6)
    assert math.isnan(ident["translation_direction_error_deg"]) and not ident["translation_defined"]
    assert set(out["time_s"]) == {"oracle", "broken", "identity"}
    json.dumps(out)


# ====================================================== real data baselines
def test_tum_colmap_baseline_cli(shared_data, tmp_path, capsys):
    path = shared_data / "tum_fr1_desk_9"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    out_json = tmp_path / "tum.json"
    rc = main(["--dataset", "tum", str(path), "--frames", "0", "4", "8", "--json", str(out_json)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "colmap vs gt rot" in printed
    result = json.loads(out_json.read_text())
    assert result["colmap_result"]["status"] == "ok"
    rows = result["vs_gt"]["colmap"]["rows"]
    rot = [r["rotation_error_deg"] for r in rows]
    tdir = [r["translation_direction_error_deg"] for r in rows]
    # asserted not to regress
    assert max(rot) < 2.0, rot
    assert max(tdir) < 15.0, tdir


def test_icl_colmap_baseline(shared_data):
    from spgeo.datasets import open_dataset

    path = shared_data / "icl_nuim_lr_5"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    frames = list(open_dataset("icl", path, frames=[1, 3, 5], load_depth=False))
    est = colmap_estimator()
    out = compare_on_dataset(frames, {"colmap": est})
    res = est.last_result
    # frame 3 registers; frame 5 has no feature overlap with frame 1 and must
    # be reported unregistered, not guessed
    assert res.status == "partial" and res.registered == [True, False], res.message
    row = out["vs_gt"]["colmap"]["rows"][0]
    assert row["rotation_error_deg"] < 2.5, row
    assert row["translation_direction_error_deg"] < 5.0, row
    assert not out["vs_gt"]["colmap"]["rows"][1]["available"]
