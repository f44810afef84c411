"""COLMAP export (spgeo.io.colmap_export): a synthetic VO run (keyframes and all
frames), a synthetic SfM-like result and ``spgeo sfm --export-colmap``, each
read back with pycolmap: poses, intrinsics (+0.5 principal-point shift), image
files, and every 3-D point in front of and inside the image that observes it."""
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from layouts import write_7scenes  # noqa: E402
from spgeo.vo import KeyframeDecisionConfig, OdometryConfig  # noqa: E402
from spgeo import synthetic  # noqa: E402
from spgeo.apps.vo_run import VORunConfig, run_odometry  # noqa: E402
from spgeo.frontend import FrontEndConfig, make_frontend  # noqa: E402
from spgeo.geometry import invert_pose, relative_pose  # noqa: E402
from spgeo.io.colmap_export import (ColmapPoints, check_export_directory,  # noqa: E402
                                    export_colmap, export_sfm_result, image_file_name)

CAM = synthetic.default_camera(160, 120)


@pytest.fixture(scope="module")
def vo_run():
    """20 frames at 160x120 (every second pose of a 40-pose trajectory: enough
    parallax to initialise), depth front-end."""
    scene = synthetic.SyntheticScene.generate(0)
    frames = synthetic.render_frames(scene, CAM, synthetic.make_trajectory(40, 0)[::2],
                                     supersample=2)
    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(160, 120), keyframe=KeyframeDecisionConfig(max_translation=0.05)), frontend="depth",
                                           progress=False))
    return run, frames


def check_model(model_dir, poses, camera, min_points=100, pose_atol=1e-9):
    """Read the model back and check it against ``poses`` (name -> T_world_cam).

    Returns the reconstruction."""
    rec = pycolmap.Reconstruction(str(model_dir))
    assert rec.num_cameras() == 1 and rec.num_images() == len(poses)
    cam = rec.cameras[1]
    assert cam.model.name == "PINHOLE"
    assert (cam.width, cam.height) == (camera.width, camera.height)
    np.testing.assert_allclose(cam.params, [camera.fx, camera.fy, camera.cx + 0.5,
                                            camera.cy + 0.5], rtol=0, atol=1e-12)
    image_dir = model_dir.parent.parent / "images"
    cfw = {}
    for img in rec.images.values():
        assert img.has_pose and img.name in poses
        M = np.asarray(img.cam_from_world().matrix())
        np.testing.assert_allclose(M, invert_pose(poses[img.name])[:3], rtol=0,
                                   atol=pose_atol)
        cfw[img.image_id] = M
        pix = cv2.imread(str(image_dir / img.name), cv2.IMREAD_UNCHANGED)
        assert pix is not None and pix.shape == (camera.height, camera.width, 3)
    # every point: observed once, in front of its camera, projecting inside its
    # image onto its own 2-D observation
    assert rec.num_points3D() >= min_points
    xyz, ids, kp = [], [], []
    for p in rec.points3D.values():
        (el,) = p.track.elements
        xyz.append(p.xyz)
        ids.append(el.image_id)
        kp.append(rec.images[el.image_id].points2D[el.point2D_idx].xy)
    xyz, ids, kp = np.array(xyz), np.array(ids), np.array(kp)
    R = np.stack([cfw[i][:, :3] for i in ids])
    t = np.stack([cfw[i][:, 3] for i in ids])
    Xc = np.einsum("nij,nj->ni", R, xyz) + t
    assert np.all(Xc[:, 2] > 0)
    fx, fy, cx, cy = cam.params
    uv = np.stack([fx * Xc[:, 0] / Xc[:, 2] + cx, fy * Xc[:, 1] / Xc[:, 2] + cy], -1)
    assert np.all((uv >= 0) & (uv < [camera.width, camera.height]))
    np.testing.assert_allclose(uv, kp, atol=1e-6)
    return rec


def test_vo_keyframes_export(vo_run, tmp_path):
    run, _ = vo_run
    res = run.result()
    kf_idx = np.flatnonzero(res.is_keyframe)
    assert len(kf_idx) >= 2
    model = run.export_colmap(tmp_path / "colmap")
    assert model == tmp_path / "colmap" / "sparse" / "0"
    poses = {image_file_name(run.names[i]): res.poses[i] for i in kf_idx}
    rec = check_model(model, poses, CAM)
    # colours and images are the run's processed keyframe images
    for k, i in enumerate(kf_idx):
        png = cv2.imread(str(tmp_path / "colmap" / "images" / image_file_name(run.names[i])))
        want = np.round(run.keyframe_images[k] * 255).astype(np.uint8)[..., ::-1]
        np.testing.assert_array_equal(png, want)
    p = next(iter(rec.points3D.values()))
    el = p.track.elements[0]
    u, v = np.round(rec.images[el.image_id].points2D[el.point2D_idx].xy - 0.5).astype(int)
    png = cv2.imread(str(tmp_path / "colmap" / "images" / rec.images[el.image_id].name))
    np.testing.assert_array_equal(p.color, png[v, u, ::-1])
    # no temporary folders left next to the export
    assert sorted(x.name for x in tmp_path.iterdir()) == ["colmap"]
    # COLMAP's own MVS preparation (image_undistorter) accepts the model
    pycolmap.undistort_images(str(tmp_path / "mvs"), str(model),
                              str(tmp_path / "colmap" / "images"))
    assert pycolmap.Reconstruction(str(tmp_path / "mvs" / "sparse")).num_images() == len(kf_idx)
    assert len(list((tmp_path / "mvs" / "images").iterdir())) == len(kf_idx)


def test_vo_all_frames_export_replaces_previous(vo_run, tmp_path):
    run, frames = vo_run
    res = run.result()
    out = tmp_path / "colmap"
    run.export_colmap(out)                      # keyframes first, then replaced
    model = run.export_colmap(out, frames=frames)
    keep = [i for i, s in enumerate(res.statuses) if s != "lost"]
    assert len(keep) > int(res.is_keyframe.sum())
    check_model(model, {image_file_name(run.names[i]): res.poses[i] for i in keep}, CAM)
    assert len(list((out / "images").iterdir())) == len(keep)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["colmap"]
    with pytest.raises(ValueError, match="not the run's frame"):
        run.export_colmap(tmp_path / "bad", frames=frames[1:])
    assert not (tmp_path / "bad").exists()


def test_sfm_result_export(tmp_path):
    """A SfM-like result (depth front-end primitives of the reference, ground-truth
    relative poses) exported at the working resolution from 320x240 inputs."""
    scene = synthetic.SyntheticScene.generate(1)
    big = synthetic.default_camera(320, 240)
    T_ref, T_views = synthetic.make_view_set(scene, big, 2, 7.5, 0.05, 1)
    views = [scene.render(big, T, supersample=2) for T in [T_ref] + list(T_views)]
    fe = make_frontend("depth", FrontEndConfig(working_size=CAM.size))
    prims = fe.primify(views[0].rgb, big, views[0].depth)
    assert prims.camera.shape == CAM.shape
    result = SimpleNamespace(camera=prims.camera, primitives=prims, supported_primitives=prims,
                             T_ref_view=[relative_pose(T_ref, T) for T in T_views])
    names = ["ref.jpg", "a.png", "b"]
    model = export_sfm_result(tmp_path / "m", result, [v.rgb for v in views], names)
    poses = dict(zip(["ref.png", "a.png", "b.png"], [np.eye(4)] + result.T_ref_view))
    rec = check_model(model, poses, prims.camera)
    # the reference's points are the scene: they land on the surface seen by view 1
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    Xw = xyz @ T_ref[:3, :3].T + T_ref[:3, 3]
    T1 = invert_pose(T_views[0])
    Xc = Xw @ T1[:3, :3].T + T1[:3, 3]
    cam1 = prims.camera
    u = np.round(cam1.fx * Xc[:, 0] / Xc[:, 2] + cam1.cx).astype(int)
    v = np.round(cam1.fy * Xc[:, 1] / Xc[:, 2] + cam1.cy).astype(int)
    ok = (Xc[:, 2] > 0) & (u >= 0) & (u < cam1.width) & (v >= 0) & (v < cam1.height)
    assert ok.mean() > 0.5
    d1 = scene.render(cam1, T_views[0]).depth[v[ok], u[ok]]
    rel = np.abs(Xc[ok, 2] / d1 - 1)
    assert np.nanmedian(rel) < 0.02


def test_bad_input(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "trajectory.txt").write_text("x")
    with pytest.raises(ValueError, match="holds other files"):
        check_export_directory(tmp_path / "run")
    with pytest.raises(ValueError, match="is the output folder"):
        check_export_directory(tmp_path / "new", tmp_path / "new")
    img = np.zeros((CAM.height, CAM.width, 3), np.uint8)
    pts = ColmapPoints(np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3), np.uint8),
                       np.array([1]), np.array([[5.0, 5.0]]))
    with pytest.raises(ValueError, match="image_index reaches 1"):
        export_colmap(tmp_path / "x", CAM, [("a", img)], np.eye(4)[None], pts)
    with pytest.raises(ValueError, match="1 images for 2 poses"):
        export_colmap(tmp_path / "x", CAM, [("a", img)], np.stack([np.eye(4)] * 2))
    with pytest.raises(ValueError, match="repeated"):
        export_colmap(tmp_path / "x", CAM, [("a", img), ("a.png", img)],
                      np.stack([np.eye(4)] * 2))
    with pytest.raises(ValueError, match="shape"):
        export_colmap(tmp_path / "x", CAM, [("a", img[:10])], np.eye(4)[None])
    with pytest.raises(ValueError, match="rgb"):
        ColmapPoints(np.zeros((2, 3)), np.zeros((1, 3), np.uint8), np.zeros(2, int),
                     np.zeros((2, 2)))
    assert sorted(x.name for x in tmp_path.iterdir()) == ["run"]   # nothing half-written


def test_cli_sfm_export_colmap(tmp_path):
    """``spgeo sfm --export-colmap`` (the test_sfm CLI set-up, 320x240 images,
    classical front-end): a model pycolmap reads, with the poses of poses.txt."""
    from spgeo.cli import main
    from spgeo.geometry import pose_from_tum
    from spgeo.viz import save_png

    big = synthetic.default_camera(320, 240)
    scene = synthetic.SyntheticScene.generate(2)
    T_ref, T_views = synthetic.make_view_set(scene, big, 2, 7.5, 0.05, 2)
    paths = []
    for k, T in enumerate([T_ref] + list(T_views)):
        p = tmp_path / f"img{k}.png"
        save_png(p, (scene.render(big, T, supersample=2).rgb * 255).round().astype(np.uint8))
        paths.append(str(p))
    out, exp = tmp_path / "out", tmp_path / "colmap"
    args = ["sfm", "--ref", paths[0], "--views", *paths[1:], "--intrinsics",
            f"{big.fx},{big.fy},{big.cx},{big.cy}", "--out", str(out)]
    assert main(args + ["--export-colmap", str(out)]) == 2     # refused before the run
    assert not out.exists()
    assert main(args + ["--export-colmap", str(exp)]) == 0
    lines = [l.split() for l in (out / "poses.txt").read_text().splitlines()]
    poses = {l[0]: pose_from_tum([float(x) for x in l[1:]]) for l in lines}
    rec = pycolmap.Reconstruction(str(exp / "sparse" / "0"))
    w, h = rec.cameras[1].width, rec.cameras[1].height
    cam = big.resized(w, h)
    check_model(exp / "sparse" / "0", poses, cam, pose_atol=1e-7)   # poses.txt: 9 decimals


def test_cli_vo_export_colmap_all_frames(vo_run, tmp_path):
    """``spgeo vo --export-colmap DIR --all-frames`` on a 7-Scenes-layout copy of
    the first 8 synthetic frames (stored at 640x480, nearest-neighbour, run at
    160x120): every frame not lost, with the poses of trajectory.txt."""
    from spgeo.cli import main
    from spgeo.io.tum import read_status, read_tum

    _, frames = vo_run
    seq = write_7scenes(tmp_path / "seq-01", frames[:8], CAM.resized(640, 480).K)
    out, exp = tmp_path / "out", tmp_path / "colmap"
    assert main(["vo", "--dataset", "7scenes", str(seq), "--resolution", "160x120",
                 "--frontend", "depth", "--no-progress", "--out", str(out),
                 "--export-colmap", str(exp), "--all-frames"]) == 0
    traj = read_tum(out / "trajectory.txt")
    _, status = read_status(out / "trajectory.status.txt")
    poses = {f"frame-{int(t):06d}.png": T for t, T, s in zip(traj.timestamps, traj.poses, status)
             if s != "lost"}
    assert len(poses) >= 2
    check_model(exp / "sparse" / "0", poses, CAM, pose_atol=1e-7)  # trajectory: 9 decimals
