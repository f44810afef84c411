"""Shared test set-up: BLAS threads, ``tests/`` on ``sys.path``, the ``slow`` marker.

``python3 -m pytest -q -m "not slow" tests`` runs the fast tier; CI runs everything.
"""
import os
import sys
from pathlib import Path

import pytest

# one BLAS thread: deterministic timings and results on the 2-core CI machine
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))


def shared_data_dir() -> Path:
    """``../shared/data`` beside the checkout, or ``$SPGEO_SHARED_DATA``."""
    env = os.environ.get("SPGEO_SHARED_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"shared sample data not found at {path}")
    return path


# ------------------------------------------------------------------ the ``slow`` marker
# Chosen by measuring ``python3 -m pytest -q --durations=0 tests``: a test is slow when its
# call, or the set-up of a module-scoped fixture it requests, takes more than about 1.5 s.
# A test that requests a slow fixture is slow too (else the fixture's cost moves to it).
SLOW_FILES = {"test_notebooks.py", "test_demo.py"}
SLOW_FIXTURES = {
    "test_completion.py": {"synthetic_results"},
    "test_demo_vo.py": {"vo_demo"},
    "test_odometry.py": {"run", "run_frequent_kf"},
    "test_rerun_logger.py": {"logged"},
    "test_vo_cli.py": {"depth_run"},
    "test_vo_evaluation.py": {"synthetic_sequence"},
    "test_vo_fast_motion.py": {"frames"},
    "test_vo_references.py": {"colmap_result"},
}
SLOW_TESTS = {
    "test_atomic_outputs.py": {"test_sfm_failure_leaves_previous_output_byte_for_byte",
                               "test_sfm_rerun_replaces_the_previous_run"},
    "test_colmap.py": {"test_colmap_fewview_paths_uint8_deterministic",
                       "test_colmap_two_view_fallback"},
    "test_eval_jobs.py": {"test_ray_gives_the_sequential_numbers",
                          "test_vo_synthetic_cli_error_row"},
    "test_odometry.py": {"test_classical_planar_monocular_accuracy",
                         "test_fixed_lag_marginalises_old_keyframes",
                         "test_mapping_failure_restarts_the_window",
                         "test_reinitialisation_after_a_long_loss"},
    "test_rerun_logger.py": {"test_rerun_is_not_imported_without_the_option",
                             "test_completion_and_sfm_logging"},
    "test_scannet_protocol.py": {"test_runner_end_to_end"},
    "test_sfm.py": {"test_cli_writes_documented_outputs", "test_depth_frontend_accuracy",
                    "test_planar_model_classical_frontend",
                    "test_unconstrained_primitives_are_flagged_not_reported"},
    "test_sfm_ablation.py": {"test_tum_classical_planar_row"},
    "test_sfm_real.py": {"test_tum_bundled_frames_rotation_error"},
    "test_trajectory_plots.py": {"test_vo_run_save_writes_the_plots"},
    "test_vo_frontier.py": {"test_tiny_synthetic_grid"},
    "test_vo_evaluation.py": {"test_feature_vo_7scenes"},
    "test_vo_references.py": {"test_compare_vo_feature_and_colmap"},
}


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow: end-to-end test (> ~1.5 s); deselect with -m \"not slow\"")


def is_slow(item) -> bool:
    name = item.path.name
    return (name in SLOW_FILES
            or item.originalname in SLOW_TESTS.get(name, ())
            or not SLOW_FIXTURES.get(name, set()).isdisjoint(item.fixturenames))


def pytest_collection_modifyitems(config, items):
    for item in items:
        if is_slow(item):
            item.add_marker(pytest.mark.slow)


# ------------------------------------------------------------------ small input files
def write_synthetic_views(folder: Path, seed: int, n: int = 3, size=(64, 48)):
    """``n`` views of synthetic room ``seed`` as PNGs ``folder/f{i}.png`` (every 4th
    pose of its hand-held trajectory), ``folder/sparse.npy`` (metres, every 5th
    pixel of view 0's depth, 0 = missing) and ``folder/camera.json``; returns the
    camera and the image paths (command-line inputs for the bad-input tests)."""
    import json

    import cv2
    import numpy as np

    from spgeo import synthetic

    cam = synthetic.default_camera(*size)
    scene = synthetic.SyntheticScene.generate(seed)
    paths = []
    for i, T in enumerate(synthetic.make_trajectory(4 * n - 3, seed)[::4]):
        view = scene.render(cam, T)
        paths.append(folder / f"f{i}.png")
        cv2.imwrite(str(paths[-1]), cv2.cvtColor(np.round(view.rgb * 255).astype(np.uint8),
                                                 cv2.COLOR_RGB2BGR))
        if i == 0:
            sparse = np.zeros_like(view.depth)
            sparse[::5, ::5] = np.nan_to_num(view.depth[::5, ::5])
            np.save(folder / "sparse.npy", sparse)
    (folder / "camera.json").write_text(json.dumps(
        {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width,
         "height": cam.height}))
    return cam, paths
