"""Accuracy / speed / memory frontier of the monocular VO over a grid of settings.

    spgeo eval vo_frontier [--datasets 7scenes synthetic] [--frames N]
        [--resolutions 160x120 320x240] [--frontends classical depth]
        [--set-grid "defaults" "mapping.level=0" "tracker.levels=4 mapping.chunk=1"]
        [--seeds 0] [--sevenscenes PATH] [--out DIR] [--workers N | --address ADDR]

The grid is every (data set, front-end, resolution, setting) and, for the
synthetic data set, every seed.  A *setting* is one string of ``FIELD=VALUE``
:class:`spgeo.vo.OdometryConfig` overrides separated by spaces or commas
(nested fields with dots, values Python literals; ``defaults`` or an empty
string: no override), applied with :func:`spgeo.configs.apply_overrides`;
a field the config does not have makes that setting's cells error rows.

Data sets: ``7scenes`` (frames ``0:N`` of ``--sevenscenes``, default the
shared redkitchen sequence, run by :func:`spgeo.apps.vo_run.run_dataset`, the
frames resized to the resolution) and ``synthetic`` (the rendered sequences of
:func:`spgeo.evaluation.vo.synthetic.synthetic_sequence`, rendered at the
resolution, run by :func:`~spgeo.evaluation.vo.synthetic.run_synthetic_vo`).

Each cell runs in a fresh Python process (``--in-process``: in this one, no
peak memory).  Columns: per-frame and keyframe-only Sim(3) ATE (metres and %
of the ground-truth path; frames flagged lost excluded), whole-pipeline FPS
and tracking FPS from the odometry's own report (frame loading, resizing and
rendering excluded), mapping and front-end seconds per keyframe, keyframes,
lost frames, the cell process's peak resident memory (``ru_maxrss``: imports,
data loading and rendering included) and the cell's wall time.  A cell that
fails is a row with its error.  With ``--workers N`` / ``--address ADDR``
the cells (each still in its own process) run on Ray
(:mod:`spgeo.evaluation.jobs`).  With ``--out DIR``: ``frontier.json``
(``rows``: every row, with seconds per stage and status counts; ``means``
per data set, front-end, resolution and setting; ``provenance``),
``frontier.csv`` (the rows) and ``frontier.md``, rewritten atomically after
each cell.  Exit status 1 when a cell failed.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import re
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from spgeo.apps.args import parse_resolution
from spgeo.apps.memory import peak_rss_mb
from spgeo.configs import apply_overrides, parse_assignments
from spgeo.evaluation.jobs import (EvalTable, Job, RunnerConfig, add_runner_arguments, provenance,
                                   run_table, runner_config)
from spgeo.evaluation.runner import protocol_argv, protocol_parser, run_protocol
from spgeo.evaluation.shared_data import shared_data_root

__all__ = ["Cell", "COLUMNS", "DEFAULT_SEVENSCENES", "parse_setting", "setting_config",
           "make_grid", "run_cell", "run_cell_subprocess", "make_jobs", "run_grid", "frontier_table",
           "markdown_table", "write_outputs", "build_parser", "run", "main"]

#: The shared 7-Scenes sequence (:func:`spgeo.evaluation.shared_data.shared_data_root`).
DEFAULT_SEVENSCENES = str(shared_data_root() / "7scenes_redkitchen_dev")
_RESULT_TAG = "VO_FRONTIER_RESULT "
_DEFAULT_FRAMES = {"7scenes": 300, "synthetic": 150}
_FIELD_START = re.compile(r"[\s,]+(?=[A-Za-z_][\w.]*\s*=)")

#: Row keys in table order (the CSV columns; the JSON rows hold these and more).
COLUMNS = ("dataset", "seed", "frontend", "resolution", "setting", "frames", "ate_m", "ate_pct",
           "kf_ate_m", "kf_ate_pct", "fps", "tracking_fps", "mapping_s_per_kf",
           "frontend_s_per_kf", "keyframes", "lost", "peak_rss_mb", "cell_wall_s", "error")


@dataclass(frozen=True)
class Cell:
    """One grid cell.

    Attributes:
        dataset: ``"7scenes"`` or ``"synthetic"``.
        frontend: front-end name (:func:`spgeo.frontend.make_frontend`).
        resolution: ``(width, height)`` pixels.
        setting: the ``FIELD=VALUE`` overrides string (``""``: defaults).
        frames: number of frames (7-Scenes: frames ``0:frames``).
        seed: synthetic seed (None for 7-Scenes).
        path: 7-Scenes sequence folder (None for synthetic).
    """

    dataset: str
    frontend: str
    resolution: Tuple[int, int]
    setting: str = ""
    frames: int = 150
    seed: Optional[int] = None
    path: Optional[str] = None


def parse_setting(text: str) -> List[str]:
    """``"a=1 b.c=(1, 2), d=None"`` -> ``["a=1", "b.c=(1, 2)", "d=None"]``:
    split on spaces / commas that precede ``NAME=`` (so tuple values keep
    theirs); ``"defaults"`` or blank -> ``[]``."""
    s = text.strip()
    if s.lower() in ("", "default", "defaults"):
        return []
    return [p.strip().rstrip(",").strip() for p in _FIELD_START.split(s) if p.strip(" ,")]


def setting_config(text: str):
    """``OdometryConfig()`` with the setting's overrides; raises
    :class:`spgeo.configs.ConfigError` (unknown field, wrong type) or
    ``ValueError`` / ``SyntaxError`` (a value that is not a Python literal)."""
    from spgeo.vo import OdometryConfig

    return apply_overrides(OdometryConfig(), parse_assignments(parse_setting(text), strict=True))


def make_grid(datasets: Sequence[str], frontends: Sequence[str],
              resolutions: Sequence[Tuple[int, int]], settings: Sequence[str],
              seeds: Sequence[int] = (0,), frames: Optional[int] = None,
              sevenscenes: str = DEFAULT_SEVENSCENES) -> List[Cell]:
    """Every (data set, front-end, resolution, setting[, seed]) cell, in that
    nesting order; ``frames`` None: 300 for 7-Scenes, 150 synthetic."""
    cells = []
    for ds in datasets:
        if ds not in _DEFAULT_FRAMES:
            raise ValueError(f"unknown data set {ds!r} (7scenes, synthetic)")
        n = frames or _DEFAULT_FRAMES[ds]
        for fe in frontends:
            for res in resolutions:
                for st in settings:
                    if ds == "7scenes":
                        cells.append(Cell(ds, fe, tuple(res), st, n, None, str(sevenscenes)))
                    else:
                        cells.extend(Cell(ds, fe, tuple(res), st, n, s) for s in seeds)
    return cells


def _base_row(cell: Cell) -> Dict[str, object]:
    row: Dict[str, object] = {k: None for k in COLUMNS}
    row.update(dataset=cell.dataset, seed=cell.seed, frontend=cell.frontend,
               resolution=f"{cell.resolution[0]}x{cell.resolution[1]}",
               setting=cell.setting.strip() or "defaults", frames=cell.frames)
    return row


def _fill(row: Dict[str, object], report: dict, ates: Dict[str, Optional[dict]]) -> None:
    """Row fields from :meth:`Odometry.report` and ``{label: {"rmse_m",
    "percent"} or None}``."""
    for label, key in (("per-frame", "ate"), ("keyframe-only", "kf_ate")):
        a = ates.get(label)
        row[f"{key}_m"] = None if a is None else float(a["rmse_m"])
        row[f"{key}_pct"] = None if a is None else float(a["percent"])
    n_kf = int(report["n_keyframes"])
    stages = report["seconds_per_stage"]
    row.update(fps=report["fps"], tracking_fps=report["tracking_fps"],
               mapping_s_per_kf=report["mapping_seconds_per_keyframe"],
               frontend_s_per_kf=stages["frontend"] / n_kf if n_kf else None,
               keyframes=n_kf, lost=int(report["status_counts"].get("lost", 0)),
               seconds_per_stage=stages, status_counts=report["status_counts"],
               segments=report["n_segments"])


def run_cell(cell: Cell) -> Dict[str, object]:
    """Run one cell in this process; the row (``peak_rss_mb`` None,
    ``error`` None).  Raises whatever the run raises."""
    t0 = time.perf_counter()
    row = _base_row(cell)
    cfg = setting_config(cell.setting)
    row["overrides"] = parse_assignments(parse_setting(cell.setting), strict=True)
    if cell.dataset == "7scenes":
        from spgeo.apps.vo_run import VORunConfig, run_dataset

        run = run_dataset("7scenes", cell.path, f"0:{cell.frames}",
                          VORunConfig(frontend=cell.frontend, progress=False,
                                      odometry=dataclasses.replace(cfg, resolution=cell.resolution)))
        ate = run.ate() or {}
        ates = {lab: None if a is None else {"rmse_m": a.rmse, "percent": a.rmse_percent_of_length}
                for lab, a in ate.items()}
        report = run.odometry.report()
    elif cell.dataset == "synthetic":
        from spgeo.evaluation.vo.synthetic import (SyntheticVOConfig, run_synthetic_vo,
                                                   synthetic_sequence)

        frames = synthetic_sequence(SyntheticVOConfig(cell.frames, int(cell.seed or 0),
                                                      size=cell.resolution))
        out = run_synthetic_vo(frames, cell.frontend, cfg)
        ates = {lab: out[lab] for lab in ("per-frame", "keyframe-only")}
        report = out["odometry"].report()
    else:
        raise ValueError(f"unknown data set {cell.dataset!r}")
    _fill(row, report, ates)
    row["cell_wall_s"] = time.perf_counter() - t0
    return row


def _child_main(cell_json: str) -> int:
    """Entry point of a cell's subprocess: the row as one tagged JSON line on stdout."""
    d = json.loads(cell_json)
    d["resolution"] = tuple(d["resolution"])
    row = run_cell(Cell(**d))
    row["peak_rss_mb"] = peak_rss_mb()
    sys.stdout.write(_RESULT_TAG + json.dumps(row, default=float) + "\n")
    return 0


def run_cell_subprocess(cell: Cell, timeout: Optional[float] = None) -> Dict[str, object]:
    """Run one cell in a fresh ``python -m spgeo.evaluation.vo.frontier``
    process; the row with its peak memory, or an error row (exception, exit
    status, timeout; the last stderr lines)."""
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "spgeo.evaluation.vo.frontier", "--_cell",
           json.dumps(asdict(cell))]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return _error_row(cell, f"timed out after {timeout} s", t0)
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(_RESULT_TAG):
            return json.loads(line[len(_RESULT_TAG):])
    tail = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()][-3:]
    return _error_row(cell, f"exit status {proc.returncode}: {' | '.join(tail) or 'no output'}", t0)


def _error_row(cell: Cell, message: str, t0: Optional[float] = None) -> Dict[str, object]:
    row = _base_row(cell)
    row["error"] = message
    if t0 is not None:
        row["cell_wall_s"] = time.perf_counter() - t0
    return row


def _cell_in_process(cell: Cell) -> Dict[str, object]:
    """:func:`run_cell` with a failure as an error row (its wall time kept)."""
    t0 = time.perf_counter()
    try:
        return run_cell(cell)
    except Exception as exc:  # a failed cell is a row, never a lost grid
        return _error_row(cell, f"{type(exc).__name__}: {exc}", t0)


def _cell_label(cell: Cell) -> str:
    seed = "" if cell.seed is None else f" seed{cell.seed}"
    return (f"{cell.dataset}{seed} {cell.frontend} {_base_row(cell)['resolution']} "
            f"{cell.setting.strip() or 'defaults'}")


def make_jobs(cells: Sequence[Cell], in_process: bool = False,
              timeout: Optional[float] = None) -> List[Job]:
    """One :class:`~spgeo.evaluation.jobs.Job` per cell: its subprocess
    (:func:`run_cell_subprocess`) unless ``in_process``; a setting that
    :func:`setting_config` rejects is an error row without a run."""
    bad: Dict[str, str] = {}
    for st in {c.setting for c in cells}:
        try:
            setting_config(st)
        except (ValueError, TypeError, SyntaxError) as exc:
            bad[st] = f"setting {st!r}: {exc}"
    jobs = []
    for i, cell in enumerate(cells):
        name = f"{i}: {_cell_label(cell)}"
        if cell.setting in bad:
            jobs.append(Job(name, _error_row, (cell, bad[cell.setting])))
        elif in_process:
            jobs.append(Job(name, _cell_in_process, (cell,)))
        else:
            jobs.append(Job(name, run_cell_subprocess, (cell, timeout)))
    return jobs


def run_grid(cells: Sequence[Cell], in_process: bool = False, timeout: Optional[float] = None,
             out: Optional[Path] = None, progress: bool = True,
             runner: Optional[RunnerConfig] = None,
             config: Optional[dict] = None) -> List[Dict[str, object]]:
    """Run every cell (subprocesses unless ``in_process``, also on Ray
    workers); one row per cell in grid order, failures as error rows.  A
    setting that :func:`setting_config` rejects is an error row without a
    run.  ``runner``: the backend (default sequential here; its ``progress``
    is replaced by ``progress``); ``out``: files rewritten after each cell
    (:func:`write_outputs`, ``config`` in their provenance)."""
    runner = dataclasses.replace(runner or RunnerConfig(), progress=progress, desc="vo_frontier")
    prov = provenance({"in_process": in_process, "timeout": timeout, "n_cells": len(cells),
                       **(config or {})}, runner)
    table = run_table(make_jobs(cells, in_process, timeout), runner,
                      lambda rows: frontier_table(rows, prov), out, "frontier")
    return table.rows


_TABLE = (("data", "dataset", 0), ("seed", "seed", 0), ("front-end", "frontend", 0),
          ("res", "resolution", 0), ("setting", "setting", 0), ("frames", "frames", 0),
          ("ATE m", "ate_m", 4), ("ATE %", "ate_pct", 2), ("KF ATE m", "kf_ate_m", 4),
          ("FPS", "fps", 1), ("track FPS", "tracking_fps", 1), ("map s/KF", "mapping_s_per_kf", 2),
          ("fe s/KF", "frontend_s_per_kf", 2), ("KFs", "keyframes", 0), ("lost", "lost", 0),
          ("peak MB", "peak_rss_mb", 0), ("cell s", "cell_wall_s", 1), ("error", "error", 0))
_NOTE = ("ATE: Sim(3)-aligned RMSE of camera centres (evo), per-frame = every frame not lost, "
         "% of the ground-truth path; FPS from the odometry's own timings (loading excluded); "
         "peak MB = the cell process's maximum resident memory.")


def frontier_table(rows: Sequence[Dict[str, object]],
                   prov: Optional[dict] = None) -> EvalTable:
    """The rows as an :class:`~spgeo.evaluation.jobs.EvalTable` (means per
    data set, front-end, resolution and setting over the seeds; CSV columns
    :data:`COLUMNS`)."""
    return EvalTable(list(rows), _TABLE, group_by=("dataset", "frontend", "resolution", "setting"),
                     id_keys=("seed", "frames"), provenance=dict(prov or {}),
                     csv_columns=COLUMNS, note=_NOTE)


def markdown_table(rows: Sequence[Dict[str, object]]) -> str:
    """The rows as one markdown table (``-`` for missing values; errors shortened)."""
    return frontier_table(rows).markdown(rows_only=True)


def write_outputs(rows: Sequence[Dict[str, object]], out: Path,
                  prov: Optional[dict] = None) -> Dict[str, Path]:
    """``out/frontier.json`` (``{"rows": every key, "means", "provenance"}``),
    ``frontier.csv`` (:data:`COLUMNS`) and ``frontier.md``, each written
    atomically; returns the paths."""
    return frontier_table(rows, prov).write(Path(out), "frontier")


NAME = "vo_frontier"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--datasets", nargs="+", default=["7scenes", "synthetic"],
                    choices=sorted(_DEFAULT_FRAMES))
    ap.add_argument("--sevenscenes", default=DEFAULT_SEVENSCENES, metavar="PATH",
                    help="7-Scenes sequence folder (default %(default)s)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames per run (default 300 for 7-Scenes, 150 synthetic)")
    ap.add_argument("--resolutions", nargs="+", default=["160x120"], metavar="WxH")
    ap.add_argument("--frontends", nargs="+", default=["classical"])
    ap.add_argument("--set-grid", nargs="+", default=["defaults"], metavar="SETTING",
                    help="one string per setting: FIELD=VALUE overrides separated by spaces "
                         "or commas ('defaults': none), e.g. 'mapping.level=0 tracker.levels=4'")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="synthetic seeds")
    ap.add_argument("--in-process", action="store_true",
                    help="run the cells in this process (no peak memory)")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per cell")
    ap.add_argument("--out", default=None, help="write frontier.json/.csv/.md here")
    ap.add_argument("--no-progress", action="store_true")
    add_runner_arguments(ap)
    return ap


def run(args: argparse.Namespace) -> int:
    """Run the grid (:func:`run_grid`), print :func:`frontier_table`, one stderr line
    per failed cell; 1 when a cell failed.  ValueError for a bad argument."""
    if args.frames is not None and args.frames < 3:
        raise ValueError("--frames must be >= 3")
    resolutions = [parse_resolution(r) for r in args.resolutions]
    cells = make_grid(args.datasets, args.frontends, resolutions, args.set_grid, args.seeds,
                      args.frames, args.sevenscenes)
    runner = runner_config(args, desc="vo_frontier")
    config = {k: getattr(args, k) for k in ("datasets", "frames", "resolutions", "frontends",
                                            "set_grid", "seeds", "sevenscenes")}
    rows = run_grid(cells, args.in_process, args.timeout, Path(args.out) if args.out else None,
                    not args.no_progress, runner, config)
    print(frontier_table(rows, provenance(config, runner)).markdown())
    for r in rows:
        if r.get("error"):
            print(f"error: {r['dataset']} {r['frontend']} {r['resolution']} {r['setting']}: "
                  f"{r['error']}", file=sys.stderr)
    return 1 if any(r.get("error") for r in rows) else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The protocol; ``--_cell JSON`` runs one cell (the child process of
    :func:`run_cell_subprocess`)."""
    argv = protocol_argv(argv)
    if argv[:1] == ["--_cell"]:
        return _child_main(argv[1])
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
