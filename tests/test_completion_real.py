"""``spgeo eval completion_real`` on two TUM frames (skips without the shared data)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import shared_data_dir
from spgeo.evaluation.completion import real as cr


@pytest.fixture(scope="module")
def root():
    path = shared_data_dir()
    if not (path / "tum_fr1_desk_9").is_dir():
        pytest.skip(f"shared TUM sample not found under {path}")
    return path


def test_run_dataset_rows_metrics_and_gains(root):
    res = cr.run_dataset("tum", root, frames="0:2", frontends=["classical", "depth"],
                         methods=["graph"], shape_models=["scale", "plane"],
                         baselines=["linear", "ip_basic"], progress=False)
    assert len(res.frames) == 2
    mean = res.mean()
    assert set(mean) == {"spgeo classical graph/scale", "spgeo classical graph/plane",
                         "spgeo ORACLE depth-normals graph/scale",
                         "spgeo ORACLE depth-normals graph/plane", "linear", "ip_basic",
                         "spgeo classical choose=heldout"}
    won = res.winners["spgeo classical choose=heldout"]
    assert set(won) == {"primitives", "linear", "ip_basic"} and sum(won.values()) > 0
    assert "weighs each candidate most" in res.table() and "(regime 'grid')" in res.table()
    for v in mean.values():
        assert 0 < v["mae_mm"] < 1000 and 0 < v["imae_per_km"] < 1000 and v["seconds"] > 0
    g = res.gains()
    best = min(mean["linear"]["mae_mm"], mean["ip_basic"]["mae_mm"])
    m = "spgeo classical graph/plane"
    assert g[m]["mae_mm"] == pytest.approx(1 - mean[m]["mae_mm"] / best)
    assert "| linear |" in res.table()
    json.dumps(res.to_dict())


def test_main_writes_markdown_and_json(root, tmp_path):
    rc = cr.main(["--root", str(root), "--datasets", "tum", "--frames", "0:1",
                  "--frontends", "classical", "--baselines", "linear", "--out", str(tmp_path)])
    assert rc == 0
    data = json.loads((tmp_path / "completion_real.json").read_text())
    assert np.isfinite(data["tum"]["mean"]["linear"]["mae_mm"])
    assert "spgeo classical median/scale" in (tmp_path / "completion_real.md").read_text()


def test_unknown_dataset_and_missing_root(tmp_path):
    with pytest.raises(ValueError, match="unknown data set"):
        cr.run_dataset("kitti", tmp_path)
    with pytest.raises(FileNotFoundError):
        cr.run_dataset("tum", tmp_path)
    assert cr.run_completion_real(tmp_path, ["tum"]) == {}


def test_set_overrides_the_completion_config(root, tmp_path, capsys):
    args = ["--root", str(root), "--datasets", "tum", "--frames", "0:1", "--frontends",
            "classical", "--baselines", "linear"]
    assert cr.main(args + ["--out", str(tmp_path / "a")]) == 0
    assert cr.main(args + ["--set", "plane_coupling=0.5", "--out", str(tmp_path / "b")]) == 0
    a, b = (json.loads((tmp_path / d / "completion_real.json").read_text())["tum"]["mean"]
            for d in ("a", "b"))
    row = "spgeo classical graph/plane"
    assert a[row]["mae_mm"] != b[row]["mae_mm"]              # the override reached the solver
    assert a["linear"]["mae_mm"] == b["linear"]["mae_mm"]
    capsys.readouterr()
    assert cr.main(args + ["--set", "no_such_field=1"]) == 2
    assert "unknown field 'no_such_field'" in capsys.readouterr().err


def test_completion_strata_partition_and_errors(root, capsys):
    from spgeo.evaluation.completion.strata import STRATA, main, strata_errors

    rows = strata_errors("tum", root=root, frames="0:2")
    assert list(rows) == [lab for lab, _, _ in STRATA]
    assert sum(r["fraction"] for r in rows.values()) == pytest.approx(1.0)
    for r in rows.values():
        if r["fraction"] > 0.05:
            assert 0 < r["spgeo_mm"] < 2000 and 0 < r["linear_mm"] < 2000
    assert main(["--datasets", "tum", "--root", str(root / "none")]) == 2
    assert "completion_strata: error:" in capsys.readouterr().err


def test_regimes_place_the_points_differently(root):
    """``--regime``: the same frame's 150 points differ between the grid, the
    strongest corners, uniform pixels and KLT tracks, and linear interpolation
    is scored on each; an unknown regime is refused by name, tracks without
    their sequence too; the last frame is tracked backwards."""
    ds = cr.open_sample("tum", root, "0:1")
    seq = cr.open_sample("tum", root, "0:")
    masks = {r: next(cr.sparse_frames(ds, 150, 0, progress=False, regime=r, sequence=seq))[2] > 0
             for r in cr.REGIMES}
    assert all(m.sum() == 150 for m in masks.values())
    assert all((masks["grid"] != masks[r]).any() for r in ("corners", "uniform", "tracks"))
    with pytest.raises(ValueError, match="regime"):
        next(cr.sparse_frames(ds, 150, 0, progress=False, regime="spiral"))
    with pytest.raises(ValueError, match="sequence"):
        next(cr.sparse_frames(ds, 150, 0, progress=False, regime="tracks"))
    assert cr._neighbours(seq, seq.frame_numbers[-1], 3) == [len(seq) - 2, len(seq) - 3,
                                                            len(seq) - 4]
    rc = cr.main(["--root", str(root), "--datasets", "tum", "--frames", "0:1", "--regime",
                  "corners", "--frontends", "classical", "--baselines", "linear", "--no-choose"])
    assert rc == 0
