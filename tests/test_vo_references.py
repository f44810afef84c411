"""VO evaluation references: the pycolmap SfM reference (evaluation.references.colmap_vo),
the side-by-side comparison (evaluation.vo.compare) and the TUM fr1 protocol
runner (evaluation.vo.tum_fr1).

Tolerances are measured values with margin (deterministic: one COLMAP
thread, fixed seeds; synthetic scene 0, trajectory seed 0, 25 frames rendered
at 320x240, evaluated at 160x120); the measurements are in
docs/results_parts/baselines.md.
"""
from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from spgeo.camera import PinholeCamera
from spgeo.frame import Frame
from spgeo.evaluation.trajectory import read_status, read_tum, status_path_for

pycolmap = pytest.importorskip("pycolmap")

from spgeo.evaluation.references.colmap_vo import ColmapVOConfig, run_colmap_vo  # noqa: E402
from spgeo.evaluation.vo.tum_fr1 import (  # noqa: E402
    FR1_SEQUENCES, FR1Config, crop_camera, crop_frame, format_fr1_table, main as fr1_main,
    protocol_frames, run_fr1, sequence_folder)
from spgeo.evaluation.vo.compare import (  # noqa: E402
    VOCompareRow, compare_vo, format_markdown_table, main as compare_main, write_results)

N_FRAMES = 25


@pytest.fixture(scope="module")
def frames():
    from spgeo.synthetic import SyntheticScene, default_camera, make_trajectory, render_frames

    return render_frames(SyntheticScene.generate(0), default_camera(320, 240),
                         make_trajectory(N_FRAMES, 0))


@pytest.fixture(scope="module")
def colmap_result(frames):
    return run_colmap_vo(frames, ColmapVOConfig(resolution=(160, 120)))


# ============================================================ COLMAP reference
@pytest.mark.slow
def test_colmap_vo_registers_synthetic_sequence(frames, colmap_result, tmp_path):
    res = colmap_result
    gt = [f.T_world_cam for f in frames]
    assert res.n_frames == N_FRAMES and len(res.timestamps) == N_FRAMES
    assert res.num_registered >= N_FRAMES - 2
    assert res.num_models >= 1 and res.model_sizes[0] == res.num_registered
    # fixed shared intrinsics: the frames' camera resized like the VO input
    assert res.camera == frames[0].camera.resized(160, 120)
    # camera-to-world, first registered frame at the identity, proper rotations
    first = int(np.flatnonzero(res.registered)[0])
    np.testing.assert_allclose(res.T_world_cam[first], np.eye(4), atol=1e-9)
    for T in res.T_world_cam:
        if T is not None:
            np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    ate = res.ate(gt)
    assert ate.label == "per-frame" and ate.n_associated == res.num_registered
    assert ate.rmse < 0.012, str(ate)
    assert ate.rmse_percent_of_length < 5.0, str(ate)
    # the same number from (timestamps, poses)
    stamps = [f.timestamp for f in frames]
    assert res.ate(gt, stamps).rmse == pytest.approx(ate.rmse, rel=1e-9)
    # TUM file + status round trip
    path = res.save_tum(tmp_path / "colmap.txt")
    back = read_tum(path)
    assert len(back) == res.num_registered
    np.testing.assert_allclose(back.poses[0], np.eye(4), atol=1e-8)
    _, status = read_status(status_path_for(path))
    assert status == res.status
    summary = json.loads(json.dumps(res.summary()))
    assert summary["n_registered"] == res.num_registered
    assert set(res.timings) >= {"prepare", "extract", "match", "map", "total"}


def test_colmap_vo_failures_are_reported_not_raised():
    cam = PinholeCamera(150.0, 150.0, 79.5, 59.5, 160, 120)
    res = run_colmap_vo([np.zeros((120, 160)) for _ in range(4)], camera=cam)
    assert res.num_registered == 0 and res.num_models == 0
    assert res.message and all(T is None for T in res.T_world_cam)
    assert np.all(np.isnan(res.poses))
    with pytest.raises(ValueError, match="no frames"):
        run_colmap_vo([], camera=cam)
    with pytest.raises(ValueError, match="camera is required"):
        run_colmap_vo([np.zeros((120, 160))])
    other = PinholeCamera(140.0, 140.0, 79.5, 59.5, 160, 120)
    mixed = [Frame(np.zeros((120, 160), np.float32), c, float(i))
             for i, c in enumerate((cam, other))]
    with pytest.raises(ValueError, match="shared camera"):
        run_colmap_vo(mixed)
    with pytest.raises(ValueError, match="vocab_tree_path"):
        ColmapVOConfig(loop_detection=True)
    with pytest.raises(ValueError):
        ColmapVOConfig(resolution=(0, 120))


# ================================================================== compare_vo
@pytest.mark.slow
def test_compare_vo_feature_and_colmap(frames, colmap_result, tmp_path):
    rows = compare_vo(frames, ("feature", "colmap"), resolution=(160, 120))
    assert [r.method for r in rows] == ["feature", "colmap"]
    feat, col = rows
    for r in rows:
        assert r.error is None, r.error
        assert r.n_frames == N_FRAMES and not r.oracle
        assert r.tracked_fraction >= 0.9
        for v in (r.ate_rmse_m, r.ate_percent, r.fps, r.wall_s, r.gt_length_m, r.ate_scale):
            assert math.isfinite(v) and v > 0
        assert r.ate_percent == pytest.approx(100 * r.ate_rmse_m / r.gt_length_m)
    assert feat.ate_rmse_m < 0.05 and math.isfinite(feat.kf_ate_rmse_m) and feat.n_keyframes >= 2
    assert col.ate_rmse_m < 0.012 and math.isnan(col.kf_ate_rmse_m) and col.is_keyframe is None
    # same frames, same deterministic reference as run_colmap_vo
    assert col.ate_rmse_m == pytest.approx(colmap_result.ate([f.T_world_cam for f in frames]).rmse,
                                           rel=1e-6)
    table = format_markdown_table(rows, "synthetic")
    for word in ("per-frame", "keyframe-only", "Sim(3)", "| feature |", "| colmap |"):
        assert word in table
    written = write_results(rows, tmp_path, {"dataset": "synthetic"})
    assert read_tum(written["colmap"]).poses.shape[0] == col.n_tracked
    assert read_tum(written["feature.keyframes"]).poses.shape[0] == sum(
        1 for k, T in zip(feat.is_keyframe, feat.poses) if k and np.all(np.isfinite(T)))
    payload = json.loads(written["results.json"].read_text())
    assert [r["method"] for r in payload["rows"]] == ["feature", "colmap"]


def test_compare_vo_reports_bad_methods(frames):
    with pytest.raises(ValueError, match="unknown method"):
        compare_vo(frames[:5], ("orbslam",))
    no_depth = [Frame(f.image, f.camera, f.timestamp, None, f.T_world_cam, f.name)
                for f in frames[:5]]
    (row,) = compare_vo(no_depth, ("spgeo-depth",))
    assert isinstance(row, VOCompareRow) and row.oracle
    assert row.error is not None and "depth" in row.error and math.isnan(row.ate_rmse_m)
    assert "oracle" in format_markdown_table([row])
    no_gt = [Frame(f.image, f.camera, f.timestamp, name=f.name) for f in frames[:5]]
    with pytest.raises(ValueError, match="ground truth"):
        compare_vo(no_gt, ("feature",))


def test_compare_vo_cli_on_bundled_tum(tmp_path, capsys):
    from spgeo.datasets import bundled_tum_path

    # 160x120: at the 320x240 default the ORB baseline does not initialise on these 9 frames
    rc = compare_main(["--dataset", "tum", str(bundled_tum_path()), "--methods", "feature",
                       "--resolution", "160x120", "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "per-frame" in out and "Sim(3)" in out and "| feature |" in out
    payload = json.loads((tmp_path / "results.json").read_text())
    (row,) = payload["rows"]
    assert row["n_frames"] == 9 and math.isfinite(row["ate_rmse_m"])
    assert (tmp_path / "feature.txt").is_file() and (tmp_path / "feature.status.txt").is_file()


# ================================================================== TUM fr1
def test_crop_transform_shifts_principal_point():
    from spgeo.datasets import tum_camera

    cam = tum_camera("fr1").undistorted()
    rng = np.random.default_rng(0)
    img = rng.random((480, 640, 3)).astype(np.float32)
    f = Frame(img, cam, 1.0, T_world_cam=np.eye(4), name="x")
    c = crop_frame(f, (32, 16, 32, 16))
    assert c.image.shape == (448, 576, 3) and (c.camera.width, c.camera.height) == (576, 448)
    assert c.camera.cx == pytest.approx(cam.cx - 32) and c.camera.cy == pytest.approx(cam.cy - 16)
    assert (c.camera.fx, c.camera.fy) == (cam.fx, cam.fy)
    np.testing.assert_array_equal(c.image, img[16:464, 32:608])
    # a 3-D point projects to the same image content before and after the crop
    X = np.array([[0.1, -0.05, 1.3]])
    uv, _ = cam.project(X)
    uv_c, _ = c.camera.project(X)
    np.testing.assert_allclose(uv_c, uv - [32, 16], atol=1e-9)
    # protocol: crop then resize to 160x120
    (p,) = list(protocol_frames([f], FR1Config()))
    assert p.image.shape[:2] == (120, 160)
    assert p.camera == crop_camera(cam, 32, 16, 32, 16).resized(160, 120)
    with pytest.raises(ValueError, match="undistort"):
        crop_camera(tum_camera("fr1"), 32, 16, 32, 16)
    with pytest.raises(ValueError):
        crop_camera(cam, 320, 0, 320, 0)
    with pytest.raises(ValueError, match="RGB-only"):
        FR1Config(methods=("spgeo-depth",))


def test_tum_fr1_runner_skips_missing_sequences(tmp_path, capsys):
    from spgeo.datasets import bundled_tum_path

    root = tmp_path / "fr1"
    shutil.copytree(bundled_tum_path(), sequence_folder(root, "desk"))
    report = run_fr1(root, config=FR1Config(methods=("feature",)), out_dir=tmp_path / "out")
    assert set(report.skipped) == set(FR1_SEQUENCES) - {"desk"}
    assert all(v == "not found" for v in report.skipped.values())
    (desk,) = report.evaluated
    assert desk.name == "desk" and desk.n_frames == 9
    (row,) = desk.rows
    assert row.error is None and row.n_tracked >= 8 and row.ate_rmse_m < 0.05
    mean, k = report.mean_ate("feature")
    assert k == 1 and mean == pytest.approx(row.ate_rmse_m)
    table = format_fr1_table(report)
    assert "skipped" in table and "0.153" in table and "Sim(3)" in table
    saved = json.loads((tmp_path / "out" / "fr1_report.json").read_text())
    assert saved["n_sequences_in_mean"] == {"feature": 1}
    assert (tmp_path / "out" / "desk" / "feature.txt").is_file()
    # command line: one present, one missing sequence; an empty root
    assert fr1_main(["--root", str(root), "--sequences", "desk", "xyz", "--methods", "feature",
                     "--no-progress"]) == 0
    assert "fr1/xyz | - | skipped" in capsys.readouterr().out
    empty = tmp_path / "empty"
    empty.mkdir()
    assert fr1_main(["--root", str(empty), "--methods", "feature", "--no-progress"]) == 1


def test_tum_fr1_runner_spgeo_classical(tmp_path):
    from spgeo.datasets import bundled_tum_path
    from spgeo.evaluation.vo.tum_fr1 import run_fr1_sequence

    seq = sequence_folder(tmp_path, "desk")
    shutil.copytree(bundled_tum_path(), seq)
    res = run_fr1_sequence(seq, FR1Config(methods=("spgeo-classical",)))
    assert res.skipped is None and res.n_frames == 9
    (row,) = res.rows
    assert row.method == "spgeo-classical" and not row.oracle
    assert row.error is None, row.error
    assert row.n_tracked >= 8 and row.ate_rmse_m < 0.05
    assert row.is_keyframe is not None and row.n_keyframes >= 2
