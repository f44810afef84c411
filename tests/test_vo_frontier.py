"""``spgeo eval vo_frontier``: the grid, its rows and its files."""
import csv
import json
import math

import pytest

from spgeo.configs import ConfigError
from spgeo.evaluation.vo.frontier import (COLUMNS, Cell, main, make_grid, markdown_table,
                                          parse_setting, run_grid, setting_config)


def test_parse_setting_splits_on_field_names_only():
    assert parse_setting("defaults") == [] and parse_setting("  ") == []
    assert parse_setting("mapping.level=0, tracker.levels=4") == ["mapping.level=0",
                                                                   "tracker.levels=4"]
    assert parse_setting("a=(1, 2) b=None,c='x y'") == ["a=(1, 2)", "b=None", "c='x y'"]
    assert setting_config("mapping.level=0 tracker.levels=4").tracker.levels == 4
    with pytest.raises(ConfigError, match="unknown field 'no_such_field'"):
        setting_config("no_such_field=1")


def test_make_grid_order_and_defaults():
    cells = make_grid(["7scenes", "synthetic"], ["classical"], [(160, 120), (320, 240)],
                      ["defaults", "mapping.level=0"], seeds=[0, 1], sevenscenes="/x")
    assert len(cells) == 2 * 2 + 2 * 2 * 2
    assert cells[0] == Cell("7scenes", "classical", (160, 120), "defaults", 300, None, "/x")
    assert cells[-1] == Cell("synthetic", "classical", (320, 240), "mapping.level=0", 150, 1)
    with pytest.raises(ValueError, match="unknown data set"):
        make_grid(["kitti"], ["classical"], [(160, 120)], [""])


def test_unknown_field_is_an_error_row_not_a_crash(tmp_path, capsys):
    rc = main(["--datasets", "synthetic", "--frames", "30", "--set-grid", "no_such_field=3",
               "--no-progress", "--out", str(tmp_path)])
    assert rc == 1
    rows = json.loads((tmp_path / "frontier.json").read_text())["rows"]
    assert len(rows) == 1 and "unknown field 'no_such_field'" in rows[0]["error"]
    assert rows[0]["ate_m"] is None
    assert "no_such_field" in capsys.readouterr().err


def test_failed_run_is_an_error_row(tmp_path):
    rows = run_grid([Cell("7scenes", "classical", (160, 120), "", 10, None,
                          str(tmp_path / "missing"))], in_process=True, progress=False)
    assert len(rows) == 1 and rows[0]["error"] and "missing" in rows[0]["error"]
    assert "| 7scenes |" in markdown_table(rows)


@pytest.mark.slow
def test_tiny_synthetic_grid(tmp_path, capsys):
    rc = main(["--datasets", "synthetic", "--frames", "45", "--seeds", "0",
               "--set-grid", "defaults", "primitive_model='planar'",
               "--no-progress", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    rows_md, means_md = out.split("Means over the rows without error")
    assert rows_md.count("| synthetic |") == 2 and means_md.count("| synthetic |") == 2
    rows = json.loads((tmp_path / "frontier.json").read_text())["rows"]
    with open(tmp_path / "frontier.csv", newline="") as f:
        assert list(csv.DictReader(f).fieldnames) == list(COLUMNS)
    assert (tmp_path / "frontier.md").read_text().startswith("| data |")
    assert [r["setting"] for r in rows] == ["defaults", "primitive_model='planar'"]
    assert rows[1]["overrides"] == {"primitive_model": "planar"} and rows[0]["overrides"] == {}
    for r in rows:
        assert set(COLUMNS) <= set(r) and r["error"] is None
        assert r["frames"] == 45 and r["resolution"] == "160x120" and r["seed"] == 0
        for key in ("ate_m", "ate_pct", "fps", "tracking_fps", "peak_rss_mb", "cell_wall_s"):
            assert math.isfinite(r[key]) and r[key] > 0, key
        assert r["keyframes"] >= 2 and r["lost"] == 0
        assert 50 < r["peak_rss_mb"] < 8000
    # a planar primitive model changes the map, hence the trajectory
    assert rows[0]["ate_m"] != rows[1]["ate_m"]
