"""Self-describing outputs of ``spgeo vo`` (issue 42): ``groundtruth.txt`` beside
``trajectory.txt`` that evo reads to the report's ATE, ``Trajectory.from_ground_truth``,
the manifest's file list (checked against the folder, what and units per file), the
fusion's parameters as settings (``--set fusion.FIELD=VALUE``) and in report.json, and
open3d's colour clamping counted and logged once instead of printed.

Runs: the depth front-end (initialised at frame 0) on 10 synthetic frames processed at
160x120: from Python (about a second; the fast tier) and through ``spgeo vo --mesh`` on
them stored as a 7-Scenes sequence (a few seconds; ``slow``)."""
import json
import logging

import numpy as np
import pytest

from layouts import write_7scenes
from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.cli import main
from spgeo.io.outputs import MANIFEST, FileInfo, StagedFolder, describe_folder, read_manifest
from spgeo.trajectory import Trajectory
from spgeo.vo import KeyframeDecisionConfig, OdometryConfig, MappingConfig

N = 10
CAM = synthetic.default_camera(160, 120)


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    # every 6th pose: three keyframes, so that the keyframe-only ATE exists
    return synthetic.render_frames(scene, CAM, synthetic.make_trajectory(6 * N, 0)[::6],
                                   supersample=1)


@pytest.fixture(scope="module")
def seven_scenes(tmp_path_factory, frames):
    return write_7scenes(tmp_path_factory.mktemp("describe") / "seq-01", frames,
                         CAM.resized(640, 480).K)


@pytest.fixture(scope="module")
def cli_run(seven_scenes, tmp_path_factory):
    """``spgeo vo --mesh`` with a fusion setting given by ``--set``."""
    out = tmp_path_factory.mktemp("describe_out") / "run"
    rc = main(["vo", "--dataset", "7scenes", str(seven_scenes), "--frontend", "depth",
               "--resolution", "160x120", "--mesh", "--set", "fusion.trunc_voxels=4",
               "keyframe.max_translation=0.05",
               "--no-progress", "--out", str(out)])
    assert rc == 0
    return out


def evo_ape_rmse(gt_file, est_file):
    """What ``evo_ape tum GT EST -as`` prints as rmse (its own steps: read, associate with
    the default 0.01 s, Sim(3) Umeyama alignment, APE of the translation part)."""
    from evo.core import metrics, sync
    from evo.main_ape import ape
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(gt_file))
    est = file_interface.read_tum_trajectory_file(str(est_file))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    res = ape(ref, est, metrics.PoseRelation.translation_part, align=True, correct_scale=True)
    return res.stats["rmse"], est.num_poses


# ------------------------------------------------------------------ the command line
@pytest.mark.slow
def test_manifest_lists_exactly_the_folder_with_what_and_units(cli_run):
    manifest = read_manifest(cli_run)
    entries = manifest["files"]
    on_disk = sorted(p.relative_to(cli_run).as_posix() for p in cli_run.rglob("*")
                     if p.is_file() and p.name != MANIFEST)
    assert [e["path"] for e in entries] == on_disk
    for e in entries:
        assert (cli_run / e["path"]).stat().st_size == e["bytes"]
        assert isinstance(e["what"], str) and len(e["what"]) > 20, e
        assert isinstance(e["units"], str) and e["units"], e
    by_path = {e["path"]: e for e in entries}
    expected = {"trajectory.txt", "keyframes.txt", "trajectory.status.txt", "report.json",
                "groundtruth.txt", "mesh.ply", "cloud.ply", "trajectory_topview.png",
                "trajectory_error.png"}
    assert expected <= set(by_path)
    clouds = [p for p in by_path if p.startswith("clouds/")]
    assert clouds and all(p.endswith(".ply") for p in clouds)
    assert "fused TSDF point cloud (all keyframes)" in by_path["cloud.ply"]["what"]
    assert "clouds/" in by_path["cloud.ply"]["what"]       # not the per-keyframe clouds
    # the depth front-end reads the sensor depth: metres; ground truth: metres
    assert by_path["trajectory.txt"]["units"].startswith("positions in metres")
    assert "camera-to-world" in by_path["groundtruth.txt"]["what"]
    assert manifest["status"] == "ok" and manifest["frames"] == N


@pytest.mark.slow
def test_report_states_units_and_fusion_parameters(cli_run):
    """report.json: the positions' unit, the fusion's resolved parameters and its config
    (``--set fusion.trunc_voxels=4`` reached the fusion: truncation = 4 voxels)."""
    rep = json.loads((cli_run / "report.json").read_text())
    assert rep["units"]["positions"].startswith("metres")
    fusion = rep["fusion"]
    assert fusion["config"]["trunc_voxels"] == 4.0
    assert rep["run_config"]["fusion"] == fusion["config"]
    assert fusion["sdf_trunc"] == pytest.approx(4 * fusion["voxel_size"])
    assert fusion["voxel_size"] == pytest.approx(0.01 * fusion["reference_depth"])
    assert fusion["depth_max"] == pytest.approx(3.0 * fusion["reference_depth"])
    assert fusion["n_views"] >= 1 and fusion["n_vertices"] > 0
    assert fusion["n_colours_clipped"] >= 0


def test_set_fusion_fields_reach_the_run_config():
    import argparse

    from spgeo.cli.vo import _run_config, add_vo_cli
    from spgeo.configs import ConfigError
    from spgeo.io.fusion import FusionConfig

    parser = argparse.ArgumentParser()
    add_vo_cli(parser.add_subparsers())

    def cfg(*sets):
        return _run_config(parser.parse_args(["vo", "--dataset", "7scenes", "x", "--out", "o",
                                              *sets]))

    assert cfg().fusion == FusionConfig()                    # defaults: outputs unchanged
    c = cfg("--set", "fusion.voxel_size=0.01", "--set", "fusion.depth_max=4")
    assert c.fusion.voxel_size == 0.01 and c.fusion.depth_max == 4.0
    with pytest.raises(ConfigError, match="voxel_size"):
        cfg("--set", "fusion.voxel_size=-1")
    with pytest.raises(ConfigError, match="voxel"):
        cfg("--set", "fusion.voxel=0.01")                     # unknown field, named


@pytest.mark.slow
def test_evo_ape_on_groundtruth_reproduces_the_reported_ate(cli_run):
    rep = json.loads((cli_run / "report.json").read_text())["ate"]
    rmse, n = evo_ape_rmse(cli_run / "groundtruth.txt", cli_run / "trajectory.txt")
    assert n == rep["per-frame"]["n_associated"]
    assert rmse == pytest.approx(rep["per-frame"]["rmse_m"], rel=1e-6, abs=1e-9)
    rmse, n = evo_ape_rmse(cli_run / "groundtruth.txt", cli_run / "keyframes.txt")
    assert n == rep["keyframe-only"]["n_associated"] >= 3
    assert rmse == pytest.approx(rep["keyframe-only"]["rmse_m"], rel=1e-6, abs=1e-9)


@pytest.mark.slow
def test_groundtruth_file_is_the_data_sets_ground_truth(cli_run, seven_scenes, frames):
    """Same timestamps as trajectory.txt, same number format, the poses of the data set
    (:meth:`Trajectory.from_ground_truth` of the reader) to the file's precision."""
    from spgeo.datasets import open_dataset
    from spgeo.io.tum import read_tum

    gt = read_tum(cli_run / "groundtruth.txt")
    est = read_tum(cli_run / "trajectory.txt")
    np.testing.assert_array_equal(gt.timestamps, est.timestamps)
    reader = Trajectory.from_ground_truth(open_dataset("7scenes", seven_scenes))
    np.testing.assert_array_equal(reader.timestamps, gt.timestamps)
    np.testing.assert_allclose(gt.poses, reader.poses, atol=2e-8)
    np.testing.assert_allclose(reader.poses, [f.T_world_cam for f in frames], atol=1e-12)
    line = [ln for ln in (cli_run / "groundtruth.txt").read_text().splitlines()
            if not ln.startswith("#")][1]
    ref = [ln for ln in (cli_run / "trajectory.txt").read_text().splitlines()
           if not ln.startswith("#")][1]
    assert [len(x.split(".")[1]) for x in line.split()] == \
        [len(x.split(".")[1]) for x in ref.split()]


# ------------------------------------------------------------------ ground truth and evo
def test_from_ground_truth_of_a_reader(seven_scenes, frames):
    """A data set's ground truth as a Trajectory, read without images (the reader's
    timestamps: 7-Scenes frame numbers)."""
    from spgeo.datasets import open_dataset

    t = Trajectory.from_ground_truth(open_dataset("7scenes", seven_scenes, frames="2:8"))
    np.testing.assert_array_equal(t.timestamps, np.arange(2.0, 8.0))
    np.testing.assert_allclose(t.poses, [f.T_world_cam for f in frames[2:8]], atol=1e-12)
    assert t.status_counts()["ok"] == 6


def test_from_ground_truth_leaves_out_frames_without_one():
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    bad = np.full((4, 4), np.nan)
    t = Trajectory.from_ground_truth([0.0, 1.0, 2.0, 3.0], [T, None, bad, np.eye(4)])
    np.testing.assert_array_equal(t.timestamps, [0.0, 2.0, 3.0])
    np.testing.assert_array_equal(t.poses[0], T)
    assert t.finite.tolist() == [True, False, True]           # non-finite: no pose
    assert all(s == "ok" for s in t.status)
    with pytest.raises(ValueError, match="2 timestamps for 1 poses"):
        Trajectory.from_ground_truth([0.0, 1.0], [T])
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        Trajectory.from_ground_truth([0.0], [np.eye(3)])
    with pytest.raises(TypeError, match="data-set reader"):
        Trajectory.from_ground_truth([0.0, 1.0])


@pytest.fixture(scope="module")
def library_run(frames):
    cfg = VORunConfig(frontend="depth", progress=False,
                      odometry=OdometryConfig(resolution=(160, 120),
                                              keyframe=KeyframeDecisionConfig(max_translation=0.05),
                                              mapping=MappingConfig(mode="inline")))
    return run_odometry(frames, cfg)


def test_evo_on_saved_files_reproduces_both_ates(library_run, tmp_path):
    """``evo_ape tum groundtruth.txt trajectory.txt -as`` gives report.json's per-frame ATE,
    with keyframes.txt its keyframe-only ATE; groundtruth.txt has trajectory.txt's
    timestamps and the frames' ground truth."""
    from spgeo.io.tum import read_tum

    paths = library_run.save(tmp_path / "o")
    rep = json.loads(paths["report"].read_text())["ate"]
    for label, est in (("per-frame", paths["trajectory"]), ("keyframe-only", paths["keyframes"])):
        rmse, n = evo_ape_rmse(paths["groundtruth"], est)
        assert n == rep[label]["n_associated"] >= 3
        assert rmse == pytest.approx(rep[label]["rmse_m"], rel=1e-6, abs=1e-9)
    gt, traj = read_tum(paths["groundtruth"]), read_tum(paths["trajectory"])
    np.testing.assert_array_equal(gt.timestamps, traj.timestamps)
    np.testing.assert_allclose(gt.poses, library_run.ground_truth().poses, atol=2e-8)


def test_lost_frames_are_left_out_of_the_ground_truth(library_run, tmp_path, monkeypatch):
    """A lost frame has no line in trajectory.txt (issue 53: posed frames only, as
    ORB-SLAM writes them; before, it held the previous pose) nor in groundtruth.txt, so evo
    reproduces the report; trajectory.status.txt still lists it as lost."""
    run = library_run
    res = run.result()
    status = list(res.statuses)
    lost = next(i for i, s in enumerate(status) if i > 0 and s != "keyframe")
    status[lost] = "lost"
    from spgeo.vo import OdometryResult

    hacked = OdometryResult(res.timestamps, res.poses, status, res.is_keyframe, res.segment)
    monkeypatch.setattr(run, "result", lambda: hacked)
    paths = run.save(tmp_path / "o")
    gt = Trajectory.load(paths["groundtruth"])
    assert not np.isclose(gt.timestamps, res.timestamps[lost]).any() and len(gt) == N - 1
    assert not np.isclose(np.loadtxt(paths["trajectory"])[:, 0], res.timestamps[lost]).any()
    back = Trajectory.load(paths["trajectory"])
    assert len(back) == N and back.status[lost] == "lost" and np.isnan(back.poses[lost]).all()
    rep = json.loads(paths["report"].read_text())["ate"]["per-frame"]
    rmse, n = evo_ape_rmse(paths["groundtruth"], paths["trajectory"])
    assert n == rep["n_associated"] == N - 1
    assert rmse == pytest.approx(rep["rmse_m"], rel=1e-6, abs=1e-9)


def test_metric_scale_outputs_still_reproduce_the_ate(library_run, tmp_path):
    """With a metric scale the trajectory is in metres: the Sim(3) alignment absorbs it
    (same RMSE, scale divided by it); the manifest and report say metres."""
    from spgeo.vo.metric_scale import MetricScale

    run = library_run
    plain = run.ate()["per-frame"]
    run.metric_scale = MetricScale(2.5, 1.0, (2.5, 2.5), 1, (2.5,), (100,), "test")
    try:
        paths = run.save(tmp_path / "o")
        described = run.describe_files(paths)
    finally:
        run.metric_scale = None
    rep = json.loads(paths["report"].read_text())
    assert rep["ate"]["per-frame"]["scale"] == pytest.approx(plain.scale / 2.5, rel=1e-9)
    rmse, _ = evo_ape_rmse(paths["groundtruth"], paths["trajectory"])
    assert rmse == pytest.approx(rep["ate"]["per-frame"]["rmse_m"], rel=1e-6, abs=1e-9)
    assert rmse == pytest.approx(plain.rmse, rel=1e-5, abs=1e-9)
    assert "--metric-scale" in rep["units"]["positions"]
    assert "--metric-scale" in described[paths["trajectory"]].units


def test_monocular_units_say_vo_units(library_run, tmp_path, monkeypatch):
    """The unknown scale of a monocular run is stated (what the issue's user missed)."""
    monkeypatch.setattr(type(library_run.odometry.frontend), "uses_depth", False,
                        raising=False)
    assert library_run.position_units.startswith("VO units (unknown scale")


def test_every_saved_file_is_described(library_run, tmp_path):
    """VORun.describe_files covers everything save writes, fusion included; a path
    described but not written is refused."""
    run = library_run
    fused = run.fuse()
    paths = run.save(tmp_path / "o", fusion=fused)
    described = run.describe_files(paths)
    entries = describe_folder(tmp_path / "o", described)
    files = sorted(p.relative_to(tmp_path / "o").as_posix()
                   for p in (tmp_path / "o").rglob("*") if p.is_file())
    assert [e["path"] for e in entries] == files
    assert all(e["what"] and e["units"] for e in entries)
    with pytest.raises(ValueError, match="not a file"):
        describe_folder(tmp_path / "o", {tmp_path / "o" / "nothing.txt": FileInfo("x")})


# ------------------------------------------------------------------ other commands
def test_generic_manifest_lists_every_file(tmp_path):
    """A command that describes nothing still gets every file listed (report.json with
    the generic description, others with what None)."""
    with StagedFolder(tmp_path / "out", command="test") as st:
        (st.path / "report.json").write_text("{}")
        (st.path / "sub").mkdir()
        (st.path / "sub" / "a.bin").write_bytes(b"123")
        st.commit("complete", described={"sub/a.bin": FileInfo("three bytes", "bytes")})
    files = read_manifest(tmp_path / "out")["files"]
    assert [f["path"] for f in files] == ["report.json", "sub/a.bin"]
    assert files[0]["what"].startswith("the command's report")
    assert files[1] == {"path": "sub/a.bin", "what": "three bytes", "units": "bytes",
                        "bytes": 3}
    with StagedFolder(tmp_path / "out2") as st:
        (st.path / "x.txt").write_text("1")
        st.commit()
    assert read_manifest(tmp_path / "out2")["files"] == [
        {"path": "x.txt", "what": None, "units": None, "bytes": 1}]


# ------------------------------------------------------------------ open3d's warnings
def test_colour_clamping_is_counted_and_logged_once(tmp_path, caplog, capfd):
    """Colours past 1 (the TSDF's rounding): clipped and counted, one log line, and
    open3d prints nothing when the result is written."""
    import open3d as o3d

    from spgeo.io.fusion import FusionResult, _clip_colours

    pts = np.random.default_rng(0).random((10, 3))
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(pts),
                                     o3d.utility.Vector3iVector([[0, 1, 2]]))
    cols = np.full((10, 3), 0.5)
    cols[:3, 0] = 1.0 + 1e-7
    mesh.vertex_colors = o3d.utility.Vector3dVector(cols)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    cloud.colors = o3d.utility.Vector3dVector(cols)
    with caplog.at_level(logging.INFO, logger="spgeo.io.fusion"):
        assert _clip_colours(mesh, cloud) == 6
    lines = [r for r in caplog.records if "clipped" in r.getMessage()]
    assert len(lines) == 1 and lines[0].levelno == logging.INFO
    assert np.asarray(mesh.vertex_colors).max() == 1.0
    # an unclipped result written directly: open3d's clamp warning is silenced
    cloud.colors = o3d.utility.Vector3dVector(cols)
    capfd.readouterr()
    FusionResult(mesh, cloud, 0.1, 0.5, 3.0, 1).write(tmp_path)
    out = capfd.readouterr()
    assert "clamped" not in out.out + out.err


# ------------------------------------------------------------------ the shared clip
@pytest.mark.slow
def test_shared_7scenes_groundtruth_and_manifest(shared_data, tmp_path):
    """On the shared 7-Scenes clip (monocular): evo on the written files gives the
    report's ATE, the manifest lists the folder and says VO units."""
    seq = shared_data / "7scenes_redkitchen_dev"
    if not seq.is_dir():
        pytest.skip(f"{seq} not found")
    out = tmp_path / "vo"
    assert main(["vo", "--dataset", "7scenes", str(seq), "--frames", "0:40", "--no-progress",
                 "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    rmse, _ = evo_ape_rmse(out / "groundtruth.txt", out / "trajectory.txt")
    assert rmse == pytest.approx(rep["ate"]["per-frame"]["rmse_m"], rel=1e-6)
    entries = read_manifest(out)["files"]
    assert len(entries) == sum(1 for p in out.rglob("*") if p.is_file()) - 1
    assert "VO units" in {e["path"]: e for e in entries}["trajectory.txt"]["units"]


def test_a_run_of_two_segments_is_scored_per_segment(library_run, monkeypatch, caplog):
    """Issue 53: a run that re-initialised (here: the second half of the frames made
    segment 1 at three times the scale) gets one Sim(3) ATE per segment in the report and
    the summary, and a warning that the per-frame ATE aligns both with one Sim(3)."""
    import logging

    from spgeo.vo import OdometryResult

    run = library_run
    res = run.result()
    half = len(res.timestamps) // 2
    seg = np.where(np.arange(len(res.timestamps)) < half, 0, 1)
    poses = res.poses.copy()
    poses[half:, :3, 3] = 3.0 * poses[half:, :3, 3] + np.array([1.0, 0.0, 0.0])
    hacked = OdometryResult(res.timestamps, poses, list(res.statuses), res.is_keyframe, seg)
    monkeypatch.setattr(run, "result", lambda: hacked)
    whole = run.ate()["per-frame"].rmse
    with caplog.at_level(logging.WARNING):
        rep = run.ate_report()
    assert "aligns 2 map segments" in caplog.text
    per = rep["per_segment"]
    assert [p["segment"] for p in per] == [0, 1]
    assert all(p["rmse_m"] < 0.2 * whole for p in per)
    assert per[1]["scale"] == pytest.approx(per[0]["scale"] / 3.0, rel=0.15)  # its own (5 frames each)
    assert sum("segment 1:" in line for line in run.summary_lines()) == 1


def test_a_depth_run_whose_frames_were_all_lost_has_no_map(library_run, monkeypatch):
    """Issue 53: a run is ``ok`` when some frame was tracked against a map (with sensor depth
    keyframe 0 is one: its frames are ``ok`` at once), ``no_map`` when every frame after the
    first was lost or only waited for keyframe 1 (``init``, provisional; before: ``ok`` for
    any depth run)."""
    from spgeo.vo import OdometryResult

    run = library_run
    res = run.result()

    def with_statuses(statuses):
        hacked = OdometryResult(res.timestamps, res.poses, statuses, res.is_keyframe,
                                res.segment)
        monkeypatch.setattr(run, "result", lambda: hacked)
        return run.status

    n = len(res.timestamps)
    assert with_statuses(["keyframe"] + ["lost"] * (n - 1)) == "no_map"
    assert with_statuses(["keyframe", "ok"] + ["lost"] * (n - 2)) == "ok"
    assert with_statuses(["keyframe", "init"] + ["lost"] * (n - 2)) == "no_map"
