"""Mapping off the tracking path (issue 32, :mod:`spgeo.vo.mapping_worker`): the
worker's protocol gives the inline numbers bit for bit when the tracker waits,
live mapping stays accurate and says what it did, failures are clear errors."""
import dataclasses

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_sim3
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.validation import InputError
from spgeo.vo import KeyframeDecisionConfig, Odometry, OdometryConfig
from spgeo.vo.odometry import MAX_LEAD_FRAMES
from spgeo.vo.mapping_worker import MappingJob, MappingWorker, MappingWorkerError

CAM = synthetic.default_camera(160, 120)
N_FRAMES = 60


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    poses = synthetic.make_trajectory(N_FRAMES, 0)
    return synthetic.render_frames(scene, CAM, poses, supersample=2)


def _run(frames, mapping, wait=False):
    fe = make_frontend("classical", FrontEndConfig(working_size=(160, 120)))
    cfg = OdometryConfig(mapping=mapping, keyframe=KeyframeDecisionConfig(max_translation=0.1))
    with Odometry(CAM, cfg, fe, wait_for_mapper=wait) as vo:
        for f in frames:
            vo.track(f)
        res, rep = vo.result(), vo.report()
        kfs = vo.keyframes
    return res, rep, kfs


@pytest.fixture(scope="module")
def inline(frames):
    return _run(frames, "inline")


def _ate(frames, res):
    gt = (np.array([f.timestamp for f in frames]), np.array([f.T_world_cam for f in frames]))
    return ate_sim3(res, gt).rmse


def test_waiting_worker_gives_the_inline_numbers(frames, inline):
    """Every pose, status and keyframe depth equal, bit for bit: the worker's copies
    and the caller's stay equal through the update protocol (landmarks on)."""
    res, rep, kfs = _run(frames, "live", wait=True)
    res0, rep0, kfs0 = inline
    assert rep0["n_keyframes"] >= 4 and rep["n_keyframes"] == rep0["n_keyframes"]
    assert np.array_equal(res.poses, res0.poses)
    assert list(res.statuses) == list(res0.statuses)
    for a, b in zip(kfs, kfs0):
        assert np.array_equal(a.primitives.log_scales, b.primitives.log_scales)
        assert np.array_equal(a.T_world_kf, b.T_world_kf)
    drop = lambda reps: [{k: v for k, v in r.items() if k != "seconds"} for r in reps]  # noqa: E731
    assert drop(rep["mapping"]) == drop(rep0["mapping"])
    assert rep["landmarks"]["landmarks"] == rep0["landmarks"]["landmarks"]
    assert rep["mapping_worker"]["frames_tracked_against_older_map"] == 0
    assert rep["mapping_worker"]["updates"] == rep0["n_keyframes"] - 1


def test_live_mapping_is_as_accurate_and_reports_itself(frames, inline):
    """Tracking goes on while the worker solves: the trajectory stays within the
    inline one's accuracy (small tolerance: live timing varies), and report.json
    says how many frames were tracked against a map whose update was pending (at most
    MAX_LEAD_FRAMES after each new keyframe)."""
    res, rep, _ = _run(frames, "live")
    ate0, ate = _ate(frames, inline[0]), _ate(frames, res)
    assert ate < 1.5 * ate0 + 0.01, (ate, ate0)
    live = rep["mapping_worker"]
    assert rep["mapping_mode"] == "live"
    assert live["updates"] == rep["n_keyframes"] - 1
    assert 0 <= live["frames_tracked_against_older_map"] < N_FRAMES
    # the tracker never runs more than MAX_LEAD_FRAMES ahead of its map
    assert 0 <= live["latency_frames_max"] <= MAX_LEAD_FRAMES and live["worker_peak_rss_mib"] > 0
    assert set(live["worker_seconds"]) >= {"landmarks", "mapping"}


def test_live_smoother_is_out_of_reach_and_config_checked():
    fe = make_frontend("classical", FrontEndConfig(working_size=(160, 120)))
    with Odometry(CAM, OdometryConfig(), fe) as vo:
        with pytest.raises(RuntimeError, match="mapping='inline'"):
            vo.smoother_estimate()
    with pytest.raises(InputError, match="mapping"):
        OdometryConfig(mapping="threads")
    # loop closure moves the map the update reads: its back end stays inline
    cfg = OdometryConfig(loop_closure=dataclasses.replace(OdometryConfig().loop_closure,
                                                          enabled=True))
    assert not cfg.mapping_in_worker and OdometryConfig().mapping_in_worker


def test_worker_failure_is_a_clear_error_and_close_stops_it():
    worker = MappingWorker(CAM, OdometryConfig())
    worker.submit(MappingJob(window=[3, 4], keyframes=[], candidates=[], segment=0))
    with pytest.raises(MappingWorkerError, match=r"without keyframes \[3, 4\]"):
        worker.receive()
    proc = worker._proc
    worker.close()
    assert proc.poll() is not None
    worker.close()     # idempotent
