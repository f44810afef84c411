"""Bounded memory of the VO (issue 23): what a processed frame and a keyframe that left
the window keep, and that their outputs are unchanged."""
import gc
import weakref

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.apps.memory import RssCheckpoints, current_rss_mb, peak_rss_mb
from spgeo.evaluation.vo.memory import growth_per_1000, palindrome
from spgeo.factors.photometric_group import PhotometricFactorGroup
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.vo import KeyframeDecisionConfig, Odometry, OdometryConfig, MappingConfig
from spgeo.vo.keyframe_store import KeyframeStore
from spgeo.vo.result import write_keyframe_clouds

CAM = synthetic.default_camera(160, 120)
WINDOW = 2
SMALL = 4096        # bytes: no array a processed frame keeps is larger


def _arrays(obj, seen=None):
    """Every numpy array reachable from ``obj`` through containers and attributes."""
    seen = set() if seen is None else seen
    if id(obj) in seen or isinstance(obj, (str, bytes, int, float, type(None))):
        return []
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return [obj]
    if isinstance(obj, dict):
        items = list(obj.values())
    elif isinstance(obj, (list, tuple, set)):
        items = list(obj)
    else:
        items = list(getattr(obj, "__dict__", {}).values())
    return [a for it in items for a in _arrays(it, seen)]


@pytest.fixture(scope="module")
def run():
    """Keyframes every 0.02 median depths, a window of 2: most keyframes retire.
    While a keyframe is in the window the test keeps its last state."""
    scene = synthetic.SyntheticScene.generate(0)
    poses = synthetic.make_trajectory(60, 0)
    vo = Odometry(CAM, OdometryConfig(window=WINDOW,
                                      keyframe=KeyframeDecisionConfig(max_translation=0.02),
                                      # inline: the groups are in this process
                                      mapping=MappingConfig(mode="inline")),
                  make_frontend("depth", FrontEndConfig(working_size=(160, 120))))
    gc.collect()
    before = weakref.WeakSet(_groups())     # other tests' groups, still alive
    last = {}
    for T in poses:
        view = scene.render(CAM, T)
        vo.track(Frame(view.rgb, CAM, len(vo.frames) / 30.0, depth=view.depth))
        for k, kf in vo.window_keyframes().items():
            last[k] = (vo.keyframe_image(k), kf)
    return vo, last, before


def _groups():
    return [o for o in gc.get_objects() if isinstance(o, PhotometricFactorGroup)]


def test_keyframes_outside_the_window_hold_no_image_or_pyramid(run):
    vo, last, _ = run
    live = vo.window_keyframes()
    assert len(live) <= WINDOW and vo.n_keyframes >= WINDOW + 3
    retired = [k for k in range(vo.n_keyframes) if k not in live]
    for k in retired:
        mk = vo._map.kfs[k]
        assert mk.retired and mk.image is None and mk.keyframe is None and mk.map_pixels is None
        assert sum(a.nbytes for a in _arrays(mk)) <= 256      # the 4x4 pose
    # read back: the state it had when it left the window (pose, scales, image, pyramid)
    for k in retired:
        image, kf = last[k]
        back = vo.keyframe(k)
        np.testing.assert_array_equal(back.T_world_kf, kf.T_world_kf)
        np.testing.assert_array_equal(back.primitives.log_scales, kf.primitives.log_scales)
        np.testing.assert_array_equal(back.points, kf.points)
        np.testing.assert_array_equal(back.pyramid.images[0], kf.pyramid.images[0])
        np.testing.assert_array_equal(vo.keyframe_image(k), image)
        assert back.median_depth == kf.median_depth == vo._map.kfs[k].median_depth


def test_processed_frames_hold_small_records_only(run):
    vo, _, _ = run
    for f in vo.frames:
        sizes = [a.nbytes for a in _arrays(f)]
        assert max(sizes) <= SMALL and sum(sizes) <= 4 * SMALL


def test_factor_groups_are_freed_when_they_leave_the_graph(run):
    """Only the groups in the window's smoother survive (those of the initialising
    SfM and of marginalised keyframes are freed)."""
    vo, _, before = run
    gc.collect()
    alive = [g for g in _groups() if g not in before]
    assert len(alive) == len(vo._port.backend.mapper._groups) > 0


def test_saved_clouds_equal_the_clouds_of_the_final_state(run, tmp_path):
    """Clouds of retired keyframes (read back from the store) are byte-identical to
    the clouds written from the objects they were when they left the window."""
    vo, last, _ = run
    paths = vo.save(tmp_path / "run")["clouds"]
    ref = write_keyframe_clouds(tmp_path / "ref", [(k, *last[k]) for k in vo.keyframes_with_depth()])
    assert len(paths) == len(ref) == len(vo.keyframes_with_depth()) >= WINDOW + 3
    for a, b in zip(paths, ref):
        assert a.read_bytes() == b.read_bytes()


def test_keyframe_store_round_trip_and_cleanup(run):
    vo, _, _ = run
    image, kf = vo.keyframe_image(0), vo.keyframe(0)
    store = KeyframeStore()
    assert store.folder is None
    store.put(3, image, kf.primitives)
    folder = store.folder
    img2, prims2 = store.get(3)
    np.testing.assert_array_equal(img2, image)
    np.testing.assert_array_equal(prims2.pixels, kf.primitives.pixels)
    with pytest.raises(KeyError):
        store.get(4)
    store.close()
    assert not folder.exists()


def test_rss_checkpoints_and_palindrome():
    rec = RssCheckpoints(every=2)
    for _ in range(5):
        rec.frame_done()
    rep = rec.report()
    assert list(rep["rss_mb"]) == ["2", "4"] and rep["rss_every_frames"] == 2
    assert rep["peak_rss_mb"] >= max(rep["rss_mb"].values()) * 0.99 > 0
    assert peak_rss_mb() >= current_rss_mb() * 0.99
    assert list(palindrome(3, 9)) == [0, 1, 2, 1, 0, 1, 2, 1, 0]
    rows = [{"frames": f, "m": m} for f, m in ((100, 5.0), (300, 10.0), (1300, 30.0))]
    assert growth_per_1000(rows, "m", warmup=300) == pytest.approx(20.0)
