"""Sparse-point regimes of the completion benchmarks (issue 39):
:func:`spgeo.completion.sparse_points.track_sparse_depth`."""
import numpy as np
import pytest

from spgeo.completion.sparse_points import _track_lifetimes, track_sparse_depth


def _textured_frames(n: int = 4, shift: int = 2, seed: int = 0):
    """``n`` grey 120x160 frames of a scene moving ``shift`` px right per frame:
    the left half textured (smoothed noise), the right half flat."""
    import cv2

    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (120, 220)), (0, 0), 1.5)
    tex[:, 110:] = 128.0
    return [np.clip(tex[:, 40 - i * shift:200 - i * shift], 0, 255).astype(np.uint8)
            for i in range(n)]


def test_tracked_points_lie_where_texture_is_trackable():
    """The kept points are distinct pixels with depth, all on the textured
    half (the flat half has no corner), their depths unchanged; the same
    arguments give the same map; without motion all are kept too."""
    frames = _textured_frames()
    depth = np.full((120, 160), 2.0)
    depth[:10] = 0.0                                   # no depth on the top rows
    sp = track_sparse_depth(frames, depth, 40)
    v, u = np.nonzero(sp)
    assert u.size == 40 and np.all(sp[v, u] == 2.0)
    assert v.min() >= 10 and u.max() < 70 + 6          # textured half (x < 70 in frame 0) only
    np.testing.assert_array_equal(sp, track_sparse_depth(frames, depth, 40))
    assert np.count_nonzero(track_sparse_depth(frames[:1], depth, 40)) == 40


def test_lost_tracks_rank_after_kept_ones():
    """Tracks through a moving scene live through every frame, into an
    unrelated frame they die; when fewer survive than asked, the set is
    completed by the strongest lost ones; bad input is refused."""
    import cv2

    frames = _textured_frames(4)
    noise = np.random.default_rng(5).uniform(0, 255, (120, 160)).astype(np.uint8)
    depth = np.full((120, 160), 1.5)
    pts = cv2.goodFeaturesToTrack(frames[0], 40, 0.01, 10.0).reshape(-1, 2)
    pts = pts[(pts[:, 0] > 15) & (pts[:, 0] < 60)]      # inside the image after the motion
    assert np.mean(_track_lifetimes(frames, pts, 1.0) == 3) > 0.9
    assert np.mean(_track_lifetimes([frames[0], noise], pts, 1.0) == 0) > 0.8
    sp = track_sparse_depth([frames[0], noise], depth, 30)
    assert np.count_nonzero(sp) == 30
    with pytest.raises(ValueError, match="differ"):
        track_sparse_depth([frames[0], noise[:50]], depth, 30)
    with pytest.raises(ValueError, match="no corner"):
        track_sparse_depth(frames, np.zeros((120, 160)), 30)
    with pytest.raises(ValueError, match="n_points"):
        track_sparse_depth(frames, depth, 0)
