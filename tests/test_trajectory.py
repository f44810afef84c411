"""spgeo.trajectory.Trajectory and its TUM + status files (spgeo.io.tum)."""
import numpy as np
import pytest

from spgeo.io.tum import read_tum, status_path_for
from spgeo.trajectory import STATUSES, FrameStatus, Trajectory


def _trajectory():
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, 0, 3] = np.arange(5)
    T[2] = np.nan                                   # a frame without a pose
    return Trajectory(np.arange(5) * 0.1, T, ["init", "ok", "lost", "keyframe", "ok"],
                      [0, 0, 0, 1, 0], [0, 0, -1, 0, 0], {"inliers": [1, 2, 3, 4, 5]})


def test_save_load_roundtrip(tmp_path):
    tr = _trajectory()
    path = tr.save(tmp_path / "t.txt", header=["test"])
    assert read_tum(path).poses.shape == (4, 4, 4)          # the NaN pose has no line
    back = Trajectory.load(path)
    assert back.status == tr.status and all(isinstance(s, FrameStatus) for s in back.status)
    np.testing.assert_array_equal(back.is_keyframe, tr.is_keyframe)
    np.testing.assert_array_equal(back.segment, tr.segment)
    assert back.columns == {"inliers": ["1", "2", "3", "4", "5"]}
    np.testing.assert_allclose(back.poses[[0, 1, 3, 4]], tr.poses[[0, 1, 3, 4]], atol=1e-9)
    assert np.isnan(back.poses[2]).all()
    kf = tr.save(tmp_path / "k.txt", keyframes_only=True, status_file=False)
    assert len(read_tum(kf)) == 1 and not status_path_for(kf).exists()


def test_properties_and_errors():
    tr = _trajectory()
    np.testing.assert_array_equal(tr.tracked, [True, True, False, True, True])
    assert tr.status_counts() == {"init": 1, "ok": 2, "keyframe": 1, "lost": 1,
                                  "relocalised": 0, "reinit": 0, "skipped": 0}
    assert set(tr.status_counts()) == set(STATUSES) and FrameStatus.OK == "ok"
    sub = tr.subset(tr.tracked)
    assert len(sub) == 4 and sub.columns["inliers"] == [1, 2, 4, 5]
    plain = Trajectory([0.0, 1.0], np.tile(np.eye(4), (2, 1, 1)))
    assert plain.status == [FrameStatus.OK] * 2 and not plain.is_keyframe.any()
    with pytest.raises(ValueError, match="unknown frame status 'tracked'"):
        Trajectory([0.0], np.eye(4)[None], ["tracked"])
    with pytest.raises(ValueError, match="2 timestamps for 1 poses"):
        Trajectory([0.0, 1.0], np.eye(4)[None])
    with pytest.raises(ValueError, match="'segment' has 1 values for 2 frames"):
        Trajectory([0.0, 1.0], np.tile(np.eye(4), (2, 1, 1)), segment=[0])


def test_trajectory_repr_is_one_bounded_line_with_the_key_numbers():
    """Issue 42: ``repr`` no longer dumps the arrays (13 KB for 300 frames)."""
    import numpy as np

    from spgeo.trajectory import Trajectory

    n = 300
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 0.01
    status = ["ok"] * n
    status[5] = "lost"
    kf = np.zeros(n, bool)
    kf[::10] = True
    text = repr(Trajectory(np.arange(n) / 30.0, poses, status, kf))
    assert "\n" not in text and len(text) < 200
    for part in ("300 frames", "30 keyframes", "t 0.000-9.967", "lost=1", "ok=299",
                 "1 segment(s)", "path 2.990"):
        assert part in text, (part, text)


def test_lost_frames_are_neither_saved_nor_scored(tmp_path):
    """Issue 53: a lost frame holds the last good pose; it has no line in the TUM
    file (its status stays in the status file) and ate_sim3 on the trajectory leaves it
    out, unless told to count every finite pose."""
    from spgeo.metrics.ate import ate_sim3

    n = 12
    stamps = np.arange(n) * 0.1
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n) * 0.2
    gt[:, 1, 3] = np.sin(np.arange(n))
    est = gt.copy()
    status = ["ok"] * n
    for i in (5, 6, 7):
        est[i], status[i] = est[4], "lost"
    traj = Trajectory(stamps, est, status)
    path = traj.save(tmp_path / "t.txt")
    assert len(np.loadtxt(path)) == n - 3
    back = Trajectory.load(path)
    assert [str(s) for s in back.status] == status and np.isnan(back.poses[5:8]).all()
    ate = ate_sim3(traj, (stamps, gt))
    assert ate.n_associated == n - 3 and ate.rmse < 1e-9
    assert ate_sim3(traj, (stamps, gt), tracked_only=False).rmse > 0.05
