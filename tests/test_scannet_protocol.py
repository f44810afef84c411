"""ScanNet few-view SfM protocol: reader (SensReader export layout), view-set
selection, runner end to end on a synthetic scene written in the same layout."""
import json

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.sfm import scannet as S
from spgeo.geometry import so3_exp

N_FRAMES, SKIP = 61, 10
COLOR, DEPTH = (324, 242), (160, 120)   # colour not a multiple of depth: per-axis scaling
SEED = 0


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("scannet")
    scene = synthetic.SyntheticScene.generate(SEED)
    path = S.write_synthetic_scannet(root, "scene0000_00", seed=SEED, n_frames=N_FRAMES,
                                     color_size=COLOR, depth_size=DEPTH, frame_skip=SKIP,
                                     invalid_pose_frames=(50,), scene=scene)
    return root, path, scene


def test_layout_and_reader_round_trip(written):
    root, path, scene = written
    for sub in ("color/0.jpg", "depth/10.png", "pose/60.txt", "intrinsic/intrinsic_color.txt",
                "intrinsic/intrinsic_depth.txt", "intrinsic/extrinsic_color.txt"):
        assert (path / sub).is_file(), sub
    assert S.list_scenes(root) == [path] and S.list_scenes(path) == [path]
    seq = S.ScanNetScene(path)
    assert seq.frame_numbers == list(range(0, N_FRAMES, SKIP))
    assert seq.color_size == COLOR and seq.depth_size == DEPTH
    cam_d = synthetic.default_camera(*DEPTH)
    # colour intrinsics resized to the depth grid == the depth camera (same view)
    np.testing.assert_allclose(seq.camera.K, cam_d.K, atol=1e-4)
    assert seq.camera.size == DEPTH
    np.testing.assert_allclose(seq.color_camera.K, synthetic.default_camera(*COLOR).K, atol=1e-5)
    poses = synthetic.make_trajectory(N_FRAMES, SEED)
    gt = seq.ground_truth()
    for n, T in zip(seq.frame_numbers, gt):
        if n == 50:
            assert T is None                       # written as -inf (lost tracking)
        else:
            np.testing.assert_allclose(T, poses[n], atol=2e-6)
    f = seq[seq.frame_position(20)]
    assert f.name == "20" and f.image.shape == (120, 160, 3) and f.depth.shape == (120, 160)
    d_true = scene.render_depth(cam_d, poses[20])
    ok = np.isfinite(d_true)
    assert np.array_equal(ok, np.isfinite(f.depth))
    assert np.abs(f.depth[ok] - d_true[ok]).max() <= 5.1e-4    # mm quantisation
    # colour (JPEG, 324x242 -> 160x120) is aligned with the depth grid
    ref = scene.render(cam_d, poses[20], supersample=2).rgb
    assert np.abs(f.image - ref).mean() < 0.03
    shifted = np.abs(f.image[:, 2:] - ref[:, :-2]).mean()
    assert np.abs(f.image - ref).mean() < 0.7 * shifted
    # options: depth intrinsics, no depth, frame selection, explicit output size
    assert np.allclose(S.ScanNetScene(path, intrinsics="depth").camera.K, cam_d.K, atol=1e-5)
    assert S.ScanNetScene(path, load_depth=False)[0].depth is None
    assert S.ScanNetScene(path, frames="20:50").frame_numbers == [20, 30, 40]
    big = S.ScanNetScene(path, image_size=(320, 240))[0]
    assert big.image.shape == (240, 320, 3) and big.depth.shape == (240, 320)


def test_resize_depth_nearest_is_centre_aligned():
    d = np.arange(16, dtype=float).reshape(4, 4)
    np.testing.assert_array_equal(S.resize_depth_nearest(d, (2, 2)), [[5, 7], [13, 15]])
    np.testing.assert_array_equal(S.resize_depth_nearest(d, (4, 4)), d)


def _pose(t=(0, 0, 0), rot_deg=0.0):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.radians(rot_deg) * np.array([0.0, 1.0, 0.0]))
    T[:3, 3] = t
    return T


def test_view_set_selection_discards_near_static_sets():
    numbers = list(range(0, 421, 10))
    poses = {n: _pose((0.01 * n, 0, 0)) for n in numbers}   # 10 frames = 10 cm
    poses[200] = None                                       # invalid reference
    poses[400] = _pose((4.0, 0, 0))
    poses[410] = _pose((4.0 + 0.01, 0, 0), rot_deg=0.5)     # 1 cm, 0.5 deg: near-static
    cfg = S.ScanNetProtocolConfig(stride=200, offsets=(10, -10, 20, -20), max_views=2)
    sets, skipped = S.select_view_sets(numbers, poses, cfg, "s")
    assert [s.ref for s in sets] == [0]
    assert sets[0].views == (10, 20)                        # -10, -20 do not exist
    np.testing.assert_allclose(sets[0].gt_translation, [0.1, 0.2])
    reasons = {s["ref"]: s["reason"] for s in skipped}
    assert "invalid reference pose" in reasons[200]
    assert reasons[400].startswith("near-static")
    # rotation alone (no translation) is motion: kept
    poses[410] = _pose((4.0, 0, 0), rot_deg=5.0)
    sets, _ = S.select_view_sets(numbers, poses, cfg, "s")
    assert [s.ref for s in sets] == [0, 400] and sets[1].views == (410, 390)
    # too few valid neighbours
    poses[390] = None
    poses[380] = _pose((np.inf, 0, 0))
    poses[420] = None
    sets, skipped = S.select_view_sets(numbers, poses, cfg, "s")
    assert [s.ref for s in sets] == [0]
    assert "only 1 of 2" in {s["ref"]: s["reason"] for s in skipped}[400]


@pytest.mark.slow
def test_runner_end_to_end(written):
    """References 0 and 30 (frames every 10, +-10/+-20 offsets), n = 1, 2 views,
    both initialisations, on one set.  Measured (160x120, classical): two-view
    init iMAE 30.4 / 20.6 1/km for n = 1 / 2 (16.7 / 11.7 without the depth stage)
    vs 56.1 for the median-scaled
    constant depth, rotation errors <= 0.18 deg; identity init n = 2 flagged
    low_parallax with iMAE 268 without the depth stage, 48.6 with it (it lands in a
    rotation/translation confusion)."""
    root, _, _ = written
    cfg = S.ScanNetProtocolConfig(stride=30, offsets=(10, -10, 20, -20), max_views=2,
                                  working_size=(160, 120), max_samples=1, progress=False)
    res = S.run_scannet_sfm(root, ["scene0000_00"], cfg)
    assert res.n_sets == 1 and len(res.rows) == 4
    assert {r["ref"] for r in res.rows} == {0}
    assert any(s["ref"] == 60 for s in res.skipped)        # 50 has no pose
    for r in res.rows:
        assert r["status"] != "error"
        for k in ("imae_per_km", "irmse_per_km", "abs_rel", "const_imae_per_km",
                  "rot_err_mean_deg", "tdir_err_mean_deg"):
            assert np.isfinite(r[k]), (k, r)
        assert 0 < r["coverage"] <= 1
    for r in (r for r in res.rows if r["init"] == "features"):
        assert r["status"] == "ok"
        # 0.6: the SfM depth stage (issue 54) costs this 160x120 case 16.8 -> 30.4 (n = 1)
        # and 11.8 -> 20.6 (n = 2) iMAE; it was 0.5 (docs/results.md)
        assert r["imae_per_km"] < 0.6 * r["const_imae_per_km"], r
        assert max(r["rot_err_deg"]) < 1.0, r
    summary = res.summary()
    assert [(s["init"], s["n_views"]) for s in summary] == [
        ("identity", 1), ("identity", 2), ("features", 1), ("features", 2), ("constant depth", 0)]
    table = res.table()
    assert "iMAE [1/km]" in table and "constant depth" in table
    json.dumps(res.to_dict(), default=float)


def test_cli(written, tmp_path, capsys):
    root, _, _ = written
    out = tmp_path / "rows.json"
    rc = S.main([str(root), "--stride", "30", "--offsets", "10", "-10", "--max-views", "1",
                 "--inits", "features", "--working-size", "160", "120", "--max-samples", "1",
                 "--json", str(out)])
    assert rc == 0
    assert "| features | 1 | 1 | 1 |" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert len(data["rows"]) == 1 and data["rows"][0]["views"] == [10]
    assert S.main([str(tmp_path / "nope")]) == 2


def test_bad_input(written, tmp_path):
    root, path, _ = written
    missing = tmp_path / "nope"
    with pytest.raises(FileNotFoundError, match="nope"):
        S.ScanNetScene(missing)
    with pytest.raises(FileNotFoundError, match="nope"):
        S.run_scannet_sfm(missing)
    with pytest.raises(FileNotFoundError, match="scene9999_00"):
        S.run_scannet_sfm(root, ["scene9999_00"])
    with pytest.raises(FileNotFoundError, match="no ScanNet scene"):
        S.list_scenes(tmp_path)
    # a scene without its pose folder: the error names the folder
    broken = tmp_path / "scene0001_00"
    (broken / "color").mkdir(parents=True)
    for sub in ("depth", "intrinsic"):
        (broken / sub).mkdir()
    with pytest.raises(FileNotFoundError, match=r"scene0001_00[/\\]pose"):
        S.ScanNetScene(broken)
    (broken / "pose").mkdir()
    with pytest.raises(FileNotFoundError, match="color"):
        S.ScanNetScene(broken)                            # no images
    # malformed pose file: ValueError naming it
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(path, bad)
    (bad / "pose" / "10.txt").write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"10\.txt"):
        S.ScanNetScene(bad).ground_truth()
    with pytest.raises(ValueError, match="intrinsics"):
        S.ScanNetScene(path, intrinsics="kinect")
    with pytest.raises(ValueError, match="offsets"):
        S.ScanNetProtocolConfig(offsets=(0, 10))
    with pytest.raises(ValueError, match="max_views"):
        S.ScanNetProtocolConfig(offsets=(10,), max_views=2)
    with pytest.raises(ValueError, match="inits"):
        S.ScanNetProtocolConfig(inits=("random",))
    with pytest.raises(ValueError, match="no usable view set"):
        S.run_scannet_sfm(root, config=S.ScanNetProtocolConfig(stride=1000, offsets=(500,),
                                                               max_views=1))
    with pytest.raises(ValueError, match="shape"):
        S.evaluate_depth(np.ones((2, 2)), np.ones((3, 3)))
