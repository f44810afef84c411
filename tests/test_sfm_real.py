"""Few-view SfM on real frames: spgeo vs ground truth, not to regress.

Bounds come from ``python -m spgeo.evaluation.sfm.real`` (measurements in
docs/results_parts/baselines.md); COLMAP on the same frames is tested in
test_colmap.py.
"""
from pathlib import Path

import numpy as np

from spgeo.evaluation.sfm.real import run_case, spgeo_estimator
import pytest


def _errors(comp, name):
    return [r["rotation_error_deg"] if r["available"] else np.nan
            for r in comp["vs_gt"][name]["rows"]]


@pytest.mark.slow
def test_tum_bundled_frames_rotation_error():
    """Bundled TUM fr1_desk frames 0 (ref), 4, 8 (always available)."""
    est = spgeo_estimator("classical")
    comp = run_case("tum_fr1_desk_0_4_8", None, {"spgeo": est})
    rot = np.asarray(_errors(comp, "spgeo"), float)
    assert est.last_result.status == "ok"
    assert np.all(rot < [1.6, 3.0]), rot


def test_icl_frames_flag_what_they_cannot_pose(shared_data):
    """ICL living room frames 1 (ref), 2, 3: frame 2 shares too few features with
    frame 1 (COLMAP cannot register it either): it must be flagged, not 'ok'."""
    est = spgeo_estimator("depth")
    comp = run_case("icl_lr_1_2_3", Path(shared_data), {"spgeo": est})
    res = est.last_result
    assert res.view_status[0] == "unverified" and res.status != "ok"
    rot = np.asarray(_errors(comp, "spgeo"), float)
    assert rot[1] < 1.5, rot
