"""spgeo.twoview.backends.ratio_matches: the pairs of OpenCV's brute-force k=2 matcher
in both directions (ratio test, mutual check), ties included, for SIFT and ORB."""
import cv2
import numpy as np
import pytest

from spgeo import synthetic
from spgeo.twoview import FeatureOptions, to_gray_uint8
from spgeo.twoview.backends import opencv_features, ratio_matches


def _knn_reference(d1, d2, options):
    """The matching written with cv2.BFMatcher.knnMatch (k=2) both ways."""
    norm = cv2.NORM_L2 if options.features == "sift" else cv2.NORM_HAMMING
    bf = cv2.BFMatcher(norm, crossCheck=False)

    def one_way(a, b):
        return {m.queryIdx: m.trainIdx for m, n in bf.knnMatch(a, b, k=2)
                if m.distance < options.ratio * n.distance}

    fwd = one_way(d1, d2)
    if options.cross_check:
        bwd = one_way(d2, d1)
        fwd = {i: j for i, j in fwd.items() if bwd.get(j) == i}
    return np.array(sorted(fwd.items()), dtype=np.int64).reshape(-1, 2)


def _scene_descriptors(options):
    cam = synthetic.default_camera(320, 240)
    scene = synthetic.SyntheticScene.generate(3)
    poses = synthetic.make_trajectory(6, 3)[::3]
    return [opencv_features(to_gray_uint8(scene.render(cam, T).rgb), options)[1] for T in poses]


@pytest.mark.parametrize("features", ["sift", "orb"])
@pytest.mark.parametrize("cross_check", [True, False])
def test_ratio_matches_equal_the_knn_matcher_with_ties(features, cross_check):
    opts = FeatureOptions(features=features, max_features=500, cross_check=cross_check)
    descs = [d for d in _scene_descriptors(opts) if d is not None and len(d) > 10]
    assert len(descs) >= 2
    a, b = descs[0], descs[1]
    tied = np.concatenate([b, b[:20], b[:2]])      # exact duplicates: equal distances
    cases = [(a, b), (b, a), (a[::3], tied), (tied, a[::3]), (a, a)]
    n = 0
    for d1, d2 in cases:
        got = ratio_matches(d1, d2, opts)
        ref = _knn_reference(d1, d2, opts)
        assert got.dtype == np.int64 and got.shape[1] == 2
        np.testing.assert_array_equal(got, ref)
        n += len(ref)
    assert n > 0


def test_ratio_matches_of_too_few_descriptors_are_empty():
    opts = FeatureOptions()
    d = np.random.default_rng(0).random((5, 128)).astype(np.float32)
    for d1, d2 in ((None, d), (d, None), (d[:1], d), (d, d[:1])):
        assert ratio_matches(d1, d2, opts).shape == (0, 2)
