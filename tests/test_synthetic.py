"""Tests of spgeo.synthetic: the procedural ground-truth renderer."""
from __future__ import annotations

import json
import math
import os

import cv2
import numpy as np
import pytest

from spgeo import synthetic as syn
from spgeo.camera import PinholeCamera
from spgeo.frame import Frame
from spgeo.geometry import (check_pose, pose_from_tum, relative_pose, rotation_angle_deg,
                            transform_points)
from spgeo.images import sample_bilinear, scharr_gradients, to_gray

CAM = syn.default_camera(160, 120)


@pytest.fixture(scope="module")
def scene() -> syn.SyntheticScene:
    return syn.SyntheticScene.generate(3)


def _pose(eye, yaw_deg, pitch_deg=0.0, roll_deg=0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = syn.camera_rotation(math.radians(yaw_deg), math.radians(pitch_deg),
                                    math.radians(roll_deg))
    T[:3, 3] = eye
    return T


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


# ------------------------------------------------------------------ scene
def test_generate_is_deterministic_by_seed():
    a, b, c = (syn.SyntheticScene.generate(s) for s in (5, 5, 6))
    assert a.objects == b.objects
    assert a.surfaces == b.surfaces
    assert a.objects != c.objects
    T = _pose((0.1, -0.2, 1.4), 40.0, -5.0)
    va, vb, vc = (s.render(CAM, T) for s in (a, b, c))
    np.testing.assert_array_equal(va.rgb, vb.rgb)
    np.testing.assert_array_equal(va.depth, vb.depth)
    np.testing.assert_array_equal(va.surface_ids, vb.surface_ids)
    assert np.mean(np.abs(va.rgb - vc.rgb)) > 0.02


def test_scene_layout_respects_free_zone_and_room(scene):
    cfg = scene.config
    X, Y, Z = cfg.room_size
    n_req = cfg.n_boxes + cfg.n_cylinders + cfg.n_spheres + cfg.n_panels
    assert len(scene.objects) >= n_req - 2
    kinds = {type(o) for o in scene.objects}
    assert kinds == {syn.BoxSpec, syn.CylinderSpec, syn.SphereSpec, syn.PanelSpec}
    # ids: room 0..5, then distinct consecutive ids
    assert [s.id for s in scene.surfaces] == list(range(len(scene.surfaces)))
    assert [s.name for s in scene.surfaces[:6]] == ["floor", "ceiling", "wall-x", "wall+x",
                                                     "wall-y", "wall+y"]
    # the mesh vertices of every object stay outside the free zone and inside the room
    V = scene._vertices.astype(float)
    obj_vertices = V[np.isin(np.arange(len(V)), scene._triangles[scene._tri_surface >= 6].ravel())]
    r = np.linalg.norm(obj_vertices[:, :2], axis=1)
    assert r.min() >= cfg.free_zone_radius - 1e-6
    assert np.all(np.abs(obj_vertices[:, 0]) <= X / 2 + 1e-6)
    assert np.all(np.abs(obj_vertices[:, 1]) <= Y / 2 + 1e-6)
    assert obj_vertices[:, 2].min() >= -1e-6 and obj_vertices[:, 2].max() <= Z + 1e-6


def test_closed_room_has_no_misses_and_objects_are_visible(scene):
    poses = syn.make_trajectory(60, seed=4)[::6]
    seen = set()
    depths = []
    for T in poses:
        v = scene.render(CAM, T)
        assert v.valid.all() and np.isfinite(v.depth).all()
        seen.update(np.unique(scene.surface_object(v.surface_ids)).tolist())
        depths.append(v.depth)
    d = np.concatenate([x.ravel() for x in depths])
    assert d.min() > 0.3 and d.max() < 8.0
    assert np.mean((d > 1.0) & (d < 5.0)) > 0.9
    assert len(seen - {-1}) >= 3  # several objects seen while looking around


def test_rays_that_leave_the_room_are_misses():
    room = syn.SyntheticScene.build([syn.SphereSpec((0.0, 0.0, 1.5), 0.5)], seed=0)
    v = room.render(CAM, _pose((10.0, 0.0, 1.5), 0.0))  # outside, looking away from the room
    assert not v.valid.any()
    assert np.all(v.surface_ids == -1) and np.all(np.isnan(v.depth))
    assert np.all(np.isnan(v.normals)) and np.all(v.rgb == 0)
    hit = room.cast_rays(np.array([0.0, 0.0, 1.5]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    # from inside the sphere: the far side of the sphere, at its radius
    np.testing.assert_allclose(hit["t"], [0.5, 0.5], atol=1e-9)
    assert np.all(hit["surface_ids"] == 6)
    np.testing.assert_allclose(hit["normals"], [[-1, 0, 0], [0, 0, -1]], atol=1e-9)


# ------------------------------------------------------------- geometry
def test_wall_depth_and_normals_facing_camera():
    room = syn.SyntheticScene.build([], syn.SceneConfig(), seed=0)
    v = room.render(CAM, _pose((0.4, -0.3, 1.5), 0.0))  # looking along +x at wall x = 3
    assert np.all(v.surface_ids == 3)  # wall+x
    np.testing.assert_allclose(v.depth, 2.6, atol=1e-5)
    np.testing.assert_allclose(v.normals, np.broadcast_to([0, 0, -1], v.normals.shape), atol=1e-6)


def test_slanted_view_of_wall_matches_plane_with_anisotropic_intrinsics():
    cam = PinholeCamera(170.0, 130.0, 71.3, 52.9, 160, 120)
    room = syn.SyntheticScene.build([], syn.SceneConfig(), seed=0)
    T = _pose((0.2, 0.5, 1.3), 25.0, 10.0, 5.0)
    v = room.render(cam, T)
    wall = v.surface_ids == 3
    assert wall.mean() > 0.5
    X = transform_points(T, cam.unproject_depth_map(v.depth))
    np.testing.assert_allclose(X[wall][:, 0], 3.0, atol=2e-5)
    # analytic depth of the plane x = 3 along each ray
    rays = cam.rays() @ T[:3, :3].T
    z = (3.0 - T[0, 3]) / rays[..., 0]
    np.testing.assert_allclose(v.depth[wall], z[wall], rtol=1e-6)
    n_cam = T[:3, :3].T @ np.array([-1.0, 0.0, 0.0])
    np.testing.assert_allclose(v.normals[wall], np.broadcast_to(n_cam, v.normals[wall].shape),
                               atol=1e-6)


def test_sphere_depth_and_exact_normals():
    centre, radius = np.array([2.0, 0.5, 1.5]), 0.4
    sc = syn.SyntheticScene.build([syn.SphereSpec(tuple(centre), radius)], seed=1)
    cam = PinholeCamera(150.0, 150.0, 80.0, 60.0, 161, 121)
    eye = np.array([0.0, 0.0, 1.5])
    T = syn.look_at(eye, centre)
    v = sc.render(cam, T)
    sid = [s.id for s in sc.surfaces if s.kind == syn.SurfaceKind.SPHERE][0]
    assert v.surface_ids[60, 80] == sid
    assert v.depth[60, 80] == pytest.approx(np.linalg.norm(centre - eye) - radius, abs=1e-5)
    np.testing.assert_allclose(v.normals[60, 80], [0, 0, -1], atol=1e-6)
    on = v.surface_ids == sid
    assert on.sum() > 500
    c_cam = transform_points(np.linalg.inv(T), centre)
    P = cam.unproject_depth_map(v.depth)[on]
    np.testing.assert_allclose(np.linalg.norm(P - c_cam, axis=1), radius, atol=2e-5)
    assert _angle_deg(v.normals[on], (P - c_cam) / radius).max() < 0.05
    # silhouette: every pixel whose ray clearly hits the analytic sphere shows it
    r = cam.rays()
    rr = np.sum(r * r, -1)
    rc = r @ c_cam
    disc = rc ** 2 - rr * (c_cam @ c_cam - radius ** 2)
    inside = disc / rr > (0.01 * radius) ** 2  # away from the grazing rim
    assert np.all(on[inside])
    assert not np.any(on[disc < 0])


def test_cylinder_normals_are_radial():
    sc = syn.SyntheticScene.build([syn.CylinderSpec((2.0, -0.3, 0.0), 0.3, 2.0)], seed=2)
    T = syn.look_at((0.0, 0.2, 1.6), (2.0, -0.3, 1.0))
    v = sc.render(CAM, T)
    side = [s.id for s in sc.surfaces if s.kind == syn.SurfaceKind.CYLINDER][0]
    on = v.surface_ids == side
    assert on.sum() > 300
    X = transform_points(T, CAM.unproject_depth_map(v.depth))[on]
    radial = X[:, :2] - [2.0, -0.3]
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), 0.3, atol=2e-5)
    n_world = v.normals[on] @ T[:3, :3].T
    np.testing.assert_allclose(n_world[:, 2], 0.0, atol=1e-6)
    assert _angle_deg(n_world[:, :2], radial).max() < 0.01


def test_normals_unit_facing_camera_and_consistent_with_depth(scene):
    T = _pose((0.2, 0.1, 1.45), 130.0, -8.0, 3.0)
    cam = syn.default_camera(320, 240)
    v = scene.render(cam, T)
    n = v.normals.astype(float)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    assert np.all(np.sum(n * cam.rays(), axis=-1) < 0)
    # finite-difference normals of the unprojected depth, where the 3x3 patch is one surface
    P = cam.unproject_depth_map(v.depth)
    ids = v.surface_ids
    same = np.ones_like(ids[1:-1, 1:-1], dtype=bool)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            same &= ids[1 + dv:ids.shape[0] - 1 + dv, 1 + du:ids.shape[1] - 1 + du] == ids[1:-1, 1:-1]
    du_vec = P[1:-1, 2:] - P[1:-1, :-2]
    dv_vec = P[2:, 1:-1] - P[:-2, 1:-1]
    n_fd = np.cross(dv_vec, du_vec)  # faces the camera (x right, y down, z forward)
    n_fd /= np.linalg.norm(n_fd, axis=-1, keepdims=True)
    n_c = n[1:-1, 1:-1]
    err = _angle_deg(n_fd, n_c)
    kinds = np.array([s.kind for s in scene.surfaces])[ids[1:-1, 1:-1]]
    planar = same & (kinds == syn.SurfaceKind.PLANE)
    curved = same & (kinds != syn.SurfaceKind.PLANE)
    assert planar.sum() > 0.5 * planar.size
    assert np.percentile(err[planar], 99) < 0.05
    if curved.sum() > 50:
        assert np.median(err[curved]) < 2.0


def test_intrinsics_are_honoured_exactly():
    """A panel facing the camera: its edges project where K says (fx != fy, off-centre c)."""
    cam = PinholeCamera(200.0, 150.0, 70.3, 45.8, 160, 100)
    panel = syn.PanelSpec(center=(2.0, 0.2, 1.6), normal=(-1.0, 0.0, 0.0), size=(0.8, 0.6))
    sc = syn.SyntheticScene.build([panel], seed=0)
    T = _pose((0.0, 0.0, 1.5), 0.0)  # looking along +x from height 1.5
    v = sc.render(cam, T)
    pid = 6
    # panel corners in the camera frame: x_cam = -y_world, y_cam = -(z - 1.5), z_cam = 2
    corners_world = np.array([[2.0, -0.2, 1.3], [2.0, 0.6, 1.9]])
    uv, z = cam.project(transform_points(np.linalg.inv(T), corners_world))
    np.testing.assert_allclose(z, 2.0)
    u_lo, u_hi = sorted(uv[:, 0])
    v_lo, v_hi = sorted(uv[:, 1])
    assert u_lo == pytest.approx(200.0 * -0.6 / 2.0 + 70.3) and v_lo == pytest.approx(
        150.0 * -0.4 / 2.0 + 45.8)
    u, vv = cam.pixel_grid()
    pred = (u > u_lo) & (u < u_hi) & (vv > v_lo) & (vv < v_hi)
    clear = (np.minimum(np.abs(u - u_lo), np.abs(u - u_hi)) > 1e-3) & (
        np.minimum(np.abs(vv - v_lo), np.abs(vv - v_hi)) > 1e-3)
    assert pred.sum() > 1000
    np.testing.assert_array_equal((v.surface_ids == pid)[clear], pred[clear])
    np.testing.assert_allclose(v.depth[pred & clear], 2.0, atol=1e-6)
    np.testing.assert_allclose(v.depth[~pred & clear & (v.surface_ids == 3)], 3.0, atol=1e-5)
    # a known 3-D point: the panel centre projects to its K-predicted pixel, with depth 2
    (uc, vc), _ = cam.project(transform_points(np.linalg.inv(T), np.array(panel.center)))
    assert v.depth[int(round(vc)), int(round(uc))] == pytest.approx(2.0, abs=1e-6)
    assert (uc, vc) == pytest.approx((200.0 * 0.2 / 2.0 * -1 + 70.3, 150.0 * -0.1 / 2.0 + 45.8))


# ------------------------------------------------------------ appearance
def test_shading_is_lambertian_and_albedo_is_solid(scene):
    T = _pose((-0.2, 0.3, 1.35), 250.0, -10.0)
    flat_scene = syn.SyntheticScene.generate(3, syn.SceneConfig(shading=False))
    v_flat = flat_scene.render(CAM, T)
    v = scene.render(CAM, T)
    np.testing.assert_array_equal(v.depth, v_flat.depth)
    X = transform_points(T, CAM.unproject_depth_map(v.depth)).reshape(-1, 3)
    alb = scene.albedo(X, v.surface_ids.reshape(-1)).reshape(v.rgb.shape)
    np.testing.assert_allclose(v_flat.rgb, alb, atol=2e-5)
    n_world = v.normals.reshape(-1, 3) @ T[:3, :3].T
    cfg = scene.config
    L = np.asarray(cfg.light_direction) / np.linalg.norm(cfg.light_direction)
    shade = cfg.ambient + cfg.diffuse * np.maximum(n_world @ L, 0.0)
    np.testing.assert_allclose(v.rgb, np.clip(alb * shade.reshape(v.depth.shape)[..., None], 0, 1),
                               atol=2e-5)
    assert v.rgb.dtype == np.float32 and v.rgb.min() >= 0 and v.rgb.max() <= 1


def test_textures_are_rich_and_distinct(scene):
    v = scene.render(CAM, _pose((0.0, 0.0, 1.4), 60.0, -10.0), supersample=2)
    gray = to_gray(v.rgb)
    gu, gv = scharr_gradients(gray)
    mag = np.hypot(gu, gv)
    ids, counts = np.unique(v.surface_ids, return_counts=True)
    big = ids[counts > 400]
    assert len(big) >= 3
    means = []
    for s in big:
        m = v.surface_ids == s
        assert gray[m].std() > 0.03, s
        assert np.mean(mag[m] > 0.005) > 0.5, s
        means.append(v.rgb[m].mean(axis=0))
    means = np.array(means)
    dists = np.linalg.norm(means[:, None] - means[None], axis=-1)[np.triu_indices(len(means), 1)]
    assert dists.min() > 0.01  # different surfaces look different


def test_supersampling_changes_rgb_only(scene):
    T = _pose((0.1, 0.1, 1.5), 200.0)
    v1 = scene.render(CAM, T)
    v3 = scene.render(CAM, T, supersample=3)
    np.testing.assert_array_equal(v1.depth, v3.depth)
    np.testing.assert_array_equal(v1.surface_ids, v3.surface_ids)
    diff = np.abs(v1.rgb - v3.rgb)
    assert 0.0 < diff.mean() < 0.03
    # anti-aliasing smooths: the mean gradient magnitude drops
    g1 = np.hypot(*scharr_gradients(to_gray(v1.rgb))).mean()
    g3 = np.hypot(*scharr_gradients(to_gray(v3.rgb))).mean()
    assert g3 < g1


def test_two_views_are_photometrically_consistent(scene):
    cam = syn.default_camera(320, 240)
    T_ref, views = syn.make_view_set(scene, cam, n_views=2, rotation_deg=7.5,
                                     baseline_frac=0.05, seed=1)
    ref = scene.render(cam, T_ref)
    median = float(np.median(ref.depth))
    for T_tgt in views:
        assert rotation_angle_deg(relative_pose(T_ref, T_tgt)) == pytest.approx(7.5, abs=1e-3)
        assert np.linalg.norm(T_tgt[:3, 3] - T_ref[:3, 3]) == pytest.approx(0.05 * median, rel=0.1)
        tgt = scene.render(cam, T_tgt)
        X_tgt = transform_points(relative_pose(T_tgt, T_ref), cam.unproject_depth_map(ref.depth))
        uv, z = cam.project(X_tgt)
        warped, inside = sample_bilinear(tgt.rgb, uv[..., 0], uv[..., 1])
        ui = np.clip(np.round(np.nan_to_num(uv[..., 0])).astype(int), 0, cam.width - 1)
        vi = np.clip(np.round(np.nan_to_num(uv[..., 1])).astype(int), 0, cam.height - 1)
        visible = inside & (np.abs(tgt.depth[vi, ui] - z) < 0.02 * z)
        assert visible.mean() > 0.6  # the views look at the same content
        err = np.abs(warped - ref.rgb).mean(axis=-1)
        good = np.mean(err[visible] < 0.04)
        err_identity = np.abs(tgt.rgb - ref.rgb).mean(axis=-1)
        bad = np.mean(err_identity[visible] < 0.04)
        assert good > 0.85, good
        assert bad < 0.6 * good, (bad, good)
        # and the surface id of the warped point agrees (same 3-D point)
        assert np.mean(tgt.surface_ids[vi, ui][visible] == ref.surface_ids[visible]) > 0.97


# ------------------------------------------------------------ trajectories
def test_camera_rotation_conventions():
    R = syn.camera_rotation(0.0)
    np.testing.assert_allclose(R[:, 2], [1, 0, 0], atol=1e-12)  # forward = +x
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)  # right
    assert syn.camera_rotation(0.0, math.radians(10))[2, 2] > 0  # positive pitch looks up
    T = syn.look_at((1, 2, 1.5), (3, 2, 1.5))
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
    check_pose(T)


def test_trajectory_is_smooth_deterministic_and_in_free_zone():
    cfg = syn.TrajectoryConfig()
    P = syn.make_trajectory(150, seed=2, config=cfg)
    assert P.shape == (150, 4, 4)
    for T in P:
        check_pose(T)
    np.testing.assert_array_equal(P, syn.make_trajectory(150, seed=2, config=cfg))
    assert not np.allclose(P, syn.make_trajectory(150, seed=3, config=cfg))
    t = P[:, :3, 3]
    c = np.asarray(cfg.center)
    radius = np.linalg.norm(t[:, :2] - c[:2], axis=1)
    assert radius.max() <= cfg.max_radius + 1e-9
    assert radius.max() < syn.SceneConfig().free_zone_radius - 0.3
    assert np.all(np.abs(t[:, 2] - c[2]) < cfg.height_amplitude + 0.02)
    speed = np.linalg.norm(np.diff(t, axis=0), axis=1) * cfg.fps
    assert 0.1 < speed.mean() < 0.5 and speed.max() < 1.0
    acc = np.linalg.norm(np.diff(t, 2, axis=0), axis=1) * cfg.fps ** 2
    assert np.percentile(acc, 95) < 3.0
    steps = np.array([rotation_angle_deg(relative_pose(P[i], P[i + 1])) for i in range(149)])
    assert 0.1 < steps.mean() < 2.0 and steps.max() < 3.0
    assert np.abs(np.diff(steps)).max() < 1.0  # smooth angular speed
    forward = P[:, :3, 2]
    assert np.all(np.abs(forward[:, 2]) < math.sin(math.radians(25)))  # roughly horizontal
    assert np.all(P[:, 2, 1] < -math.cos(math.radians(30)))  # image 'down' points down
    yaw = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    assert np.ptp(np.degrees(yaw)) > 10  # it looks around


def test_pure_rotation_segment_has_constant_translation():
    cfg = syn.TrajectoryConfig(pure_rotation=(40, 70))
    P = syn.make_trajectory(120, seed=7, config=cfg)
    t = P[:, :3, 3]
    np.testing.assert_array_equal(t[40:70], np.broadcast_to(t[40], (30, 3)))
    assert rotation_angle_deg(relative_pose(P[40], P[69])) > 2.0
    assert np.linalg.norm(t[39] - t[40]) < 0.05 and np.linalg.norm(t[70] - t[69]) < 0.05
    assert np.linalg.norm(t[100] - t[40]) > 0.05  # it moves again afterwards
    base = syn.make_trajectory(120, seed=7)
    np.testing.assert_allclose(t[:40], base[:40, :3, 3])
    np.testing.assert_allclose(P[:, :3, :3], base[:, :3, :3])  # rotation unaffected
    with pytest.raises(ValueError):
        syn.make_trajectory(50, seed=0, config=syn.TrajectoryConfig(pure_rotation=(40, 70)))


# --------------------------------------------------------------- outputs
def test_render_frames(scene):
    poses = syn.make_trajectory(3, seed=1)
    frames = syn.render_frames(scene, CAM, poses)
    assert len(frames) == 3 and all(isinstance(f, Frame) for f in frames)
    for i, f in enumerate(frames):
        assert f.name == f"{i:06d}" and f.timestamp == pytest.approx(i / 30.0)
        assert f.image.shape == (120, 160, 3) and f.image.dtype == np.float32
        np.testing.assert_array_equal(f.T_world_cam, poses[i])
        v = scene.render(CAM, poses[i])
        np.testing.assert_array_equal(f.depth, v.depth)
        np.testing.assert_array_equal(f.meta["normals"], v.normals)
        np.testing.assert_array_equal(f.meta["surface_ids"], v.surface_ids)
    stamped = syn.render_frames(scene, CAM, poses[:2], timestamps=[5.0, 6.5])
    assert [f.timestamp for f in stamped] == [5.0, 6.5]


def _read_list(path):
    with open(path, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    assert len(lines) >= 3 and all(line.startswith("#") for line in lines[:3])
    assert not any(line.startswith("#") for line in lines[3:])
    return [line.split() for line in lines[3:]]


def test_write_tum_sequence_round_trip(scene, tmp_path):
    cam = syn.default_camera(64, 48)
    poses = syn.make_trajectory(4, seed=3)
    out = tmp_path / "seq"
    stamps = syn.write_tum_sequence(out, scene, cam, poses, fps=30.0)
    assert stamps == ["1000000000.000000", "1000000000.033333", "1000000000.066667",
                      "1000000000.100000"]
    rgb_rows = _read_list(out / "rgb.txt")
    depth_rows = _read_list(out / "depth.txt")
    gt_rows = _read_list(out / "groundtruth.txt")
    assert [r[0] for r in rgb_rows] == stamps
    assert [r[1] for r in rgb_rows] == [f"rgb/{s}.png" for s in stamps]
    assert len(depth_rows) == 4 and len(gt_rows) == 4
    for i, (rgb_row, depth_row, gt_row) in enumerate(zip(rgb_rows, depth_rows, gt_rows)):
        ts_rgb, ts_depth = float(rgb_row[0]), float(depth_row[0])
        assert ts_rgb == pytest.approx(1e9 + i / 30.0, abs=1e-6)
        assert 0 < ts_depth - ts_rgb < 0.01
        assert depth_row[1] == f"depth/{depth_row[0]}.png"
        assert gt_row[0] == rgb_row[0] and len(gt_row) == 8
        v = scene.render(cam, poses[i])
        bgr = cv2.imread(os.fspath(out / rgb_row[1]), cv2.IMREAD_UNCHANGED)
        assert bgr.dtype == np.uint8 and bgr.shape == (48, 64, 3)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        assert np.abs(rgb - v.rgb).max() <= 0.5 / 255 + 1e-6
        d16 = cv2.imread(os.fspath(out / depth_row[1]), cv2.IMREAD_UNCHANGED)
        assert d16.dtype == np.uint16 and d16.shape == (48, 64)
        assert np.all(d16 > 0)
        np.testing.assert_allclose(d16 / 5000.0, v.depth, atol=0.5 / 5000 + 1e-6)
        T = pose_from_tum([float(x) for x in gt_row[1:]])
        np.testing.assert_allclose(T, poses[i], atol=1e-7)
    with open(out / "camera.json", encoding="utf-8") as fh:
        assert PinholeCamera.from_dict(json.load(fh)) == cam
