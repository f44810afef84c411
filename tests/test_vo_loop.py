"""Loop closure inside the VO (issue 23, docs/design.md §5.2): the wiring of
:class:`spgeo.loop.LoopCloser` into :class:`spgeo.vo.Odometry`."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.loop import LoopClosureConfig, LoopCorrection
from spgeo.similarity import sim3, sim3_parts
from spgeo.vo import KeyframeDecisionConfig, Odometry, OdometryConfig, MappingConfig
from spgeo.vo.landmarks import LandmarkConfig

CAM = synthetic.default_camera(160, 120)


def _palindrome(n_unique, step, seed=0):
    """Frames 0 .. n-1 .. 0 of a subsampled synthetic trajectory (back to the start)."""
    scene = synthetic.SyntheticScene.generate(seed)
    poses = synthetic.make_trajectory(n_unique * step, seed)[::step]
    order = list(range(n_unique)) + list(range(n_unique - 2, -1, -1))
    views = {j: scene.render(CAM, poses[j]).rgb for j in range(n_unique)}
    return [views[j] for j in order], poses[order]


def _run(images, landmarks=True, mapping="inline", wait=False, **loop):
    """The VO over ``images`` with loop closure options ``loop`` (landmarks on, as by
    default, unless ``landmarks`` is False: the window-only map), mapped inline unless
    said (runs compared bit for bit)."""
    cfg = OdometryConfig(keyframe=KeyframeDecisionConfig(max_translation=0.03),
                         loop_closure=LoopClosureConfig(**loop),
                         landmarks=LandmarkConfig(enabled=landmarks),
                         mapping=MappingConfig(mode=mapping))
    vo = Odometry(CAM, cfg, make_frontend("classical", FrontEndConfig(working_size=(160, 120))),
                  wait_for_mapper=wait)
    for i, im in enumerate(images):
        vo.track(Frame(im, CAM, float(i)))
    vo.result()
    vo.close()      # a live run's worker stops; what it mapped stays readable
    return vo


@pytest.fixture(scope="module")
def short_run():
    images, _ = _palindrome(14, 3)
    return images, _run(images)


def test_loop_closure_is_off_by_default_and_reports_none(short_run):
    images, vo = short_run
    assert OdometryConfig().loop_closure.enabled is False
    assert vo.report()["loop_closures"] is None
    same = _run(images, enabled=False)
    assert np.array_equal(same.result().poses, vo.result().poses)


def test_landmark_seconds_are_their_own_stage(short_run):
    """The landmarks' time (associated before loop detection and the window update) is
    ``seconds_per_stage.landmarks`` in the report, at least the landmark map's own
    per-keyframe seconds, and no more than the run's total."""
    _, vo = short_run
    rep = vo.report()
    lm = rep["landmarks"]
    stage = rep["seconds_per_stage"]["landmarks"]
    assert lm["keyframes"] >= 2 and stage > 0
    assert stage >= 0.99 * lm["seconds_per_keyframe"] * (lm["keyframes"] - 1)
    assert stage < rep["seconds_total"]


def test_enabled_without_loop_changes_nothing(short_run):
    """Registering keyframes only reads them: with no loop (the run is shorter than
    the keyframe gap a loop needs) the trajectory is byte-identical."""
    images, vo = short_run
    on = _run(images, enabled=True)
    rep = on.report()["loop_closures"]
    assert rep["accepted"] == [] and rep["rejected"] >= 0
    assert np.array_equal(on.result().poses, vo.result().poses)


def test_a_correction_moves_keyframes_and_anchored_frames_together(short_run):
    """A similarity applied to every keyframe (as a loop correction) moves every
    frame of the trajectory by it: keyframes, supporting and tracked frames, and
    the depths by its scale (a retired keyframe when read back too)."""
    images, _ = short_run
    vo = _run(images)
    before = vo.result().poses
    W = sim3(synthetic.camera_rotation(0.3, 0.1, -0.2), np.array([0.5, -0.2, 0.1]), 1.7)
    ids = list(vo._map.order)
    moved = {k: W @ vo._map.kfs[k].T_world_kf for k in ids}
    T_new = {k: sim3(*sim3_parts(moved[k])[:2]) for k in ids}
    depth0 = [np.nanmedian(vo.keyframe(k).primitives.depth_map()) for k in ids]
    vo._map.apply_loop_correction(LoopCorrection(ids, T_new, {k: 1.7 for k in ids},
                                                  {k: W for k in ids}, None), vo._motion)
    after = vo.result().poses
    for i, f in enumerate(vo.frames):
        if str(f.status) in ("lost", "init"):
            continue
        R, t, _ = sim3_parts(W @ before[i])
        np.testing.assert_allclose(after[i][:3, :3], R, atol=1e-9)
        np.testing.assert_allclose(after[i][:3, 3], t, atol=1e-9)
    depth1 = [np.nanmedian(vo.keyframe(k).primitives.depth_map()) for k in ids]
    np.testing.assert_allclose(depth1, 1.7 * np.array(depth0), rtol=1e-9)


@pytest.fixture(scope="module")
def palindrome_runs():
    """The synthetic palindrome (80 views, every 3rd) on the window-only map (no
    landmarks: nothing remembers the start, a loop has to) with loop closure off and
    on, its true poses, and the default map (landmarks) with loop closure on."""
    images, poses = _palindrome(80, 3)
    return (_run(images, landmarks=False), _run(images, landmarks=False, enabled=True), poses,
            _run(images, enabled=True))


def _gap(vo):
    """Distance of the last camera centre from the first, over the largest
    distance of any centre from the first (0: back at the start)."""
    P = vo.result().poses
    return np.linalg.norm(P[-1, :3, 3] - P[0, :3, 3]) / np.linalg.norm(
        P[:, :3, 3] - P[0, :3, 3], axis=1).max()


@pytest.mark.slow
def test_palindrome_loops_are_true_revisits(palindrome_runs):
    """Every accepted loop of the window-only palindrome joins two frames whose true
    cameras see the same place (optical axes within 30 degrees), and its edge is the
    true relative pose: rotation within 1.5 degrees, translation direction within 15
    (measured values: docs/history.md, "Loop closure rebuilt")."""
    from spgeo.geometry import rotation_angle_deg

    _, on, poses, _ = palindrome_runs
    rep = on.report()["loop_closures"]
    assert rep["accepted"], rep
    for a in rep["accepted"]:
        Tq, Tc = poses[a["query_frame"]], poses[a["candidate_frame"]]
        assert np.degrees(np.arccos(np.clip(Tq[:3, 2] @ Tc[:3, 2], -1, 1))) < 30, a
        S = np.asarray(a["S_cand_query"])
        T_true = np.linalg.inv(Tc) @ Tq
        assert rotation_angle_deg((S[:3, :3] / a["scale"]).T @ T_true[:3, :3]) < 1.5, a
        cos = S[:3, 3] @ T_true[:3, 3] / np.linalg.norm(S[:3, 3]) / np.linalg.norm(T_true[:3, 3])
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 15, a


@pytest.mark.slow
def test_palindrome_ends_nearer_its_start_with_loop_closure(palindrome_runs):
    """On the window-only map, loop closure brings the palindrome's last pose nearer
    its first (measured gaps: docs/history.md, "Loop closure rebuilt")."""
    off, on, _, _ = palindrome_runs
    assert _gap(on) < _gap(off)


@pytest.mark.slow
def test_landmark_connected_return_needs_no_loop(palindrome_runs):
    """With landmarks (the default) the return re-observes the start's landmarks, so
    the keyframes there are connected to the query and are no loop candidates: no
    loop, the trajectory byte-identical to loop closure off, and the end gap small."""
    images, _ = _palindrome(80, 3)
    on = palindrome_runs[3]
    rep = on.report()["loop_closures"]
    assert rep["accepted"] == [] and rep["rejected"] == 0, rep
    off = _run(images)
    assert np.array_equal(on.result().poses, off.result().poses)
    assert _gap(on) < 0.05


@pytest.mark.slow
def test_loop_closure_runs_behind_the_mapping_port(palindrome_runs):
    """Loop closure is a stage of the back end (issue 37): through the mapping worker,
    applied before the next frame, the window-only palindrome gets the inline run's
    loops and trajectory bit for bit (the correction travels in the update and is
    applied to the map by ``KeyframeMap.apply_update``); mapped live (the default
    schedule) it accepts loops too and still ends nearer its start than without."""
    off, on, _, _ = palindrome_runs
    images, _ = _palindrome(80, 3)
    worker = _run(images, landmarks=False, mapping="live", wait=True, enabled=True)
    loops = lambda vo: [(a["query_keyframe"], a["candidate_keyframe"])   # noqa: E731
                        for a in vo.report()["loop_closures"]["accepted"]]
    assert loops(worker) == loops(on) and loops(on)
    assert np.array_equal(worker.result().poses, on.result().poses)
    live = _run(images, landmarks=False, mapping="live", enabled=True)
    assert loops(live) and _gap(live) < _gap(off)
