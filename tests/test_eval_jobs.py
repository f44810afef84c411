"""Evaluation jobs (spgeo.evaluation.jobs): local and Ray runners, error rows, the merged table."""
import argparse
import csv
import json
import math

import numpy as np
import pytest

from spgeo.evaluation.jobs import (EvalTable, Job, RunnerConfig, add_runner_arguments,
                                   mean_rows, provenance, run_jobs, run_table, runner_config)

_EXACT = ("ate_m", "ate_pct", "kf_ate_m", "kf_ate_pct", "length_m", "keyframes", "lost",
          "segments", "frames")


def _square(x):
    return {"value": x * x}


def _boom(x):
    raise ValueError(f"boom {x}")


def _not_a_dict():
    return [1, 2]


def test_failed_job_is_an_error_row_and_order_is_kept():
    jobs = [Job("a", _square, (2,), meta={"seed": 0}), Job("b", _boom, (7,), meta={"seed": 1}),
            Job("c", _not_a_dict, meta={"seed": 2}), Job("d", _square, kwargs={"x": 3})]
    rows = run_jobs(jobs, RunnerConfig(progress=False))
    assert [r["job"] for r in rows] == ["a", "b", "c", "d"]
    assert rows[0] == {"job": "a", "seed": 0, "value": 4, "error": None}
    assert rows[1] == {"job": "b", "seed": 1, "error": "ValueError: boom 7"}
    assert rows[2]["error"].startswith("TypeError: job 'c' returned list")
    assert rows[3]["value"] == 9 and rows[3]["error"] is None
    with pytest.raises(ValueError, match="duplicate job names"):
        run_jobs([jobs[0], jobs[0]], RunnerConfig(progress=False))


def test_runner_config_and_arguments():
    assert RunnerConfig().backend == "local"
    assert RunnerConfig(workers=2).backend == "ray"
    assert RunnerConfig(address="auto").backend == "ray"
    with pytest.raises(ValueError, match="workers"):
        RunnerConfig(workers=-1)
    ap = argparse.ArgumentParser()
    ap.add_argument("--no-progress", action="store_true")
    add_runner_arguments(ap)
    cfg = runner_config(ap.parse_args(["--workers", "3", "--no-progress"]), desc="x")
    assert cfg == RunnerConfig(workers=3, address=None, progress=False, desc="x")
    assert runner_config(ap.parse_args([])).backend == "local"


def test_table_means_provenance_and_files(tmp_path):
    rng = np.random.default_rng(0)
    rows = [{"job": f"{run}{s}", "run": run, "seed": s, "ate": float(rng.uniform(0, 1)),
             "kfs": int(rng.integers(2, 9)), "error": None}
            for run in ("x", "y") for s in range(3)]
    rows[1]["ate"] = float("nan")  # not finite: left out of its mean
    rows.append({"job": "x9", "run": "x", "seed": 9, "error": "RuntimeError: lost"})
    cols = (("run", "run", 0), ("seed", "seed", 0), ("ATE", "ate", 3), ("KFs", "kfs", 0),
            ("error", "error", 0))
    prov = provenance({"frames": 20}, RunnerConfig(workers=2))
    table = EvalTable(rows, cols, group_by=("run",), id_keys=("seed",), provenance=prov)
    means = {m["run"]: m for m in table.means}
    assert means["x"]["ate"] == pytest.approx(np.mean([rows[0]["ate"], rows[2]["ate"]]))
    assert means["x"]["kfs"] == pytest.approx(np.mean([r["kfs"] for r in rows[:3]]))
    assert means["x"]["n"] == 3 and means["x"]["failed"] == 1 and "seed" not in means["x"]
    assert means["y"]["ate"] == pytest.approx(np.mean([r["ate"] for r in rows[3:6]]))
    assert mean_rows(rows, ["ate"])[0]["n"] == 6  # no grouping: one row
    for key in ("commit", "dirty", "spgeo", "python", "hostname", "cpu_count", "argv", "time"):
        assert key in prov, key
    assert prov["config"] == {"frames": 20} and prov["runner"]["backend"] == "ray"
    assert prov["cpu_count"] >= 1 and prov["commit"]
    paths = table.write(tmp_path / "out", "results")
    saved = json.loads(paths["json"].read_text())
    assert [r["job"] for r in saved["rows"]] == [r["job"] for r in rows]
    assert saved["means"][0]["ate"] == pytest.approx(means["x"]["ate"])
    assert saved["provenance"]["hostname"] == prov["hostname"]
    with open(paths["csv"], newline="") as f:
        got = list(csv.DictReader(f))
    assert list(got[0]) == ["run", "seed", "ate", "kfs", "error"] and len(got) == 7
    assert got[-1]["error"] == "RuntimeError: lost" and got[-1]["ate"] == ""
    md = paths["md"].read_text()
    assert md.startswith("| run | seed | ATE | KFs | error |")
    assert "| x | 9 | - | - | RuntimeError: lost |" in md and "Provenance: commit" in md
    assert not list((tmp_path / "out").glob(".*.tmp"))


def test_run_table_rewrites_files_after_each_job(tmp_path):
    seen = []

    def table(rows):
        seen.append(len(rows))
        return EvalTable(rows, (("value", "value", 1), ("error", "error", 0)))

    jobs = [Job(str(i), _square, (i,)) for i in range(3)]
    result = run_table(jobs, RunnerConfig(progress=False), table, tmp_path, "t")
    assert seen[:3] == [1, 2, 3] and [r["value"] for r in result.rows] == [0, 1, 4]
    assert result.means[0]["value"] == pytest.approx(5 / 3)
    assert len(json.loads((tmp_path / "t.json").read_text())["rows"]) == 3


@pytest.mark.slow
def test_vo_synthetic_cli_error_row(tmp_path, capsys):
    from spgeo.evaluation.vo.synthetic import main

    rc = main(["--seeds", "0", "--frames", "12", "--runs", "depth", "nosuch", "--rotation", "none",
               "--no-progress", "--out", str(tmp_path)])
    assert rc == 1
    rows = json.loads((tmp_path / "results.json").read_text())["rows"]
    assert [r["run"] for r in rows] == ["depth", "nosuch"]
    assert rows[0]["error"] is None and math.isfinite(rows[0]["ate_pct"])
    assert rows[1]["error"].startswith("ValueError: unknown front-end 'nosuch'")
    out = capsys.readouterr()
    assert "| depth | 0 |" in out.out and "seed0/nosuch" in out.err


@pytest.mark.slow
def test_ray_gives_the_sequential_numbers():
    pytest.importorskip("ray")
    from spgeo.evaluation.vo.synthetic import make_jobs

    jobs = make_jobs([0, 1], ["depth"], n_frames=20, size=(160, 120), rotation=None)
    local = run_jobs(jobs, RunnerConfig(progress=False))
    bad = make_jobs([0], ["nosuch"], n_frames=20, size=(160, 120), rotation=None)
    ray_rows = run_jobs(jobs + bad, RunnerConfig(workers=2, progress=False))
    assert [r["job"] for r in ray_rows] == ["seed0/depth", "seed1/depth", "seed0/nosuch"]
    for a, b in zip(local, ray_rows):
        assert a["error"] is None and b["error"] is None
        for key in _EXACT:
            assert a[key] == b[key], key
        assert a["ate_m"] > 0
    assert local[0]["ate_m"] != local[1]["ate_m"]
    assert ray_rows[2]["error"].startswith("ValueError: unknown front-end")
