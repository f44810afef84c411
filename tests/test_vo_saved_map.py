"""A VO map saved and loaded (issue 53): the format round trip
(:class:`spgeo.vo.saved_map.SavedMap`), a run on a synthetic room split in two that
continues in the saved map's frame and scale (:mod:`spgeo.vo.map_entry`), the give-up
into a map of the run's own, and the bad inputs (``spgeo vo --load-map`` /
``--save-map``, exit code 2 naming the folder)."""
import json

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frame import Frame
from spgeo.trajectory import METRES, VO_UNITS, FrameStatus
from spgeo.validation import InputError
from spgeo.vo import KeyframeDecisionConfig, MappingConfig, Odometry, OdometryConfig
from spgeo.vo.saved_map import SavedMap

CAM = synthetic.default_camera(320, 240)
CFG = OdometryConfig(mapping=MappingConfig(mode="inline"))
N_SAVED, N_LOADED = 30, 30


def _odometry(saved=None, config=CFG):
    from spgeo.frontend import FrontEndConfig, make_frontend

    return Odometry(CAM, config, make_frontend("classical", FrontEndConfig(working_size=CAM.size)),
                    saved_map=saved)


def _run(vo, images, first):
    for i, im in enumerate(images):
        vo.track(Frame(im, CAM, float(first + i)))
    res = vo.result()
    vo.close()
    return res


@pytest.fixture(scope="module")
def split_run(tmp_path_factory):
    """The synthetic room (every third pose, 320x240, the defaults with inline mapping):
    one run over all 60 frames; frames 0-29 run and their map saved, then frames 30-59
    run in the loaded map."""
    poses = synthetic.make_trajectory(3 * (N_SAVED + N_LOADED), 0)[::3]
    room = synthetic.SyntheticScene.generate(0)
    images = [room.render(CAM, T).rgb for T in poses]
    whole = _run(_odometry(), images, 0)
    vo1 = _odometry()
    res1 = _run(vo1, images[:N_SAVED], 0)
    folder = tmp_path_factory.mktemp("saved") / "map"
    saved = vo1.saved_map()
    saved.save(folder)
    loaded = SavedMap.load(folder)
    vo2 = _odometry(loaded)
    res2 = _run(vo2, images[N_SAVED:], N_SAVED)
    entered = [vo2.keyframe(k).T_world_kf for k in range(CFG.window)]
    return poses, res1, res2, saved, loaded, folder, whole, entered, vo2


def _sim3(est, gt):
    from spgeo.similarity import umeyama

    return umeyama(est[:, :3, 3], gt[:, :3, 3])


@pytest.mark.slow
def test_a_saved_map_reads_back_equal(split_run):
    """Every keyframe's pose, image and scaled primitives, and the landmarks, read
    back as saved (log-depth stored as float32)."""
    _, _, _, saved, loaded, folder, _, _, _ = split_run
    head = json.loads((folder / "map.json").read_text())
    assert head["format"] == "spgeo-vo-map" and head["version"] == 1
    assert len(loaded.keyframes) == len(saved.keyframes) >= 3
    for a, b in zip(saved.keyframes, loaded.keyframes):
        assert (a.index, a.frame, a.segment) == (b.index, b.frame, b.segment)
        np.testing.assert_allclose(a.T_world_kf, b.T_world_kf, atol=1e-12)
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.primitives.log_scales, b.primitives.log_scales)
        np.testing.assert_allclose(a.primitives.depth_map(), b.primitives.depth_map(),
                                   rtol=1e-5, equal_nan=True)
    assert loaded.landmarks is not None and len(loaded.landmarks) > 50
    np.testing.assert_array_equal(saved.landmarks.descriptors, loaded.landmarks.descriptors)
    np.testing.assert_allclose(saved.landmarks.points, loaded.landmarks.points)
    assert loaded.camera.to_dict() == saved.camera.to_dict() and loaded.units == VO_UNITS


@pytest.mark.slow
def test_a_loaded_run_continues_in_the_saved_frame_and_scale(split_run):
    """The loaded run's first frame is relocalised into the saved map, none is lost,
    one segment; its first poses, mapped to the ground truth by the Sim(3) of the saved
    run, lie within 1 % of the scene depth (about 2.8) of the truth (the same frame and
    scale, not a new map), and the two runs joined and aligned by one Sim(3) are within
    1.5x the ATE of one run over all frames (the issue's goal; 0.92x when measured)."""
    from spgeo.metrics.ate import ate_sim3

    poses, res1, res2, saved, _, _, whole, entered, _ = split_run
    assert res2.statuses[0] is FrameStatus.RELOCALISED
    assert FrameStatus.LOST not in res2.statuses and set(res2.segments.tolist()) == {0}
    S = _sim3(res1.poses, poses[:N_SAVED])
    moved = (S[:3, :3] @ res2.poses[:5, :3, 3].T).T + S[:3, 3]
    err = np.linalg.norm(moved - poses[N_SAVED:N_SAVED + 5, :3, 3], axis=1)
    assert err.max() < 0.01 * 2.8, err
    ts = np.concatenate([res1.timestamps, res2.timestamps])
    joined = ate_sim3((ts, np.concatenate([res1.poses, res2.poses])), (ts, poses))
    one = ate_sim3((whole.timestamps, whole.poses), (whole.timestamps, poses))
    assert joined.rmse < 1.5 * one.rmse, (joined.rmse, one.rmse)
    # the saved keyframe it was placed against (the last) and the window before it are the
    # run's first keyframes, held at their saved poses by the window smoother
    for T, kf in zip(entered, saved.keyframes[-CFG.window:]):
        np.testing.assert_allclose(T, kf.T_world_kf, atol=1e-6)


@pytest.mark.slow
def test_a_map_of_another_scene_is_given_up_for_a_map_of_its_own(split_run):
    """Frames of another room are never placed in the saved map: after
    ``max_lost_frames`` lost frames the run starts its own map (a warning), not a
    map at a wrong pose."""
    _, _, _, _, loaded, _, _, _, _ = split_run
    other = synthetic.SyntheticScene.generate(7)
    poses = synthetic.make_trajectory(30, 0)[::3]
    cfg = OdometryConfig(keyframe=CFG.keyframe, mapping=CFG.mapping, max_lost_frames=3)
    res = _run(_odometry(loaded, cfg), [other.render(CAM, T).rgb for T in poses], 0)
    assert res.statuses[:2] == [FrameStatus.LOST] * 2
    assert res.statuses[2] in (FrameStatus.KEYFRAME, FrameStatus.REINIT)
    assert FrameStatus.RELOCALISED not in res.statuses


@pytest.mark.slow
def test_a_loaded_run_exports_the_keyframes_it_made(split_run, tmp_path):
    """The saved keyframes a run entered with are no frames of it: a COLMAP export of its
    keyframes holds the ones it made (one image each), not the saved ones."""
    pytest.importorskip("pycolmap")
    import pycolmap

    from spgeo.io.colmap_export import export_odometry

    _, _, res2, _, _, _, _, _, vo2 = split_run
    names = [f"{int(t):06d}" for t in res2.timestamps]
    images = {k: vo2.keyframe_image(k) for k in range(vo2.n_keyframes)}
    model = export_odometry(tmp_path / "colmap", vo2, names, images)
    rec = pycolmap.Reconstruction(str(model))
    assert rec.num_images() == int(res2.is_keyframe.sum()) < vo2.n_keyframes


def test_a_folder_that_is_not_a_saved_map_is_refused_naming_it(tmp_path):
    with pytest.raises(InputError, match="no map.json"):
        SavedMap.load(tmp_path)
    (tmp_path / "map.json").write_text(json.dumps({"format": "spgeo-vo-map", "version": 9}))
    with pytest.raises(InputError, match="version 9"):
        SavedMap.load(tmp_path)
    (tmp_path / "map.json").write_text(json.dumps({"format": "spgeo-vo-map", "version": 1,
                                                   "camera": CAM.to_dict(), "units": VO_UNITS,
                                                   "primitive_model": "integrated",
                                                   "keyframes": [{"index": 0, "frame": 0,
                                                                  "segment": 0,
                                                                  "T_world_kf": np.eye(4).tolist(),
                                                                  "image": "k.npy",
                                                                  "primitives": "k.npz"}]}))
    with pytest.raises(InputError, match="cannot read keyframe 0"):
        SavedMap.load(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="other than a saved map"):
        SavedMap.check_target(other)


def test_a_map_saved_at_another_camera_is_refused():
    saved = SavedMap(synthetic.default_camera(160, 120), VO_UNITS, "integrated", [])
    with pytest.raises(InputError, match="processing camera"):
        _odometry(saved)
    saved = SavedMap(CAM, METRES, "integrated", [])
    with pytest.raises(InputError, match="units"):
        _odometry(saved)


def test_cli_load_map_of_a_plain_folder_is_exit_2(tmp_path, capsys):
    from spgeo.cli import main

    (tmp_path / "imgs").mkdir()
    rc = main(["vo", "--dataset", "folder", str(tmp_path / "imgs"), "--out",
               str(tmp_path / "out"), "--load-map", str(tmp_path / "imgs")])
    assert rc == 2
    assert "not a saved spgeo map" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_save_map_then_load_map(tmp_path, capsys):
    """``spgeo vo --save-map`` on the first 24 frames of a synthetic 7-Scenes folder, then
    ``--load-map`` on the next 16: the map folder is written, the second run's first frame
    is relocalised into it (exit 0), and ``--save-map`` into a folder of other files is
    refused before any work (exit 2)."""
    from layouts import write_7scenes
    from spgeo.cli import main
    from spgeo.evaluation.trajectory import read_status

    cam = synthetic.default_camera(160, 120)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(0), cam,
                                     synthetic.make_trajectory(120, 0)[::3])
    seq = write_7scenes(tmp_path / "seq-01", frames, cam.resized(640, 480).K)
    common = ["vo", "--dataset", "7scenes", str(seq), "--resolution", "160x120",
              "--no-progress", "--set", "mapping.mode=inline"]
    assert main(common + ["--frames", "0:24", "--out", str(tmp_path / "a"),
                          "--save-map", str(tmp_path / "map")]) == 0
    assert "wrote the map (" in capsys.readouterr().out
    assert (tmp_path / "map" / "map.json").is_file()
    assert main(common + ["--frames", "24:40", "--out", str(tmp_path / "b"),
                          "--load-map", str(tmp_path / "map")]) == 0
    _, status = read_status(tmp_path / "b" / "trajectory.status.txt")
    assert status[0] == "relocalised" and "lost" not in status
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    capsys.readouterr()
    assert main(common + ["--frames", "0:4", "--out", str(tmp_path / "c"),
                          "--save-map", str(tmp_path / "mine")]) == 2
    assert "other than a saved map" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()
