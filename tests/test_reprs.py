"""Issue 42: every result and state object a user holds prints as one bounded line
with its key numbers (never its arrays), and the notebook tables hold the same."""
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.vo import KeyframeDecisionConfig, OdometryConfig, MappingConfig

#: longest repr accepted (a few hundred characters, one line)
MAX_REPR = 400


def _bounded(obj) -> str:
    text = repr(obj)
    assert len(text) <= MAX_REPR and "\n" not in text, text
    assert "array(" not in text and "[[" not in text, text
    return text


@pytest.fixture(scope="module")
def vo_run():
    cam = synthetic.default_camera(160, 120)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(0), cam,
                                     synthetic.make_trajectory(40, 0)[::2])
    seen = []
    run = run_odometry(frames, VORunConfig(odometry=OdometryConfig(resolution=(160, 120), keyframe=KeyframeDecisionConfig(max_translation=0.05)),
                                           frontend="depth", progress=False),
                       on_frame=lambda frame, result, odo: seen.append(result))
    return run, seen


def test_frame():
    cam = synthetic.default_camera(160, 120)
    frame = synthetic.render_frames(synthetic.SyntheticScene.generate(0), cam,
                                    synthetic.make_trajectory(2, 0))[1]
    text = _bounded(frame)
    assert "160x120 RGB float32, depth, ground truth" in text and f"t={frame.timestamp:.3f}" in text
    assert f"fx={cam.fx:.2f}" in text


def test_vo_objects(vo_run):
    run, results = vo_run
    last = results[-1]
    text = _bounded(last)
    assert text.startswith(f"FrameResult(#{last.index}, ") and str(last.status) in text
    x = last.T_world_cam[0, 3]
    assert f"[{x:.3f}, " in text
    assert _bounded(last.track).startswith(f"TrackResult({last.track.status}")
    assert f"relative cost {last.track.relative_cost:.3f}" in repr(last.track)
    assert str(last.status) == "ok" and run.odometry.n_keyframes >= 2
    kf = run.odometry.keyframe(run.odometry.n_keyframes - 1)
    assert f"{len(kf.primitives)} primitives" in _bounded(kf)
    text = _bounded(run.odometry)
    assert f"{len(results)} frames, {run.odometry.n_keyframes} keyframes" in text
    text = _bounded(run)
    assert text.startswith(f"VORun({run.status}, {run.n_frames} frames (0 skipped, ")
    assert "with ground truth, positions in metres" in text       # the depth front-end
    fused = run.fuse()
    assert f"{fused.n_views} views, {len(fused.vertices)} vertices" in _bounded(fused)
    traj = run.trajectory()
    text = _bounded(traj)
    assert f"Trajectory({len(traj)} frames, {int(traj.is_keyframe.sum())} keyframes" in text
    html = traj._repr_html_()
    assert "<table>" in html and f"<td style='text-align:left'>{len(traj)}</td>" in html
    assert all(v in html for v in traj.overview().values())
    assert traj.units == "metres" and text.endswith(" metres)")     # the depth front-end
    assert traj.subset([0, 1]).units == traj.with_skipped([1e6]).units == "metres"


def test_completion_and_sfm_results(room_completion_and_sfm):
    comp = room_completion_and_sfm.completion
    text = _bounded(comp)
    assert comp.summary() in text and "depth 160x120" in text
    assert f"{comp.depth.max():.2f} m" in text
    _bounded(comp.primitives)
    if comp.choice is not None:
        assert _bounded(comp.choice).startswith("HeldoutChoice(")
    sfm = room_completion_and_sfm.sfm
    text = _bounded(sfm)
    assert text.startswith(f"SfMResult({sfm.status}, {len(sfm.primitives)} primitives")
    assert f"{len(sfm.view_status)} views" in text
    html = sfm._repr_html_()
    assert html.count("<tr>") == 1 + len(sfm.view_status)
    baseline = f"{np.linalg.norm(sfm.T_ref_view[0][:3, 3]):.3f}"
    assert baseline in text and baseline in html


def test_two_view_result():
    from spgeo.twoview import estimate_relative_pose

    cam = synthetic.default_camera(160, 120)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(1), cam,
                                     synthetic.make_trajectory(9, 1)[::8])
    res = estimate_relative_pose(frames[0].image, frames[1].image, cam)
    text = _bounded(res)
    assert text.startswith(f"TwoViewResult({res.status}, {res.num_inliers}/{res.num_matches}")


def test_empty_trajectory_and_odometry():
    from spgeo.frontend import make_frontend
    from spgeo.trajectory import Trajectory
    from spgeo.vo import Odometry

    empty = Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    assert _bounded(empty).startswith("Trajectory(0 frames, 0 keyframes, t -, status {}")
    assert "<table>" in empty._repr_html_() and empty.finite.shape == (0,)
    cam = synthetic.default_camera(160, 120)
    with Odometry(cam, OdometryConfig(mapping=MappingConfig(mode="inline")),
                  make_frontend("classical")) as vo:
        assert _bounded(vo).startswith("Odometry(160x120, 0 frames, 0 keyframes")
