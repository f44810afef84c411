"""The few-view SfM shape ablation protocol (spgeo.evaluation.sfm.ablation) on the
shared TUM frames: one row's numbers against bounds from its measured output, and
cases whose data are missing left out."""
import pytest

from spgeo.evaluation.sfm.ablation import CASES, make_jobs, sfm_case_row


@pytest.mark.slow
def test_tum_classical_planar_row(shared_data):
    """TUM fr1_desk 0/4/8, classical front-end, planar shapes: verified, the
    reference depth within 15 % (median, after one scale), rotations within 2 deg."""
    row = sfm_case_row("tum", str(shared_data / "tum_fr1_desk_9"), "0:9:4", "classical",
                       "planar")
    assert row["status"] == "ok"
    assert row["median_rel"] < 0.15 and row["coverage"] > 0.9
    assert row["rot_err_deg"] < 2.0


def test_jobs_skip_missing_cases(tmp_path):
    (tmp_path / "tum_fr1_desk_9").mkdir()
    jobs = make_jobs(tmp_path, ["classical", "depth"], ["scaled"])
    assert [j.meta["case"] for j in jobs] == ["tum 0-4-8", "tum 0-4-8"]
    assert {j.meta["frontend"] for j in jobs} == {"classical", "depth"}
    assert len(CASES) == 5 and make_jobs(tmp_path / "none", ["classical"], ["scaled"]) == []


def test_onnx_depth_rows_need_a_depth_model(tmp_path):
    """The onnx-depth rows get --depth-model (theirs only) and are left out without it."""
    (tmp_path / "tum_fr1_desk_9").mkdir()
    fes = ["classical", "onnx-depth"]
    assert {j.meta["frontend"] for j in make_jobs(tmp_path, fes, ["scaled"])} == {"classical"}
    jobs = make_jobs(tmp_path, fes, ["scaled"], depth_model="fastdepth-nyu")
    assert {j.meta["frontend"]: dict(j.kwargs) for j in jobs} == {
        "classical": {}, "onnx-depth": {"depth_model": "fastdepth-nyu"}}


def test_missing_depth_model_is_one_error(tmp_path, capsys):
    from spgeo.evaluation.sfm.ablation import main

    (tmp_path / "tum_fr1_desk_9").mkdir()
    with pytest.raises(SystemExit) as exc:
        main(["--root", str(tmp_path), "--frontends", "onnx-depth", "--depth-model",
              str(tmp_path / "nope.onnx")])
    assert exc.value.code == 2 and "nope.onnx" in capsys.readouterr().err
