"""``spgeo eval vo_long_run`` (evaluation/vo/long_run.py): the long-run VO benchmark on a
synthetic-loop smoke run, and its argument errors."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from spgeo.cli.eval import PROTOCOLS
from spgeo.evaluation.vo import long_run
from spgeo.evaluation.vo.long_run import TABLE, VARIANTS, main, run_config


def test_registered_and_variants_make_configs():
    assert PROTOCOLS["vo_long_run"] == "vo.long_run"
    assert run_config("7scenes", "default").odometry.loop_closure.enabled is False
    cfg = run_config("synthetic-loop", "loops")
    assert cfg.odometry.loop_closure.enabled is True
    assert cfg.odometry.resolution == (160, 120) and cfg.progress is False
    assert set(VARIANTS) >= {"default", "loops"}


def test_palindrome_cap_keeps_the_return():
    order = long_run._order(300, 40, loop=True)
    assert len(order) <= 40 and order[0] == order[-1] == 0 and max(order) == 19
    assert long_run._order(51, 60, loop=False) == list(range(51))


@pytest.mark.parametrize("flag, known, name", [("--sequences", "synthetic-loop", "moon"),
                                               ("--variants", "default", "turbo")])
def test_unknown_name_exits_2_naming_it(tmp_path, capsys, flag, known, name):
    assert main(["--out", str(tmp_path), flag, f"{known},{name}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and repr(name) in err[0]
    assert not (tmp_path / "long_run.json").exists()


@pytest.mark.slow
def test_synthetic_loop_smoke(tmp_path, capsys):
    """Three runs (each its own process) of a short synthetic loop: one row each with a
    finite, small ATE, the loop report only where loop closure is on, the keyframes'
    depth against the exact depth (the sensor-depth front-end's, the floor, near 0),
    and the table."""
    rc = main(["--out", str(tmp_path), "--sequences", "synthetic-loop", "--frames", "40",
               "--variants", "default,loops,sensor-depth", "--timeout", "300"])
    printed = capsys.readouterr().out
    assert rc == 0
    data = json.loads((tmp_path / "long_run.json").read_text())
    rows = {r["variant"]: r for r in data["rows"]}
    assert list(rows) == ["default", "loops", "sensor-depth"]
    # measured at 9276954: AbsRel 0.040 / delta 0.982 (10 keyframes), floor 0.022 / 0.995
    for variant, bound in (("default", 0.06), ("loops", 0.06), ("sensor-depth", 0.035)):
        r = rows[variant]
        assert 0 <= r["depth_abs_rel"] < bound and r["depth_delta"] > 0.95, r
        assert r["depth_maps"] >= 5 and r["depth_coverage"] > 0.9
    for r in rows.values():
        assert r["error"] is None and r["sequence"] == "synthetic-loop"
        assert r["frames"] <= 40 and r["tracked"] + r["lost"] == r["frames"]
        assert math.isfinite(r["ate_m"]) and 0 <= r["ate_m"] < 0.2
        assert r["peak_rss_mb"] > 0 and r["fps"] > 0 and r["end_err_m"] is not None
        assert (tmp_path / f"synthetic-loop.{r['variant']}" / "report.json").is_file()
    assert rows["default"]["loops_accepted"] is None
    assert rows["loops"]["loops_accepted"] is not None and rows["loops"]["loops_rejected"] >= 0
    md = (tmp_path / "long_run.md").read_text()
    header = "| " + " | ".join(h for h, _, _ in TABLE) + " |"
    assert header in md and header in printed
    assert md.count("| synthetic-loop |") == 3


@pytest.mark.slow
def test_colmap_reference_columns_and_cache(tmp_path, capsys):
    """``--reference colmap`` on a short synthetic loop: COLMAP runs once on the distinct
    frames (cached in DIR/colmap/, reused by a rerun), the run's row gains the rotation
    and orientation columns against COLMAP, and a ``colmap`` row its own against the
    ground truth."""
    pytest.importorskip("pycolmap")
    argv = ["--out", str(tmp_path), "--sequences", "synthetic-loop", "--frames", "40",
            "--variants", "default", "--timeout", "300", "--reference", "colmap"]
    assert main(argv) == 0
    rows = {r["variant"]: r for r in json.loads((tmp_path / "long_run.json").read_text())["rows"]}
    assert list(rows) == ["default", "colmap"]
    run, col = rows["default"], rows["colmap"]
    assert col["error"] is None and col["tracked"] >= 30 and col["status"] == "reference"
    assert 0 <= col["ate_m"] < 0.05 and 0 <= col["rot_vs_gt_deg"] < 1
    assert 0 <= run["rot_vs_colmap_deg"] < 2 and 0 <= run["orient_vs_colmap_max_deg"] < 3
    assert run["reference"]["colmap"]["relative_rotation"]["gap_frames"] == 30
    assert len(list((tmp_path / "colmap").iterdir())) == 1
    md = (tmp_path / "long_run.md").read_text()
    assert "rot/30 vs COLMAP deg" in md and "| synthetic-loop | colmap |" in md
    capsys.readouterr()
    assert main(argv[:6] + ["--variants", "loops", "--colmap"]) == 0     # the cache is reused
    rows = json.loads((tmp_path / "long_run.json").read_text())["rows"]
    assert rows[-1]["status"] == "reference (cached)"
    assert rows[-1]["rot_vs_gt_deg"] == pytest.approx(col["rot_vs_gt_deg"])


def test_loop_edges_of_a_report_are_judged_against_the_reference():
    """A run's accepted loops (report.json) become (candidate frame, query frame,
    S_cand_query) edges; an edge equal to the reference's relative pose (any scale)
    has zero error, one turned by 2 degrees has 2."""
    from spgeo.evaluation.vo.long_run import ColmapReference, loop_edges, reference_columns
    from spgeo.similarity import sim3
    from spgeo.synthetic.poses import camera_rotation
    from spgeo.trajectory import Trajectory
    from scipy.spatial.transform import Rotation

    n = 80
    poses = np.stack([sim3(camera_rotation(0.02 * i, 0.01 * i, 0.0), np.array([0.05 * i, 0, 0]))
                      for i in range(n)])
    stamps = np.arange(n, dtype=float)
    ref = ColmapReference(Trajectory(stamps, poses), (stamps, poses), {})
    T_cq = np.linalg.inv(poses[3]) @ poses[70]
    turn = sim3(Rotation.from_rotvec([0.0, np.radians(2.0), 0.0]).as_matrix(), np.zeros(3))
    report = {"loop_closures": {"accepted": [
        {"candidate_frame": 3, "query_frame": 70,
         "S_cand_query": (T_cq @ sim3(np.eye(3), np.zeros(3), 1.3)).tolist()},
        {"candidate_frame": 3, "query_frame": 70, "S_cand_query": (T_cq @ turn).tolist()}]}}
    edges = loop_edges(report)
    assert [(e[0], e[1]) for e in edges] == [(3.0, 70.0)] * 2
    cols = reference_columns(Trajectory(stamps, poses), ref, edges)
    assert cols["loop_rot_vs_colmap_max_deg"] == pytest.approx(2.0, abs=1e-6)
    assert cols["loop_rot_vs_colmap_mean_deg"] == pytest.approx(1.0, abs=1e-6)
    assert reference_columns(Trajectory(stamps, poses), ref)["loop_rot_vs_colmap_max_deg"] is None
    assert loop_edges({"loop_closures": None}) == []
