"""KITTI odometry's relative errors (issue 38, :mod:`spgeo.evaluation.kitti_metrics`)
against hand-computed examples of the devkit's definition."""
import numpy as np
import pytest

from spgeo.evaluation.kitti_metrics import (KITTI_LENGTHS, kitti_relative_errors,
                                             segment_lengths)


def _straight(n, step=1.0):
    """(n, 4, 4) camera-to-world poses driving straight along z, ``step`` per frame."""
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 2, 3] = step * np.arange(n)
    return P


def _roll(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_translation_error_is_the_devkits():
    """A 10 % long estimate on a 1 m-per-frame road: a 5 m segment ends at the first
    frame beyond 5 m (6 m on), so its error is 0.6 m over the nominal 5 m: 12 %; a 10 m
    segment 1.1 m over 10 m: 11 %.  First frames every 10th (0, 10 of 21 frames)."""
    gt = _straight(21)
    est = gt.copy()
    est[:, 2, 3] *= 1.1
    res = kitti_relative_errors(est, gt, lengths=(5.0, 10.0))
    assert res.per_length[5.0][2] == 2 and res.per_length[10.0][2] == 1
    np.testing.assert_allclose(res.per_length[5.0][0], 12.0)
    np.testing.assert_allclose(res.per_length[10.0][0], 11.0)
    np.testing.assert_allclose(res.t_rel_pct, (12 + 12 + 11) / 3)
    assert res.r_rel_deg_per_100m == pytest.approx(0.0, abs=1e-9) and res.n_segments == 3
    # the monocular case: the same path at half scale, scaled back by its Sim(3) scale
    half = gt.copy()
    half[:, 2, 3] *= 0.5
    assert kitti_relative_errors(half, gt, scale=2.0, lengths=(5.0,)).t_rel_pct < 1e-9


def test_rotation_error_is_the_devkits():
    """An estimate that rolls 0.01 rad per frame about the direction of travel: over a
    5 m segment (6 frames) the error is 0.06 rad over 5 m and no translation error."""
    gt = _straight(21)
    est = gt.copy()
    for i in range(len(est)):
        est[i, :3, :3] = _roll(0.01 * i)
    res = kitti_relative_errors(est, gt, lengths=(5.0,))
    np.testing.assert_allclose(res.r_rel_deg_per_100m, np.degrees(0.06) / 5 * 100)
    assert res.t_rel_pct == pytest.approx(0.0, abs=1e-9)


def test_lengths_lost_frames_and_bad_input():
    assert segment_lengths(850.0) == KITTI_LENGTHS and segment_lengths(250.0) == (100.0, 200.0)
    assert segment_lengths(52.0) == (5.2, 10.4, 15.6, 20.8, 26.0, 31.2, 36.4, 41.6)
    gt = _straight(21)
    est = gt.copy()
    est[6] = np.nan                   # the segment 0 -> 6 is left out, 10 -> 16 stays
    assert kitti_relative_errors(est, gt, lengths=(5.0,)).n_segments == 1
    with pytest.raises(ValueError, match="no segment"):
        kitti_relative_errors(gt, gt, lengths=(50.0,))
    with pytest.raises(ValueError, match="shape"):
        kitti_relative_errors(gt[:5], gt)
    with pytest.raises(ValueError, match="scale"):
        kitti_relative_errors(gt, gt, scale=0.0)
