"""Bad or degenerate inputs to the VO, few-view SfM and ATE (issue 15): a keyframe pair
without parallax never initialises a map, timestamps must increase, a flagged SfM result
reports no depth the views do not support, NaN ground truth is counted and warned about,
and degenerate runs keep stderr free of gtsam dumps and numpy RuntimeWarnings.  Each case
asserts the error class and a message fragment, a flag, or exact counts (80x60 frames)."""
import json
import logging
import sys
import warnings

import numpy as np
import pytest

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_per_frame_and_keyframes, ate_sim3
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.sfm import SfMConfig, few_view_sfm
from spgeo.graph.builders import gtsam_error_line
from spgeo.sfm.init import triangulate_depths
from spgeo.validation import InputError
from spgeo.vo import InitConfig, KeyframeDecisionConfig, Odometry, OdometryConfig, ScaleCheckConfig
from spgeo.vo.initialisation import append_bounded

W, H = 80, 60
CAM = synthetic.default_camera(W, H)
QUICK = dict(init=InitConfig(max_gap=4, min_gap=1))      # SfM attempts after a few frames


@pytest.fixture(scope="module")
def frames():
    scene = synthetic.SyntheticScene.generate(0)
    return synthetic.render_frames(scene, CAM, synthetic.make_trajectory(12, 0), supersample=1)


def frontend():
    return make_frontend("classical", FrontEndConfig(working_size=(W, H)))


def run_vo(images, config=OdometryConfig(**QUICK)):
    vo = Odometry(CAM, config, frontend())
    for i, im in enumerate(images):
        vo.track(Frame(im, CAM, float(i)))
    return vo


# ============================================================ zero-parallax initialisation
def test_repeated_frame_never_initialises(frames):
    """One frame repeated: tracked (INIT) but never a map; every SfM attempt refused."""
    vo = run_vo([frames[0].image] * 12)
    rep = vo.report()
    assert rep["status_counts"]["keyframe"] == 1 and rep["status_counts"]["init"] == 11
    assert rep["status_counts"]["ok"] == 0 and rep["n_keyframes"] == 1
    assert rep["initialised"] is False and not vo.initialised
    assert "no map initialised" in rep["init_failure"] and "low_parallax" in rep["init_failure"]
    assert [s["frame"] for s in rep["sfm"]] == [4, 6, 9]         # spaced retries
    assert not any(s["accepted"] for s in rep["sfm"])
    assert vo.result().is_keyframe.tolist() == [True] + [False] * 11


def test_repeated_frame_default_config_one_attempt(frames):
    """Default config, 35 copies: keyframe 1 is tried at init.max_gap (30), refused, and not
    retried before gap 45; frames never 'ok'."""
    vo = run_vo([frames[0].image] * 35, OdometryConfig())
    rep = vo.report()
    assert [s["frame"] for s in rep["sfm"]] == [30]
    assert rep["sfm"][0]["status"] == "low_parallax" and rep["sfm"][0]["accepted"] is False
    assert rep["n_keyframes"] == 1 and rep["status_counts"]["ok"] == 0


def test_blank_frames_never_initialise():
    """Untracked frames (blank): the SfM alone decides and must be 'ok' with parallax."""
    vo = run_vo([np.zeros((H, W, 3), np.float32)] * 8)
    rep = vo.report()
    assert rep["n_keyframes"] == 1 and rep["status_counts"]["lost"] == 7
    assert rep["initialised"] is False and "not tracked" in rep["init_failure"]


def test_uninitialised_run_writes_no_keyframe_cloud(frames, tmp_path):
    vo = run_vo([frames[0].image] * 6)
    paths = vo.save(tmp_path / "run")
    assert paths["clouds"] == [] and vo.keyframes_with_depth() == []
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["initialised"] is False and rep["init_failure"].startswith("frame 4:")


def test_moving_sequence_still_initialises(frames):
    vo = run_vo([f.image for f in frames])
    rep = vo.report()
    assert rep["initialised"] is True and rep["init_failure"] is None
    assert rep["n_keyframes"] >= 2 and rep["status_counts"]["ok"] >= 1
    assert rep["sfm"][-1]["accepted"] is True and vo.keyframes_with_depth() == [0, 1, 2][
        :rep["n_keyframes"]]


def test_waiting_run_says_why(frames):
    vo = run_vo([frames[0].image] * 3, OdometryConfig())
    assert vo.init_failure.startswith("waiting for keyframe 1: 2 frames after keyframe 0")


# ============================================================ Odometry.track input
@pytest.mark.parametrize("stamps,fragment", [
    ((0.0, 1.0, 0.5), "timestamp 0.5 is not after the previous frame's 1.0"),
    ((0.0, 1.0, 1.0), "timestamp 1.0 is not after the previous frame's 1.0"),
    ((0.0, float("nan")), "timestamp nan is not a finite number"),
    ((0.0, float("inf")), "timestamp inf is not a finite number"),
], ids=["backwards", "repeated", "nan", "inf"])
def test_track_rejects_bad_timestamps(frames, stamps, fragment):
    vo = Odometry(CAM, OdometryConfig(**QUICK), frontend())
    for t in stamps[:-1]:
        vo.track(Frame(frames[0].image, CAM, t))
    with pytest.raises(InputError, match=fragment):
        vo.track(Frame(frames[1].image, CAM, stamps[-1], name="f"))
    assert len(vo.frames) == len(stamps) - 1          # the bad frame was not processed


def test_track_rejects_wrong_image_shape(frames):
    vo = Odometry(CAM, OdometryConfig(), frontend())
    small = synthetic.default_camera(40, 30)
    with pytest.raises(InputError, match=r"image of shape \(30, 40, 3\) does not match the "
                                         r"input camera's \(H, W\) \(60, 80\)"):
        vo.track(Frame(np.zeros((30, 40, 3), np.float32), small, 0.0))


def test_track_rejects_nan_image(frames):
    img = frames[0].image.copy()
    img[3, 4] = np.nan
    vo = Odometry(CAM, OdometryConfig(), frontend())
    with pytest.raises(InputError, match=r"frame 0 \('nanimg'\) image contains NaN or inf"):
        vo.track(Frame(img, CAM, 0.0, name="nanimg"))


def test_track_rejects_a_bare_array(frames):
    vo = Odometry(CAM, OdometryConfig(), frontend())
    with pytest.raises(TypeError, match="expects a spgeo.frame.Frame, got ndarray"):
        vo.track(frames[0].image)


@pytest.mark.parametrize("kwargs,fragment", [
    ({"init": InitConfig(min_parallax=float("nan"))}, "init.min_parallax must be >= 0, got nan"),
    ({"keyframe": KeyframeDecisionConfig(max_rotation_deg=0.0)},
     "keyframe.max_rotation_deg must be > 0"),
    ({"init": InitConfig(max_gap=0)}, "init.max_gap"),
    ({"window": 1}, "window must be >= 2"),
    ({"init": InitConfig(method="magic")}, "init.method must be one of"),
    ({"scale_check": ScaleCheckConfig(max_change=0.0)}, "scale_check.max_change must be > 0"),
    ({"scale_check": ScaleCheckConfig(min_parallax=-1.0)}, "scale_check.min_parallax must be >= 0"),
], ids=["nan_parallax", "zero_rotation", "max_gap_0", "window_1",
        "init_method", "scale_check_change_0", "scale_check_parallax_neg"])
def test_odometry_config_rejects(kwargs, fragment):
    with pytest.raises(InputError, match=fragment.replace("[", r"\[").replace("]", r"\]")):
        OdometryConfig(**kwargs)


# ============================================================ SfM honesty
def test_flagged_sfm_without_parallax_has_no_depth(frames):
    res = few_view_sfm(frames[0].image, [frames[0].image.copy()], CAM, frontend(),
                       SfMConfig(levels=2, marginals=False))
    assert res.status == "low_parallax"
    assert not np.any(np.isfinite(res.depth))
    assert res.unconstrained.tolist() == list(range(len(res.primitives)))
    assert len(res.point_cloud().points) == 0 and len(res.supported_primitives) == 0


def test_flagged_sfm_with_failed_marginals_has_no_depth(frames):
    """A blank view: an indeterminate system (marginals fail) and a flagged status."""
    res = few_view_sfm(frames[0].image, [np.zeros((H, W, 3), np.float32)], CAM, frontend(),
                       SfMConfig(levels=2))
    assert res.status != "ok"
    assert res.report["marginals_error"].startswith("Indeterminate linear system")
    assert "\n" not in res.report["marginals_error"]
    assert not np.any(np.isfinite(res.depth)) and len(res.point_cloud().points) == 0


def test_ok_sfm_cloud_matches_the_depth(frames):
    res = few_view_sfm(frames[0].image, [frames[8].image], CAM, frontend(), SfMConfig(levels=2))
    assert res.status == "ok" and res.unconstrained.size > 0
    cloud = res.point_cloud(frames[0].image)
    kept = np.setdiff1d(np.arange(len(res.primitives)), res.unconstrained)
    assert len(cloud.points) == int(res.primitives.sizes[kept].sum())
    assert np.all(np.isfinite(cloud.points)) and len(cloud.colors) == len(cloud.points)
    assert not np.isin(cloud.primitive_ids, res.unconstrained).any()
    assert len(res.supported_primitives) == kept.size


@pytest.mark.parametrize("make,exc,fragment", [
    (lambda im: ([], CAM, None), InputError, "at least one supporting view"),
    (lambda im: (im, CAM, None), InputError, "view_images is one image array of shape (60, 80, 3)"),
    (lambda im: ([im[:40]], CAM, None), InputError, "view 1 has shape (40, 80, 3)"),
    (lambda im: ([np.full_like(im, np.nan)], CAM, None), InputError,
     "view 1: image contains 14400 NaN"),
    (lambda im: ([None], CAM, None), InputError, "view 1 is None"),
    (lambda im: ([im], synthetic.default_camera(160, 120), None), InputError,
     "reference image has shape (60, 80, 3), expected (120, 160"),
    (lambda im: ([im], (80.0, 80.0, 40.0, 30.0), None), TypeError,
     "camera must be a spgeo.PinholeCamera, got tuple"),
    (lambda im: ([im], CAM, []), InputError, "init_T_ref_view has 0 poses for 1 views"),
    (lambda im: ([im], CAM, [np.full((4, 4), np.nan)]), InputError,
     "init_T_ref_view[0] must be a finite 4x4 pose"),
], ids=["no_views", "one_array", "other_size", "nan_view", "none_view", "camera_size",
        "camera_tuple", "init_length", "init_nan"])
def test_few_view_sfm_input_errors(frames, make, exc, fragment):
    views, cam, init = make(frames[0].image)
    with pytest.raises(exc) as info:
        few_view_sfm(frames[0].image, views, cam, frontend(), init_T_ref_view=init)
    assert fragment in str(info.value)


# ============================================================ ATE with NaN ground truth
def test_ate_counts_and_warns_about_nan_ground_truth(caplog):
    n = 10
    t = np.arange(n, dtype=float)
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 0, 3], P[:, 1, 3] = np.arange(n), 0.1 * np.arange(n) ** 2
    G = P.copy()
    G[3] = np.nan
    G[5, 0, 3] = np.inf
    with caplog.at_level(logging.WARNING):
        out = ate_per_frame_and_keyframes((t, P), (t, G), np.arange(n) % 2 == 0,
                                          max_time_diff=0.1)
    msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert msgs == ["ATE (per-frame): 2 of 10 ground-truth poses are not finite "
                    "(NaN / inf pose or timestamp) and were left out"]
    a = out["per-frame"]
    assert (a.n_groundtruth_dropped, a.n_estimated_dropped, a.n_associated) == (2, 0, 8)
    assert a.summary()["n_groundtruth_dropped"] == 2
    assert out["keyframe-only"].n_groundtruth_dropped == 2


def test_ate_finite_ground_truth_is_silent(caplog):
    t = np.arange(5, dtype=float)
    P = np.tile(np.eye(4), (5, 1, 1))
    P[:, 0, 3], P[:, 2, 3] = t, t ** 2
    Pe = P.copy()
    Pe[1] = np.nan                       # a lost frame: dropped without a warning
    with caplog.at_level(logging.WARNING):
        a = ate_sim3((t, Pe), (t, P), max_time_diff=0.1)
    assert not caplog.records and (a.n_estimated_dropped, a.n_groundtruth_dropped) == (1, 0)


# ============================================================ quiet stderr
@pytest.fixture
def stderr_logging():
    """Log records to stderr (the current ``sys.stderr`` at each record) as a command-line
    user sees them."""
    class CurrentStderr:
        def write(self, text):
            sys.stderr.write(text)

        def flush(self):
            sys.stderr.flush()

    handler = logging.StreamHandler(CurrentStderr())
    handler.setLevel(logging.WARNING)
    root = logging.getLogger()
    root.addHandler(handler)
    yield
    root.removeHandler(handler)


def assert_quiet(out, err, caught):
    for text in (out, err):
        for dump in ("Thrown when", "gtsam::", "Levenberg", "RuntimeWarning", "Traceback"):
            assert dump not in text, text
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], caught


def test_degenerate_sfm_keeps_stderr_quiet(frames, capfd, stderr_logging):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = few_view_sfm(frames[0].image, [np.full((H, W, 3), 0.5, np.float32)], CAM,
                           frontend(), SfMConfig(levels=2))
    out, err = capfd.readouterr()
    assert_quiet(out, err, caught)
    assert res.status != "ok" and out == ""
    assert err.count("marginals failed: Indeterminate linear system") == 1
    assert len(err.strip().splitlines()) == 1


def test_degenerate_vo_keeps_stderr_quiet(frames, capfd, stderr_logging):
    rng = np.random.default_rng(0)
    images = [frames[0].image] + [rng.random((H, W, 3)).astype(np.float32) for _ in range(5)] \
        + [np.zeros((H, W, 3), np.float32)] * 3
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        vo = run_vo(images, OdometryConfig(max_lost_frames=3, **QUICK))
    out, err = capfd.readouterr()
    assert_quiet(out, err, caught)
    assert out == "" and vo.report()["n_frames"] == 9


def test_gtsam_error_line_is_one_line():
    exc = RuntimeError("\nIndeterminate linear system detected while working near variable\n"
                       "8646911284551352321 (Symbol: x1).\n\nThrown when a linear system is "
                       "ill-posed.\nmore\n")
    assert gtsam_error_line(exc) == ("Indeterminate linear system detected while working near "
                                     "variable 8646911284551352321 (Symbol: x1).")
    assert gtsam_error_line(RuntimeError("")) == "RuntimeError"


def test_triangulation_at_infinity_gives_nan_without_warning():
    T = np.eye(4)                            # no baseline: every point at infinity
    pts = np.array([[10.0, 10.0], [40.0, 30.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        z = triangulate_depths(T, CAM, pts, pts)
    assert np.all(np.isnan(z))


def test_init_buffer_is_bounded():
    buf = []
    for i in range(9):
        append_bounded(buf, i, 4)
    assert len(buf) <= 4 and buf[-1] == 8 and buf == sorted(buf)


def test_odometry_rejects_a_tuple_camera_and_a_foreign_config():
    """Odometry's constructor checks its camera and config types (it used to keep a
    tuple camera and fail deep inside the first frame)."""
    from spgeo.frontend import make_frontend
    from spgeo.vo import Odometry

    with pytest.raises(TypeError, match="Odometry: camera must be a spgeo.PinholeCamera, "
                                        "got tuple"):
        Odometry((60, 60, 31.5, 23.5, 64, 48), OdometryConfig(), make_frontend("classical"))
    cam = synthetic.default_camera(64, 48)
    with pytest.raises(TypeError, match="config must be an OdometryConfig, got dict"):
        Odometry(cam, {"window": 5}, make_frontend("classical"))
