"""nerfstudio export (spgeo.io.nerfstudio_export): a synthetic VO run written
as ``transforms.json`` + images and read back (poses round-trip, a 3-D point
projects to the same pixel with spgeo's camera and with nerfstudio's OpenGL
camera-to-world matrix and pixel convention, nerfstudio's rays through pixel
centres are spgeo's), ``spgeo vo --mesh --export-nerfstudio DIR --all-frames
--rerun save FILE`` on a 7-Scenes-layout copy, and bad export folders (exit 2,
one line, nothing written)."""
import json

import cv2
import numpy as np
import pytest

from layouts import write_7scenes
from spgeo import synthetic
from spgeo.vo import OdometryConfig
from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.geometry import invert_pose, transform_points
from spgeo.io.nerfstudio_export import (TRANSFORMS_FILE, export_nerfstudio,
                                        opencv_from_opengl, opengl_from_opencv)

CAM = synthetic.default_camera(160, 120)


@pytest.fixture(scope="module")
def vo_run():
    scene = synthetic.SyntheticScene.generate(0)
    frames = synthetic.render_frames(scene, CAM, synthetic.make_trajectory(40, 0)[::2],
                                     supersample=2)
    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(160, 120)),
                                           frontend="depth", progress=False))
    return run, frames


def _read(folder):
    doc = json.loads((folder / TRANSFORMS_FILE).read_text())
    return doc, {f["file_path"]: np.array(f["transform_matrix"]) for f in doc["frames"]}


def _nerfstudio_pixel(doc, M, X):
    """nerfstudio's continuous pixel of world point X: OpenGL camera axes
    (the camera looks along -z, y up), pixel corners at integers."""
    Xc = transform_points(invert_pose(M), X)
    return np.array([doc["fl_x"] * Xc[0] / -Xc[2] + doc["cx"],
                     doc["cy"] - doc["fl_y"] * Xc[1] / -Xc[2]])


def _nerfstudio_ray(doc, M, i, j):
    """World direction of nerfstudio's ray for integer pixel (i, j)
    (nerfstudio.cameras.Cameras: pixel + 0.5, y flipped, z = -1)."""
    d = np.array([(i + 0.5 - doc["cx"]) / doc["fl_x"], -(j + 0.5 - doc["cy"]) / doc["fl_y"], -1.0])
    return M[:3, :3] @ d


def test_conventions():
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    T[:3, 3] = [1.0, 2.0, 3.0]
    M = opengl_from_opencv(T)
    np.testing.assert_allclose(M[:3, 0], T[:3, 0])          # x right in both
    np.testing.assert_allclose(M[:3, 1], -T[:3, 1])         # y: up vs down
    np.testing.assert_allclose(M[:3, 2], -T[:3, 2])         # z: back vs forward
    np.testing.assert_allclose(M[:3, 3], T[:3, 3])          # same camera centre
    np.testing.assert_allclose(opencv_from_opengl(M), T, atol=1e-15)


def test_keyframes_round_trip_and_project(vo_run, tmp_path):
    run, frames = vo_run
    res = run.result()
    kf = np.flatnonzero(res.is_keyframe)
    path = run.export_nerfstudio(tmp_path / "ns")
    assert path == tmp_path / "ns" / TRANSFORMS_FILE
    doc, mats = _read(tmp_path / "ns")
    assert doc["camera_model"] == "PINHOLE" and (doc["w"], doc["h"]) == (160, 120)
    assert (doc["fl_x"], doc["fl_y"]) == (CAM.fx, CAM.fy)
    assert (doc["cx"], doc["cy"]) == (CAM.cx + 0.5, CAM.cy + 0.5)
    names = [f"images/{run.names[i]}.png" for i in kf]
    assert [f["file_path"] for f in doc["frames"]] == names
    rng = np.random.default_rng(0)
    for name, i in zip(names, kf):
        T = res.poses[i]
        np.testing.assert_allclose(opencv_from_opengl(mats[name]), T, atol=1e-12)
        img = cv2.imread(str(tmp_path / "ns" / name))
        assert img is not None and img.shape == (120, 160, 3)
        uv = rng.uniform([5, 5], [150, 110])
        X = transform_points(T, CAM.unproject(uv[None], np.array([2.5])))[0]
        np.testing.assert_allclose(CAM.project(transform_points(invert_pose(T), X[None]))[0][0],
                                   uv, atol=1e-9)
        np.testing.assert_allclose(_nerfstudio_pixel(doc, mats[name], X), uv + 0.5, atol=1e-9)
        ray = _nerfstudio_ray(doc, mats[name], 7, 11)
        ours = T[:3, :3] @ CAM.unproject(np.array([[7.0, 11.0]]), np.array([1.0]))[0]
        np.testing.assert_allclose(ray / np.linalg.norm(ray), ours / np.linalg.norm(ours),
                                   atol=1e-12)


def test_all_frames_and_replacement(vo_run, tmp_path):
    run, frames = vo_run
    res = run.result()
    out = tmp_path / "ns"
    run.export_nerfstudio(out)                       # a previous export is replaced
    run.export_nerfstudio(out, frames)
    doc, mats = _read(out)
    keep = [i for i, s in enumerate(res.statuses) if s != "lost"]
    assert len(doc["frames"]) == len(keep) > int(res.is_keyframe.sum())
    for i in keep:
        np.testing.assert_allclose(opencv_from_opengl(mats[f"images/{run.names[i]}.png"]),
                                   res.poses[i], atol=1e-12)
    assert len(list((out / "images").iterdir())) == len(keep)


def test_bad_input(tmp_path):
    from spgeo.validation import InputError

    img = np.zeros((120, 160, 3), np.uint8)
    with pytest.raises(ValueError, match="images for"):
        export_nerfstudio(tmp_path / "a", CAM, [("x", img)], np.stack([np.eye(4)] * 2))
    assert not (tmp_path / "a").exists()                     # nothing half-written
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "keep.txt").write_text("x")
    with pytest.raises(InputError, match="other files"):
        export_nerfstudio(tmp_path / "b", CAM, [("x", img)], np.eye(4)[None])
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="nerfstudio export directory"):
        export_nerfstudio(tmp_path / "file" / "ns", CAM, [("x", img)], np.eye(4)[None])


def test_cli_mesh_nerfstudio_rerun(vo_run, tmp_path, capsys):
    """``spgeo vo --mesh --export-nerfstudio DIR --all-frames [--rerun save F]``:
    OUT/mesh.ply and OUT/cloud.ply, the data set with trajectory.txt's poses,
    the mesh in the recording."""
    from spgeo.cli import main
    from spgeo.io.tum import read_status, read_tum

    _, frames = vo_run
    seq = write_7scenes(tmp_path / "seq-01", frames[:8], CAM.resized(640, 480).K)
    out, ns = tmp_path / "out", tmp_path / "ns"
    args = ["vo", "--dataset", "7scenes", str(seq), "--resolution", "160x120", "--frontend",
            "depth", "--no-progress", "--out", str(out), "--mesh", "--export-nerfstudio",
            str(ns), "--all-frames"]
    rrd = None
    try:
        import rerun  # noqa: F401

        rrd = tmp_path / "vo.rrd"
        args += ["--rerun", "save", str(rrd)]
    except ImportError:
        pass
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "mesh.ply" in printed and "nerfstudio" in printed
    import open3d as o3d

    assert len(o3d.io.read_triangle_mesh(str(out / "mesh.ply")).triangles) > 100
    assert len(o3d.io.read_point_cloud(str(out / "cloud.ply")).points) > 100
    traj = read_tum(out / "trajectory.txt")
    _, status = read_status(out / "trajectory.status.txt")
    doc, mats = _read(ns)
    poses = {f"images/frame-{int(t):06d}.png": T for t, T, s in
             zip(traj.timestamps, traj.poses, status) if s != "lost"}
    assert set(mats) == set(poses)
    for name, T in poses.items():
        np.testing.assert_allclose(opencv_from_opengl(mats[name]), T, atol=1e-7)  # 9 decimals
    if rrd is not None:
        from rerun.chunk import RrdReader

        paths = {c.entity_path for c in RrdReader(str(rrd)).stream()}
        assert "/world/mesh" in paths


@pytest.mark.parametrize("where", ["file", "proc"])
def test_cli_unwritable_export_exit_2(vo_run, tmp_path, capsys, where):
    """A nerfstudio folder that cannot be written: one-line error naming it,
    exit 2, before the run (no output folder)."""
    from spgeo.cli import main

    _, frames = vo_run
    seq = write_7scenes(tmp_path / "seq-01", frames[:2], CAM.resized(640, 480).K)
    (tmp_path / "file").write_text("x")
    bad = tmp_path / "file" / "ns" if where == "file" else "/proc/spgeo-ns/ns"
    rc = main(["vo", "--dataset", "7scenes", str(seq), "--no-progress",
               "--out", str(tmp_path / "out"), "--export-nerfstudio", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.startswith("spgeo vo: error:") and str(bad) in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()
