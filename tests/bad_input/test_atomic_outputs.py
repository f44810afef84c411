"""Outputs are complete or absent (:mod:`spgeo.io.outputs`): staged folders that
replace a previous spgeo run as a whole, never mix two runs, leave the previous
output untouched when a run fails, and mark an interrupted VO run as such."""
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import write_synthetic_views
from spgeo import synthetic
from spgeo.cli import main
from spgeo.io.outputs import MANIFEST, StagedFolder, check_output_folder, read_manifest
from spgeo.validation import InputError

CAM = synthetic.default_camera(64, 48)
K = f"{CAM.fx},{CAM.fy},{CAM.cx},{CAM.cy}"


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` -> its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path, name: str):
    return sorted(p.name for p in parent.glob(f".{name}.*"))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("atomic_in")
    _, paths = write_synthetic_views(folder, seed=1)
    return folder, paths


def sfm(inputs, out):
    folder, paths = inputs
    return main(["sfm", "--ref", str(paths[0]), "--views", *map(str, paths[1:]),
                 "--intrinsics", K, "--out", str(out)])


# ------------------------------------------------------------------ StagedFolder
def test_staged_folder_commit_and_replace(tmp_path):
    target = tmp_path / "run"
    with StagedFolder(target, command="test") as st:
        (st.path / "a.txt").write_text("1")
        (st.path / "old.txt").write_text("stale")
        st.commit("complete")
    assert read_manifest(target)["status"] == "complete"
    with StagedFolder(target, command="test") as st:     # a previous spgeo output: replaced
        (st.path / "a.txt").write_text("2")
        st.commit("flagged")
    assert sorted(p.name for p in target.iterdir()) == sorted([MANIFEST, "a.txt"])
    assert (target / "a.txt").read_text() == "2" and read_manifest(target)["status"] == "flagged"
    assert leftovers(tmp_path, "run") == []


def test_staged_folder_exception_leaves_target_untouched(tmp_path):
    target = tmp_path / "run"
    with StagedFolder(target) as st:
        (st.path / "a.txt").write_text("1")
        st.commit()
    before = snapshot(target)
    with pytest.raises(RuntimeError, match="mid-run"):
        with StagedFolder(target) as st:
            (st.path / "a.txt").write_text("half")
            raise RuntimeError("mid-run")
    assert snapshot(target) == before and leftovers(tmp_path, "run") == []


def test_staged_folder_keyboard_interrupt_leaves_nothing(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with StagedFolder(tmp_path / "new") as st:
            (st.path / "x").write_text("x")
            raise KeyboardInterrupt
    assert not (tmp_path / "new").exists() and leftovers(tmp_path, "new") == []


@pytest.mark.parametrize("setup, fragment", [
    ("file", "exists and is not a folder"),
    ("foreign", "did not write"),
    ("parent_file", "a file is in the way"),
])
def test_check_output_folder_refuses(tmp_path, setup, fragment):
    target = tmp_path / "out"
    if setup == "file":
        target.write_text("x")
    elif setup == "foreign":
        target.mkdir()
        (target / "mine.txt").write_text("x")
    else:
        (tmp_path / "blocker").write_text("x")
        target = tmp_path / "blocker" / "out"
    with pytest.raises(InputError, match=fragment):
        check_output_folder(target)


def test_check_output_folder_accepts_empty_and_new(tmp_path):
    (tmp_path / "empty").mkdir()
    assert check_output_folder(tmp_path / "empty") == tmp_path / "empty"
    assert check_output_folder(tmp_path / "a" / "b") == tmp_path / "a" / "b"


# ------------------------------------------------------------------ commands
@pytest.mark.slow
def test_sfm_rerun_replaces_the_previous_run(inputs, tmp_path):
    out = tmp_path / "o"
    assert sfm(inputs, out) in (0, 3)
    (out / "stale_from_an_older_run.ply").write_text("x")
    assert sfm(inputs, out) in (0, 3)
    names = {p.name for p in out.iterdir()}
    assert "stale_from_an_older_run.ply" not in names
    assert {"poses.txt", "depth.npy", "report.json", MANIFEST} <= names
    assert leftovers(tmp_path, "o") == []
    files = read_manifest(out)["files"]         # every file, each with what it is and units
    assert sorted(f["path"] for f in files) == sorted(names - {MANIFEST})
    assert all(f["what"] and f["units"] for f in files)


@pytest.mark.slow
@pytest.mark.parametrize("where", ["solve", "write"])
def test_sfm_failure_leaves_previous_output_byte_for_byte(inputs, tmp_path, monkeypatch, where):
    out = tmp_path / "o"
    assert sfm(inputs, out) in (0, 3)
    before = snapshot(out)

    def fail(*args, **kwargs):
        raise OSError("disk full (injected)")

    if where == "solve":
        import spgeo.sfm
        monkeypatch.setattr(spgeo.sfm, "few_view_sfm", fail)
    else:
        monkeypatch.setattr(np, "save", fail)
    assert sfm(inputs, out) == 2
    assert snapshot(out) == before and leftovers(tmp_path, "o") == []


def test_complete_failure_keeps_the_previous_png(inputs, tmp_path, monkeypatch):
    folder, paths = inputs
    out = tmp_path / "d.png"
    argv = ["complete", "--rgb", str(paths[0]), "--sparse", str(folder / "sparse.npy"),
            "--intrinsics", K, "--out", str(out)]
    assert main(argv) == 0
    before = out.read_bytes()
    import spgeo.completion

    def fail(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(spgeo.completion, "complete_depth", fail)
    assert main(argv) == 130
    assert out.read_bytes() == before and not list(tmp_path.glob(".d.png.*"))


def _vo(inputs, out):
    folder, _ = inputs
    return main(["vo", "--dataset", "folder", str(folder), "--out", str(out), "--no-progress",
                 "--resolution", "64x48"])


def test_vo_ctrl_c_writes_the_frames_so_far_marked_interrupted(inputs, tmp_path, monkeypatch):
    from spgeo.vo import Odometry

    calls = {"n": 0}
    real = Odometry.track

    def track(self, frame):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(Odometry, "track", track)
    out = tmp_path / "vo"
    assert _vo(inputs, out) == 130
    rep = json.loads((out / "report.json").read_text())
    assert rep["run"]["status"] == "interrupted" and rep["run"]["n_frames"] == 2
    rows = [ln for ln in (out / "trajectory.status.txt").read_text().splitlines()
            if ln and not ln.startswith("#")]
    assert [float(r.split()[0]) for r in rows] == [0.0, 1.0]   # trajectory.txt: posed only
    assert read_manifest(out)["status"] == "interrupted"


def test_vo_failure_mid_run_leaves_previous_run(inputs, tmp_path, monkeypatch):
    from spgeo.vo import Odometry

    out = tmp_path / "vo"
    assert _vo(inputs, out) == 3          # 3 frames: no map yet (flagged, written)
    (out / "clouds").mkdir(exist_ok=True)
    (out / "clouds" / "keyframe_099.ply").write_text("stale")
    before = snapshot(out)

    def boom(self, frame):
        raise RuntimeError("injected")

    monkeypatch.setattr(Odometry, "track", boom)
    assert _vo(inputs, out) == 1
    assert snapshot(out) == before and leftovers(tmp_path, "vo") == []
    monkeypatch.undo()
    assert _vo(inputs, out) == 3          # a rerun replaces the folder: no stale cloud
    assert not (out / "clouds" / "keyframe_099.ply").exists()


def test_check_output_folder_probes_the_parent(tmp_path, monkeypatch):
    """A parent that os.access calls writable but that refuses new entries (root on
    a read-only or virtual file system) is found by the probe, before any work."""
    import spgeo.io.outputs as outputs

    def refuse(*args, **kwargs):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(outputs.tempfile, "mkdtemp", refuse)
    with pytest.raises(InputError, match="cannot write --out .*Read-only file system"):
        check_output_folder(tmp_path / "out")
