"""One speed for library and CLI (issue 25): ``Odometry`` given full-size frames
works at the same processing size as ``spgeo vo`` and gives the same trajectory."""
import numpy as np
import pytest

from spgeo.apps.vo_run import VORunConfig, run_odometry
from spgeo.frame import Frame
from spgeo.frontend import make_frontend
from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence
from spgeo.validation import InputError
from spgeo.vo import Odometry, OdometryConfig

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def frames():
    """30 frames of 400x300 (more pixels than the default target: processed at 320x240)."""
    return synthetic_sequence(SyntheticVOConfig(n_frames=30, seed=1, size=(400, 300),
                                                rotation=None, supersample=1))


def test_library_loop_equals_the_runner(frames):
    cam = frames[0].camera
    vo = Odometry(cam, OdometryConfig(), make_frontend("classical"))
    assert vo.input_camera.size == (400, 300) and vo.camera.size == (320, 240)
    for f in frames:
        vo.track(Frame(f.image, cam, f.timestamp))
    lib = vo.result()
    run = run_odometry(frames, VORunConfig(progress=False))
    cli = run.result()
    assert run.odometry.camera.size == (320, 240)
    assert lib.statuses == cli.statuses
    np.testing.assert_allclose(lib.poses, cli.poses, atol=1e-9)


def test_frames_of_another_size_are_refused(frames):
    cam = frames[0].camera
    vo = Odometry(cam, OdometryConfig(), make_frontend("classical"))
    bad = Frame(np.zeros((120, 160, 3), np.float32), cam.resized(160, 120), 0.0)
    with pytest.raises(InputError, match="input camera"):
        vo.track(bad)
