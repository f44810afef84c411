"""TSDF fusion (spgeo.io.fusion): accuracy and completeness on a synthetic
scene, with ground-truth depth at ground-truth poses and with the VO's
keyframes after a short run (Sim(3)-aligned), the written PLY files,
streaming from the keyframe store, ``spgeo vo --mesh`` (with a rerun
recording) and the ``vo_mesh`` protocol's metrics."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.evaluation.vo.mesh import (distance_to_mesh, mesh_metrics, sample_surface,
                                      sim3_transform_mesh)
from spgeo.geometry import transform_points
from spgeo.io.fusion import CLOUD_FILE, MESH_FILE, FusionConfig, fuse_views
from spgeo.synthetic.mesh import tessellate

CAM = synthetic.default_camera(160, 120)
# metres; the synthetic room's median depth is a few metres (voxel = 1 % of it)
THRESHOLD = 0.05


@pytest.fixture(scope="module")
def scene_frames():
    scene = synthetic.SyntheticScene.generate(0)
    frames = synthetic.render_frames(scene, CAM, synthetic.make_trajectory(40, 0)[::2],
                                     supersample=2)
    return scene, frames


@pytest.fixture(scope="module")
def ground_truth(scene_frames):
    """The scene's exact surface (tessellated) and the surface points the
    frames saw (their depth back-projected, every 5th pixel)."""
    scene, frames = scene_frames
    mesh = tessellate(scene.config, scene.objects)
    seen = []
    for f in frames:
        v, u = np.nonzero(np.isfinite(f.depth))
        uv = np.stack([u, v], -1).astype(float)[::5]
        seen.append(transform_points(f.T_world_cam,
                                     CAM.unproject(uv, f.depth[v, u][::5].astype(float))))
    return mesh, np.concatenate(seen)


def _metrics(vertices, triangles, ground_truth):
    mesh, seen = ground_truth
    return mesh_metrics(vertices, triangles, mesh.vertices, mesh.triangles, THRESHOLD,
                        n_samples=30_000, ref_points=seen[::3])


def test_ground_truth_depth_fuses_onto_the_surface(scene_frames, ground_truth, tmp_path):
    _, frames = scene_frames
    res = fuse_views(((f.image, f.depth, CAM, f.T_world_cam) for f in frames))
    assert res.n_views == len(frames) and len(res.triangles) > 1000
    m = _metrics(res.vertices, res.triangles, ground_truth)
    # accuracy well under a voxel, almost everything seen is reconstructed
    assert m.accuracy < 0.25 * res.voxel_size, m
    assert m.completeness > 0.97, m
    colours = np.asarray(res.mesh.vertex_colors)
    assert colours.shape == (len(res.vertices), 3) and colours.std() > 0.02
    for c in (colours, np.asarray(res.cloud.colors)):     # plots take them as they are
        assert 0.0 <= c.min() and c.max() <= 1.0
    paths = res.write(tmp_path / "map")
    import open3d as o3d

    back = o3d.io.read_triangle_mesh(str(paths["mesh"]))
    assert paths["mesh"].name == MESH_FILE and paths["cloud"].name == CLOUD_FILE
    assert len(back.triangles) == len(res.triangles)
    assert len(o3d.io.read_point_cloud(str(paths["cloud"])).points) == len(res.cloud.points)
    assert sorted(p.name for p in (tmp_path / "map").iterdir()) == [CLOUD_FILE, MESH_FILE]


def test_config_scale_and_bad_input(scene_frames):
    _, frames = scene_frames
    f = frames[0]
    half = fuse_views([(f.image, f.depth * 0.5, CAM, f.T_world_cam)])
    full = fuse_views([(f.image, f.depth, CAM, f.T_world_cam)])
    assert half.voxel_size == pytest.approx(0.5 * full.voxel_size)    # from the median depth
    fixed = fuse_views([(None, f.depth, CAM, f.T_world_cam)], FusionConfig(voxel_size=0.1))
    assert fixed.voxel_size == 0.1 and fixed.sdf_trunc == pytest.approx(0.5)
    with pytest.raises(ValueError, match="no view with valid depth"):
        fuse_views([(f.image, np.full(CAM.shape, np.nan), CAM, f.T_world_cam)])
    with pytest.raises(ValueError):
        fuse_views([(f.image, f.depth[:-1], CAM, f.T_world_cam)])
    for bad in ({"voxel_size": 0.0}, {"min_views": 0}, {"voxel_fraction": -1.0}):
        with pytest.raises(ValueError):
            FusionConfig(**bad)


@pytest.fixture(scope="module")
def vo_run(scene_frames):
    """The classical (monocular) VO on 40 frames (every second pose of an
    80-pose trajectory), window 3 so that keyframe 0 is retired to the keyframe
    store before the fusion."""
    from spgeo.vo import OdometryConfig, MappingConfig

    scene, _ = scene_frames
    frames = synthetic.render_frames(scene, CAM, synthetic.make_trajectory(80, 0)[::2],
                                     supersample=2)
    # inline mapping: this tests the fusion of a fixed map (live maps vary with timing)
    cfg = VORunConfig(progress=False, odometry=OdometryConfig(resolution=(160, 120), window=3,
                                                              mapping=MappingConfig(mode="inline")))
    return run_odometry(frames, cfg)


def test_vo_keyframes_fuse_near_the_surface(vo_run, ground_truth, scene_frames):
    """The monocular map's depth is a few per cent off (its primitives' shapes
    and scales): bounds relative to the scene's median depth."""
    run = vo_run
    assert run.status == "ok"
    kfs = run.odometry.keyframes_with_depth()
    assert len(kfs) >= 3 and len(run.odometry.window_keyframes()) < run.odometry.n_keyframes
    res = run.fuse()
    assert res.n_views == len(kfs)
    a = run.ate()["per-frame"]
    v = sim3_transform_mesh(res.vertices, a.scale, a.rotation, a.translation)
    depth = float(np.nanmedian([f.depth for f in scene_frames[1]]))
    mesh, seen = ground_truth
    m = mesh_metrics(v, res.triangles, mesh.vertices, mesh.triangles, 0.05 * depth,
                     n_samples=30_000, ref_points=seen[::3])
    print(f"VO mesh: median depth {depth:.3f} m, {m}")
    assert m.accuracy < 0.07 * depth, m
    assert m.completeness > 0.6, m


def test_fusion_streams_keyframes_from_the_store(vo_run, monkeypatch):
    """Each keyframe is read once and dropped before the next is read."""
    import gc
    import weakref

    from spgeo.io.fusion import odometry_views

    odo = vo_run.odometry
    alive = []
    real = odo.iter_keyframes

    def spy(indices=None):
        for k, image, kf in real(indices):
            gc.collect()
            assert sum(r() is not None for r in alive) <= len(odo.window_keyframes())
            alive.append(weakref.ref(kf))
            yield k, image, kf

    monkeypatch.setattr(odo, "iter_keyframes", spy)
    n = sum(1 for _ in odometry_views(odo))
    assert n == len(odo.keyframes_with_depth())


def test_metrics_helpers():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    p = sample_surface(v, t, 1000, seed=3)
    assert p.shape == (1000, 3) and np.all(p[:, 2] == 0)
    assert np.all((p[:, :2] >= 0) & (p[:, :2] <= 1))
    np.testing.assert_allclose(distance_to_mesh([[0.5, 0.5, 0.2], [2, 0.5, 0]], v, t), [0.2, 1.0],
                               atol=1e-6)
    shifted = v + [0, 0, 0.01]
    m = mesh_metrics(shifted, t, v, t, threshold=0.02, n_samples=2000)
    assert m.accuracy == pytest.approx(0.01, abs=1e-6) and m.completeness == 1.0
    assert m.chamfer == pytest.approx(0.01, abs=1e-6)
    R = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(sim3_transform_mesh(v, 2.0, R, [1, 2, 3])[1], [1, 4, 3])
