"""The VO part of ``spgeo demo`` (spgeo.apps.demo.run_vo_demo), on a short rendered
synthetic sequence with the classical (monocular) front-end.  The bundled TUM
run is left to ``spgeo demo`` itself (test time)."""
from pathlib import Path

import numpy as np
import pytest

from spgeo.cli import build_parser
from spgeo.apps.demo import DemoConfig, run_vo_demo
from spgeo.evaluation.trajectory import read_status, read_tum

N_FRAMES = 40


@pytest.fixture(scope="module")
def vo_demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    cfg = DemoConfig(out_dir=str(out), vo_frames=N_FRAMES, vo_frontends=("classical",),
                     vo_tum=False)
    return run_vo_demo(cfg)


@pytest.mark.slow
def test_synthetic_classical_accuracy(vo_demo):
    """Per-frame ATE under 5% of the path on this 40-frame seed-0 sequence."""
    rows = [r for r in vo_demo.rows if r.sequence == "synthetic"]
    assert [r.frontend for r in rows] == ["classical"]
    r = rows[0]
    assert r.n_frames == N_FRAMES and r.n_tracked + r.n_lost == N_FRAMES
    assert r.n_lost <= 2 and r.n_keyframes >= 2 and r.init_frame is not None
    assert r.trajectory_length_m > 0.1
    assert r.ate_percent < 5.0
    assert np.isclose(r.ate_percent, 100 * r.ate_rmse_m / r.trajectory_length_m)
    assert r.fps > 0


@pytest.mark.slow
def test_table_has_the_rows(vo_demo):
    assert [r.sequence for r in vo_demo.rows] == ["synthetic"]
    table = vo_demo.table().splitlines()
    assert table[0].split()[:2] == ["sequence", "front-end"]
    row = [line for line in table if line.startswith("synthetic")]
    assert len(row) == 1 and row[0].split()[1] == "classical"
    assert f"{vo_demo.rows[0].ate_percent:6.2f}" in row[0]


@pytest.mark.slow
def test_trajectories_written(vo_demo):
    for r in vo_demo.rows:
        assert vo_demo.files[f"vo_{r.sequence}_classical"] == r.out_dir
        traj = read_tum(f"{r.out_dir}/trajectory.txt")
        gt = read_tum(f"{r.out_dir}/groundtruth.txt")
        written = {p for p in Path(r.out_dir).rglob("*") if p.is_file()}
        assert written == set(vo_demo.described)          # every file described, with units
        assert all(info.what and info.units for info in vo_demo.described.values())
        _, status = read_status(f"{r.out_dir}/trajectory.status.txt")
        assert sum(s == "lost" for s in status) == r.n_lost
        assert len(traj.timestamps) == r.n_frames == len(gt.timestamps) + r.n_lost


def test_cli_no_vo_flag():
    args = build_parser().parse_args(["demo", "--no-vo"])
    assert args.no_vo is True
    assert build_parser().parse_args(["demo"]).no_vo is False
