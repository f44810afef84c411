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
# A test is marked at the test (``@pytest.mark.slow``, or ``pytestmark`` for a whole module)
# when its call, or the set-up of a module-scoped fixture it requests, takes more than about
# 1.5 s (``python3 -m pytest -q --durations=0 tests``); a test that requests a slow fixture is
# marked too, else the fixture's cost moves into the fast tier.
def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow: end-to-end test (> ~1.5 s); deselect with -m \"not slow\"")


# ------------------------------------------------------------------ shared synthetic cases
@pytest.fixture(scope="session")
def room_completion_and_sfm():
    """Synthetic room 1 at 160x120: three views (every 4th pose of its hand-held
    trajectory), view 0's depth every 12th pixel as sparse depth, and the classical
    front-end's ``complete_depth`` and ``few_view_sfm`` (view 0 the reference) on them;
    a namespace ``camera, frames, sparse, completion, sfm``."""
    from types import SimpleNamespace

    import numpy as np

    from spgeo import synthetic
    from spgeo.completion import complete_depth
    from spgeo.sfm import few_view_sfm

    cam = synthetic.default_camera(160, 120)
    frames = synthetic.render_frames(synthetic.SyntheticScene.generate(1), cam,
                                     synthetic.make_trajectory(9, 1)[::4])
    f = frames[0]
    sparse = np.zeros_like(f.depth)
    sparse[::12, ::12] = f.depth[::12, ::12]
    return SimpleNamespace(
        camera=cam, frames=frames, sparse=sparse,
        completion=complete_depth(f.image, sparse, cam, "classical"),
        sfm=few_view_sfm(f.image, [g.image for g in frames[1:]], cam, "classical"))


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
