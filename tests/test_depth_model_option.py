"""``--depth-model NAME|PATH`` on ``spgeo vo`` and ``spgeo sfm`` (issue 24): the
``onnx-depth`` front-end's depth network reaches :func:`spgeo.frontend.build_frontend`
through ``VORunConfig.depth_model`` and the SfM command; ``--normal-model`` names the
``onnx`` front-end's normal network only; a model whose static input size is not its
preset's fails with one line naming the file, the sizes and the fix (exit code 2,
nothing written); the real FastDepth (../shared/models, skipped when absent) runs
through ``spgeo sfm`` on two shared TUM frames."""
from __future__ import annotations

import argparse
import json

import pytest

import onnx_builders as B
from conftest import shared_data_dir, write_synthetic_views
from spgeo import models
from spgeo.apps.vo_run import VORunConfig, make_vo_frontend
from spgeo.cli import main
from spgeo.cli.vo import _run_config, add_vo_cli
from spgeo.frontend import build_frontend, check_model_options
from spgeo.frontend.onnx_depth import DEPTH_PRESETS, OnnxDepthNormals
from spgeo.validation import InputError

FASTDEPTH = DEPTH_PRESETS["fastdepth"]
TUM_K = "517.3,516.5,318.6,255.3"


@pytest.fixture(scope="module")
def mdir(tmp_path_factory):
    """A dynamic-size relative-depth contract model and a FastDepth-like 224x224 one."""
    d = tmp_path_factory.mktemp("depth_models")
    B.depth_model(d / "dyn.onnx", coeffs=(0.2, -0.1, 0.5))
    B.depth_model(d / "fixed224.onnx", coeffs=(0.2, -0.1, 0.5), kind="depth",
                  input_size=(224, 224), output_rank=4, input_name=FASTDEPTH.input_name,
                  output_name=FASTDEPTH.output_name)
    return d


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sfm_in")
    cam, paths = write_synthetic_views(folder, seed=0)
    return f"{cam.fx},{cam.fy},{cam.cx},{cam.cy}", paths


def vo_args(*extra):
    sub = argparse.ArgumentParser().add_subparsers()
    p = add_vo_cli(sub)
    return p.parse_args(["--dataset", "folder", "x", "--out", "o", *extra])


def sfm_argv(images, out, *extra):
    k, paths = images
    return ["sfm", "--ref", str(paths[0]), "--views", *map(str, paths[1:]),
            "--intrinsics", k, "--out", str(out), *map(str, extra)]


# ------------------------------------------------------------------ routing
def test_build_frontend_routes_the_depth_model(mdir):
    fe = build_frontend("onnx-depth", (64, 48), depth_model=str(mdir / "dyn.onnx"))
    assert isinstance(fe.normal_estimator, OnnxDepthNormals)
    assert fe.normal_estimator.config.model_path == str(mdir / "dyn.onnx")
    assert fe.config.working_size == (64, 48) and fe.uses_depth is False
    # other front-ends refuse the depth model (it would be ignored), naming it
    for name in ("classical", "onnx", "depth"):
        with pytest.raises(ValueError, match=r"depth model 'nowhere\.onnx'.*" + name):
            build_frontend(name, depth_model="nowhere.onnx")


def test_library_vo_run_refuses_an_unused_depth_model(tmp_path):
    """``VORunConfig(depth_model=..., frontend="classical")`` is refused when the run
    starts (before any frame or data set is read), as ``spgeo vo`` refuses it."""
    from spgeo.apps.vo_run import run_dataset, run_odometry

    cfg = VORunConfig(depth_model="some-depth.onnx", frontend="classical", progress=False)

    def no_frames():
        raise AssertionError("a frame was read")
        yield

    with pytest.raises(ValueError, match=r"depth model 'some-depth\.onnx'.*'classical'"):
        run_odometry(no_frames(), cfg)
    with pytest.raises(ValueError, match=r"depth model 'some-depth\.onnx'"):
        run_dataset("folder", tmp_path / "nowhere", config=cfg)
    with pytest.raises(ValueError, match=r"depth model 'some-depth\.onnx'"):
        make_vo_frontend(cfg, (64, 48))
    # a depth_model from --set with another front-end is the CLI's input error too
    with pytest.raises(InputError, match="add --frontend onnx-depth"):
        _run_config(vo_args("--set", "depth_model=some-depth.onnx"))


def test_normal_model_is_refused_for_onnx_depth(mdir):
    with pytest.raises(ValueError, match=r"onnx-depth.*--depth-model .*dyn\.onnx"):
        build_frontend("onnx-depth", normal_model=str(mdir / "dyn.onnx"))
    with pytest.raises(ValueError, match="--depth-model"):
        VORunConfig(frontend="onnx-depth", normal_model="x.onnx")
    check_model_options("onnx", "x.onnx")         # the onnx front-end's own option


def test_vo_config_routes_the_depth_model(mdir):
    path = str(mdir / "dyn.onnx")
    cfg = _run_config(vo_args("--frontend", "onnx-depth", "--depth-model", path))
    assert cfg.frontend == "onnx-depth" and cfg.depth_model == path and cfg.normal_model is None
    fe = make_vo_frontend(cfg, (64, 48))
    assert fe.normal_estimator.config.model_path == path
    assert _run_config(vo_args("--set", f"depth_model={path}",
                               "--frontend", "onnx-depth")).depth_model == path
    with pytest.raises(InputError, match="--depth-model.*add --frontend onnx-depth"):
        _run_config(vo_args("--depth-model", path))
    with pytest.raises(ValueError, match="--depth-model"):
        _run_config(vo_args("--frontend", "onnx-depth", "--normal-model", path))


# ------------------------------------------------------------------ static size
def test_static_size_mismatch_names_file_sizes_and_fix(mdir):
    path = mdir / "fixed224.onnx"
    with pytest.raises(ValueError) as err:
        build_frontend("onnx-depth", depth_model=str(path))
    msg = str(err.value)
    assert str(path) in msg and "224x224" in msg and "518x518" in msg
    assert "'generic-depth-518'" in msg
    assert f"spgeo models register NAME {path} --preset fastdepth" in msg
    assert "\n" not in msg


def test_static_size_mismatch_through_the_cli(mdir, images, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(sfm_argv(images, out, "--frontend", "onnx-depth", "--depth-model",
                       mdir / "fixed224.onnx"))
    _, err = capsys.readouterr()
    assert rc == 2 and not out.exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert "fixed224.onnx" in lines[0] and "--preset fastdepth" in lines[0]
    rc = main(sfm_argv(images, out, "--depth-model", mdir / "dyn.onnx"))
    assert rc == 2 and "add --frontend onnx-depth" in capsys.readouterr().err
    rc = main(sfm_argv(images, out, "--frontend", "onnx-depth", "--normal-model", "x.onnx"))
    assert rc == 2 and "--depth-model" in capsys.readouterr().err and not out.exists()


def test_registered_name_runs_sfm(mdir, images, tmp_path, monkeypatch, capsys):
    """A 224x224 model registered under the fastdepth preset runs through `spgeo sfm`."""
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "cache"))
    models.register_model("toy-fixed", mdir / "fixed224.onnx", preset="fastdepth")
    out = tmp_path / "out"
    rc = main(sfm_argv(images, out, "--frontend", "onnx-depth", "--depth-model", "toy-fixed"))
    capsys.readouterr()
    assert rc in (0, 3) and (out / "poses.txt").is_file() and (out / "depth.npy").is_file()


# ------------------------------------------------------------------ the real network
def test_fastdepth_through_sfm_on_tum(tmp_path, monkeypatch, capsys):
    """Real FastDepth, registered under the fastdepth preset, through `spgeo sfm
    --frontend onnx-depth --depth-model NAME` on two shared TUM fr1_desk frames."""
    model = shared_data_dir().parent / "models" / "fastdepth" / "fastdepth_nyu_224.onnx"
    tum = shared_data_dir() / "tum_fr1_desk_9" / "rgb"
    if not model.is_file() or not tum.is_dir():
        pytest.skip("shared FastDepth model or TUM frames not found")
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path / "cache"))
    models.register_model("fastdepth-nyu", model, preset="fastdepth")
    frames = sorted(tum.glob("*.png"))
    out = tmp_path / "out"
    rc = main(["sfm", "--ref", str(frames[0]), "--views", str(frames[4]), "--intrinsics",
               TUM_K, "--out", str(out), "--frontend", "onnx-depth",
               "--depth-model", "fastdepth-nyu"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "ok" and report["cloud_points"] > 0
    assert len((out / "poses.txt").read_text().splitlines()) == 2
