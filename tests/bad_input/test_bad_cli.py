"""Bad input through the ``spgeo`` command line: every case ends with the exit code
of :mod:`spgeo.cli.exit_codes`, one ``spgeo CMD: ...`` line naming the value or
file on stderr, and never a traceback; nothing is written where the run fails
before its outputs."""
import json

import cv2
import numpy as np
import pytest

from conftest import write_synthetic_views
from spgeo import synthetic
from spgeo.cli import main

CAM = synthetic.default_camera(64, 48)
K = f"{CAM.fx},{CAM.fy},{CAM.cx},{CAM.cy}"


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """Three small rendered views of a synthetic room (PNG), their sparse depth."""
    folder = tmp_path_factory.mktemp("cli_in")
    _, paths = write_synthetic_views(folder, seed=0)
    sparse = np.load(folder / "sparse.npy")
    np.save(folder / "sparse_mm.npy", sparse * 1000.0)
    np.save(folder / "sparse_bool.npy", sparse > 0)
    jpg = folder / "v1.jpg"
    cv2.imwrite(str(jpg), cv2.imread(str(paths[1])))
    data = jpg.read_bytes()
    (folder / "cut.jpg").write_bytes(data[:len(data) // 2])
    (folder / "dir.png").mkdir()
    seq = folder / "seq"          # an image folder for `spgeo vo --dataset folder`
    seq.mkdir()
    for p in paths:
        (seq / p.name).write_bytes(p.read_bytes())
    (seq / "camera.json").write_text((folder / "camera.json").read_text())
    return folder, paths


def run(capsys, argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def sfm_args(images, out, ref=None, views=None, intrinsics=K):
    folder, paths = images
    return ["sfm", "--ref", ref or paths[0], "--views", *(views or paths[1:]),
            "--intrinsics", intrinsics, "--out", out]


@pytest.mark.parametrize("intrinsics, fragment", [
    ("0.808,1.076,0.498,0.532", "looks normalised"),
    ("0.001,0.001,31.5,23.5", "field of view"),
    ("50,50,500,23.5", "principal point cx=500"),
    ("50,250,31.5,23.5", "fx / fy"),
    ("nan,50,31.5,23.5", "fx must be finite"),
    ("50,50,31.5", "--intrinsics must be fx,fy,cx,cy"),
    ("a,b,c,d", "four numbers"),
])
def test_sfm_implausible_intrinsics(images, tmp_path, capsys, intrinsics, fragment):
    out = tmp_path / "out"
    rc, _, err = run(capsys, sfm_args(images, out, intrinsics=intrinsics))
    assert rc == 2 and fragment in err and err.startswith("spgeo sfm: error:")
    assert not out.exists()


@pytest.mark.parametrize("command", ["sfm", "complete"])
@pytest.mark.parametrize("joined", [False, True])
def test_negative_focal_length_is_named(images, tmp_path, capsys, command, joined):
    """``--intrinsics -fx,...`` (argparse would take the value for an option) and
    ``--intrinsics=-fx,...`` both reach the check that names the negative focal length."""
    folder, paths = images
    value = f"{-CAM.fx},{CAM.fy},{CAM.cx},{CAM.cy}"
    intrinsics = [f"--intrinsics={value}"] if joined else ["--intrinsics", value]
    if command == "sfm":
        out = tmp_path / "out"
        argv = ["sfm", "--ref", paths[0], "--views", *paths[1:], *intrinsics, "--out", out]
    else:
        out = tmp_path / "d.png"
        argv = ["complete", "--rgb", paths[0], "--sparse", folder / "sparse.npy", *intrinsics,
                "--out", out]
    rc, _, err = run(capsys, argv)
    assert rc == 2 and err.startswith(f"spgeo {command}: error:")
    assert f"fx must be finite and > 0, got {-CAM.fx!r}" in err
    assert not out.exists()


def test_complete_help_states_the_default_method(capsys):
    from spgeo.completion import CompletionConfig

    with pytest.raises(SystemExit):
        main(["complete", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"(default {CompletionConfig.method!r};" in text and "median (default)" not in text


@pytest.mark.parametrize("which, fragment", [
    ("missing", "not found"), ("folder", "is a folder"), ("truncated", "truncated or corrupt"),
])
def test_sfm_bad_image_files(images, tmp_path, capsys, which, fragment):
    folder, paths = images
    bad = {"missing": folder / "nope.png", "folder": folder / "dir.png",
           "truncated": folder / "cut.jpg"}[which]
    rc, _, err = run(capsys, sfm_args(images, tmp_path / "o", views=[paths[1], bad]))
    assert rc == 2 and fragment in err and bad.name in err


def test_sfm_out_is_a_file(images, tmp_path, capsys):
    out = tmp_path / "file.txt"
    out.write_text("keep me")
    rc, _, err = run(capsys, sfm_args(images, out))
    assert rc == 2 and "exists and is not a folder" in err
    assert out.read_text() == "keep me"


def test_sfm_out_is_a_foreign_folder(images, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    rc, _, err = run(capsys, sfm_args(images, out))
    assert rc == 2 and "did not write" in err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_sfm_out_parent_not_writable(images, tmp_path, capsys, monkeypatch):
    import spgeo.io.outputs as outputs

    real = outputs.os.access
    monkeypatch.setattr(outputs.os, "access",
                        lambda p, mode: False if str(p) == str(tmp_path) else real(p, mode))
    rc, _, err = run(capsys, sfm_args(images, tmp_path / "o"))
    assert rc == 2 and "is not writable" in err


@pytest.mark.parametrize("exc, rc_expected, fragment", [
    (KeyboardInterrupt(), 130, "spgeo sfm: interrupted"),
    (MemoryError(), 2, "out of memory"),
    (RuntimeError("boom"), 1, "unexpected RuntimeError: boom"),
])
def test_sfm_injected_failures(images, tmp_path, capsys, monkeypatch, exc, rc_expected, fragment):
    import spgeo.sfm

    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(spgeo.sfm, "few_view_sfm", fail)
    out = tmp_path / "o"
    rc, _, err = run(capsys, sfm_args(images, out))
    assert rc == rc_expected and fragment in err
    assert not out.exists() and not list(tmp_path.glob(".o.*"))


@pytest.mark.parametrize("sparse, out_name, fragment", [
    ("sparse_mm.npy", "d.png", "looks like millimetres"),
    ("sparse_bool.npy", "d.png", "dtype bool"),
    ("sparse.npy", "d.jpg", "must be a .png"),
    ("nope.npy", "d.png", "not found"),
])
def test_complete_bad_inputs(images, tmp_path, capsys, sparse, out_name, fragment):
    folder, paths = images
    out = tmp_path / out_name
    rc, _, err = run(capsys, ["complete", "--rgb", paths[0], "--sparse", folder / sparse,
                              "--intrinsics", K, "--out", out])
    assert rc == 2 and fragment in err
    assert not out.exists()


def test_complete_out_is_a_folder(images, tmp_path, capsys):
    folder, paths = images
    (tmp_path / "x.png").mkdir()
    rc, _, err = run(capsys, ["complete", "--rgb", paths[0], "--sparse", folder / "sparse.npy",
                              "--intrinsics", K, "--out", tmp_path / "x.png"])
    assert rc == 2 and "is a folder" in err


def test_complete_normalised_intrinsics(images, tmp_path, capsys):
    folder, paths = images
    rc, _, err = run(capsys, ["complete", "--rgb", paths[0], "--sparse", folder / "sparse.npy",
                              "--intrinsics", "0.8,1.07,0.5,0.53", "--out", tmp_path / "d.png"])
    assert rc == 2 and "looks normalised" in err


@pytest.mark.parametrize("extra, fragment", [
    (["--resolution", "100000x100000"], "<= 8192"),
    (["--set", "no_such_field=1"], "no_such_field"),
    (["--frames", "5:3"], "5:3"),
    (["--depth-scale", "0"], "depth scale must be a finite number > 0 (raw depth units per "
                             "metre, e.g. 5000 for TUM, 1000 for millimetres), got '0'"),
    (["--depth-scale", "-5000"], "got '-5000'"),
    (["--depth-scale", "nan"], "got 'nan'"),
    (["--depth-scale", "5mm"], "got '5mm'"),
])
def test_vo_bad_arguments(images, tmp_path, capsys, extra, fragment):
    folder, _ = images
    out = tmp_path / "o"
    rc, _, err = run(capsys, ["vo", "--dataset", "folder", folder / "seq", "--out", out,
                              "--no-progress", *extra])
    assert rc == 2 and fragment in err and err.startswith("spgeo vo: error:")
    assert not out.exists()


def test_vo_depth_scale_for_a_reader_without_depth(tmp_path, capsys):
    rc, _, err = run(capsys, ["vo", "--dataset", "video", tmp_path / "clip.avi",
                              "--depth-scale", "5000", "--out", tmp_path / "o"])
    assert rc == 2 and "--depth-scale: the 'video' reader has no such option" in err
    assert "tum, 7scenes, icl, folder" in err


def test_vo_image_dir_for_kitti_only_and_named(tmp_path, capsys):
    """``--image-dir`` picks a KITTI camera folder: refused for another reader (naming
    the kinds that take it), and a folder name KITTI does not have is named."""
    rc, _, err = run(capsys, ["vo", "--dataset", "folder", tmp_path, "--image-dir", "image_2",
                              "--out", tmp_path / "o"])
    assert rc == 2 and "--image-dir: the 'folder' reader has no such option" in err
    assert "(kinds that take it: kitti)" in err
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "calib.txt").write_text("P0: " + " ".join(["1"] * 12) + "\n")
    rc, _, err = run(capsys, ["vo", "--dataset", "kitti", tmp_path / "seq", "--image-dir",
                              "image_9", "--out", tmp_path / "o"])
    assert rc == 2 and "image_dir must be one of" in err and "'image_9'" in err


def test_vo_missing_dataset(tmp_path, capsys):
    rc, _, err = run(capsys, ["vo", "--dataset", "tum", tmp_path / "nowhere",
                              "--out", tmp_path / "o", "--no-progress"])
    assert rc == 2 and "nowhere" in err


def test_vo_out_checked_before_the_run(tmp_path, capsys, monkeypatch):
    """A bad --out fails before any frame is read."""
    import spgeo.apps.vo_run as vo_run

    def never(*args, **kwargs):
        raise AssertionError("the run started")

    monkeypatch.setattr(vo_run, "run_dataset", never)
    out = tmp_path / "f"
    out.write_text("x")
    rc, _, err = run(capsys, ["vo", "--dataset", "tum", tmp_path, "--out", out, "--no-progress"])
    assert rc == 2 and "exists and is not a folder" in err


def test_models_errors_on_stderr(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("SPGEO_MODEL_DIR", str(tmp_path))
    rc, out, err = run(capsys, ["models", "fetch", "no-such-model"])
    assert rc == 2 and "no-such-model" in err and "error" not in out
    rc, out, err = run(capsys, ["models", "path", "no-such-model"])
    assert rc == 2 and "no-such-model" in err


def test_eval_unknown_protocol(capsys):
    with pytest.raises(SystemExit) as e:    # argparse: usage error, exit 2
        main(["eval", "no_such_protocol"])
    assert e.value.code == 2
    assert "no_such_protocol" in capsys.readouterr().err


def test_sfm_flagged_result_exit_3_without_a_fake_cloud(images, tmp_path, capsys):
    """Zero parallax (the reference repeated as the views): exit 3, depth all NaN,
    no cloud.ply with points at an arbitrary depth, the manifest says flagged."""
    folder, paths = images
    out = tmp_path / "o"
    rc, out_text, err = run(capsys, sfm_args(images, out, views=[paths[0], paths[0]]))
    assert rc == 3 and "flagged" in err
    assert np.all(np.isnan(np.load(out / "depth.npy")))
    assert not (out / "cloud.ply").exists() and "no cloud.ply" in out_text
    rep = json.loads((out / "report.json").read_text())
    assert rep["status"] != "ok" and rep["cloud_points"] == 0
    assert json.loads((out / ".spgeo-output.json").read_text())["status"] == "flagged"


def test_vo_repeated_frame_is_flagged_not_a_map(images, tmp_path, capsys):
    """One frame repeated: no keyframe pair with parallax, so no map: exit 3, the
    reason on stderr and in report.json, no keyframe clouds (the issue's planes at
    z = 1), every frame ``init``/``lost`` (never ``ok``)."""
    folder, paths = images
    seq = tmp_path / "same"
    seq.mkdir()
    for i in range(12):
        (seq / f"r{i:02d}.png").write_bytes(paths[0].read_bytes())
    (seq / "camera.json").write_text((folder / "camera.json").read_text())
    out = tmp_path / "o"
    rc, _, err = run(capsys, ["vo", "--dataset", "folder", seq, "--out", out, "--no-progress",
                              "--resolution", "64x48", "--set", "init.max_gap=4"])
    assert rc == 3 and "no map was initialised" in err
    rep = json.loads((out / "report.json").read_text())
    assert rep["run"]["status"] == "no_map" and "low_parallax" in rep["run"]["init_failure"]
    assert not any((out / "clouds").glob("*.ply"))
    from spgeo.io.tum import read_status

    _, status = read_status(out / "trajectory.status.txt")
    assert len(status) == 12 and set(status) <= {"keyframe", "init", "lost"}
    assert status.count("keyframe") == 1
