"""spgeo.apps.rerun_logger.RerunLogger: a short synthetic VO run (depth front-end, 20 frames at
160x120) logged to an .rrd file and read back with rerun's own reader
(``rerun.chunk.RrdReader``); rerun is never imported without the option."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from spgeo.vo import KeyframeDecisionConfig, OdometryConfig
from spgeo import synthetic  # noqa: E402
from spgeo.apps.vo_run import VORunConfig, run_odometry  # noqa: E402
from spgeo.cli import main  # noqa: E402
from spgeo.apps.rerun_logger import RerunLogger, RerunLoggerConfig  # noqa: E402

N = 20


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    cam = synthetic.default_camera(160, 120)
    scene = synthetic.SyntheticScene.generate(0)
    # every second pose of a 40-frame trajectory: enough parallax to initialise
    frames = synthetic.render_frames(scene, cam, synthetic.make_trajectory(2 * N, 0)[::2])
    path = tmp_path_factory.mktemp("rerun") / "vo.rrd"
    online = []     # the live trajectory: each frame's pose when it was tracked

    with RerunLogger(RerunLoggerConfig(mode="save", target=str(path), recording_id="test",
                                       max_points_per_keyframe=5000)) as viewer:
        def hook(frame, result, odometry):
            online.append(np.array(result.T_world_cam, dtype=float))
            viewer.on_frame(frame, result, odometry)

        run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(160, 120), keyframe=KeyframeDecisionConfig(max_translation=0.05)), frontend="depth",
                                               progress=False), on_frame=hook)
        viewer.finish(run.odometry)
    rows = {}
    for chunk in RrdReader(str(path)).stream():
        d = chunk.to_record_batch().to_pydict()
        for key, values in d.items():
            rows.setdefault(chunk.entity_path, {}).setdefault(key, []).extend(values)
    return run, np.array(online), rows, frames


def _column(rows, entity, component, first=True):
    """(frame, value) pairs of the rows of ``entity`` holding ``component``, by
    frame; ``first``: the row's first instance (else all of them)."""
    r = rows[entity]
    pairs = [(f, v[0] if first else v) for f, v in zip(r["frame"], r[component])
             if v is not None]
    return sorted(pairs, key=lambda p: p[0])


@pytest.mark.slow
def test_entity_paths(logged):
    run, _, rows, _ = logged
    n_kf = len(run.odometry.keyframes)
    assert n_kf >= 2
    expected = {"/world/camera", "/world/camera/image", "/world/trajectory",
                "/world/ground_truth", "/status", "/timings/total"}
    for k in range(n_kf):
        expected |= {f"/world/keyframes/{k}", f"/world/keyframes/{k}/points"}
        expected |= {f"/world/keyframes/{k}/image/{x}" for x in ("rgb", "segments", "depth")}
    assert expected <= set(rows)
    assert rows["/world"]["ViewCoordinates:xyz"]   # RDF, static


@pytest.mark.slow
def test_logged_poses_equal_the_trajectory(logged):
    run, online, rows, _ = logged
    rot = _column(rows, "/world/camera", "Transform3D:mat3x3")
    trans = _column(rows, "/world/camera", "Transform3D:translation")
    assert [f for f, _ in rot] == list(range(N)) == [f for f, _ in trans]
    assert online.shape == (N, 4, 4)
    # rerun stores 3x3 matrices column-major (float32)
    R = np.array([np.reshape(v, (3, 3)).T for _, v in rot])
    t = np.array([v for _, v in trans])
    np.testing.assert_allclose(R, online[:, :3, :3], atol=1e-6)
    np.testing.assert_allclose(t, online[:, :3, 3], atol=1e-6)
    # pinhole with the VO camera's intrinsics
    K = np.reshape(_column(rows, "/world/camera", "Pinhole:image_from_camera")[0][1], (3, 3)).T
    np.testing.assert_allclose(K, run.odometry.camera.K, atol=1e-4)
    # the last trajectory strip is the final (smoothed) trajectory
    last = np.array(_column(rows, "/world/trajectory", "LineStrips3D:strips")[-1][1])
    np.testing.assert_allclose(last, run.result().poses[:, :3, 3], atol=1e-6)
    # status per frame, timings per frame
    assert len(rows["/status"]["TextLog:text"]) == N
    assert len(_column(rows, "/timings/total", "Scalars:scalars")) == N


@pytest.mark.slow
def test_ground_truth_and_keyframes(logged):
    run, online, rows, frames = logged
    # the ground truth drawn in the VO's world: anchored at frame 0's final pose, scaled
    # by a fitted factor, which is about 1 for the metric depth front-end
    drawn = np.array(_column(rows, "/world/ground_truth", "LineStrips3D:strips")[-1][1])
    est0 = run.result().poses[0]
    gt = np.array([f.T_world_cam for f in frames])
    a = (gt[:, :3, 3] - gt[0, :3, 3]) @ (est0[:3, :3] @ gt[0, :3, :3].T).T
    b = drawn - est0[:3, 3]
    scale = float(np.sum(a * b) / np.sum(a * a))
    np.testing.assert_allclose(b, scale * a, atol=1e-5)
    assert abs(scale - 1.0) < 0.05
    for k, kf in enumerate(run.odometry.keyframes):
        path = f"/world/keyframes/{k}"
        rot = _column(rows, path, "Transform3D:mat3x3")[-1][1]
        tr = _column(rows, path, "Transform3D:translation")[-1][1]
        np.testing.assert_allclose(np.reshape(rot, (3, 3)).T, kf.T_world_kf[:3, :3], atol=1e-6)
        np.testing.assert_allclose(tr, kf.T_world_kf[:3, 3], atol=1e-6)
        pts = np.array(_column(rows, f"{path}/points", "Points3D:positions", False)[-1][1])
        cloud = kf.primitives.point_cloud().points
        assert 0 < len(pts) <= 5000
        assert np.allclose(pts[0], cloud[0], atol=1e-5) and np.allclose(pts[-1], cloud[-1],
                                                                          atol=1e-5)
        seg = rows[f"{path}/image/segments"]
        assert any(v is not None for v in seg["SegmentationImage:buffer"])


def test_spec_parsing_and_cli_errors(capsys):
    assert RerunLoggerConfig.from_spec(["spawn"]).mode == "spawn"
    cfg = RerunLoggerConfig.from_spec(["save", "a.rrd"])
    assert (cfg.mode, cfg.target) == ("save", "a.rrd")
    assert RerunLoggerConfig.from_spec(["connect"]).target is None
    for bad in ([], ["save"], ["save", "a.txt"], ["spawn", "x"], ["fly"]):
        with pytest.raises(ValueError):
            RerunLoggerConfig.from_spec(bad)
    with pytest.raises(ValueError, match="mode"):
        RerunLoggerConfig(mode="x")
    with pytest.raises(SystemExit) as exc:
        main(["vo", "--dataset", "7scenes", "nowhere", "--out", "o", "--rerun", "save", "x.txt"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("spgeo vo: error: argument --rerun:") and ".rrd" in err


@pytest.mark.slow
def test_rerun_is_not_imported_without_the_option():
    code = textwrap.dedent("""
        import sys
        import spgeo, spgeo.vo, spgeo.viz, spgeo.cli
        from spgeo.cli import build_parser
        from spgeo import synthetic
        from spgeo.apps.vo_run import VORunConfig, run_odometry
        from spgeo.vo import OdometryConfig
        cam = synthetic.default_camera(64, 48)
        scene = synthetic.SyntheticScene.generate(0)
        frames = synthetic.render_frames(scene, cam, synthetic.make_trajectory(3, 0))
        run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(64, 48)), frontend="depth",
                                               progress=False))
        build_parser().parse_args(["vo", "--dataset", "7scenes", "x", "--out", "y"])
        assert run.n_frames == 3
        assert "rerun" not in sys.modules, "rerun was imported"
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


@pytest.mark.slow
def test_completion_and_sfm_logging(tmp_path, room_completion_and_sfm):
    case = room_completion_and_sfm
    cam, frames, sparse = case.camera, case.frames, case.sparse
    comp, sfm, f = case.completion, case.sfm, case.frames[0]
    path = tmp_path / "c.rrd"
    with RerunLogger(RerunLoggerConfig(mode="save", target=str(path))) as viewer:
        viewer.log_completion(f.image, cam, comp, sparse)
        viewer.log_sfm(sfm, f.image, [g.image for g in frames[1:]])
    ents = {c.entity_path for c in RrdReader(str(path)).stream()}
    assert {"/world/camera/image", "/world/camera/depth", "/world/camera/sparse",
            "/world/primitives/image/segments", "/world/cloud", "/world/reference",
            "/world/reference/image/depth", "/world/views/0", "/world/views/1"} <= ents
