"""Evaluation jobs: run a protocol's jobs locally or on Ray, merge the rows into one table.

A protocol is a list of :class:`Job` s: a name, a picklable callable (a
module-level function) with its arguments, returning one dict row, and the
identifying fields (``meta``) every row of that job carries, failed or not.
:func:`run_jobs` runs them

* ``local`` (default): one after the other in this process;
* ``ray``: as ``ray.remote`` tasks, one CPU each, on an embedded local Ray
  started with ``num_cpus=workers`` (``--workers N``) or on an existing
  cluster (``--address ADDR``; spgeo must be installed on its nodes).  Ray is
  imported only then (``pip install spgeo[distributed]``); the workers run
  with one OpenMP / BLAS / numba thread, and a Ray started here is shut
  down afterwards.

The rows come back in the order of the jobs, whatever the order of
completion; a job that raises (or whose Ray worker dies) is a row with its
``meta`` and ``error = "ExceptionType: message"``, never a lost run.  Every
row has an ``error`` key (None when it ran) and ``job`` (its name).

:class:`EvalTable` merges the rows: the per-job rows, the means over the
successful rows (per group), and the :func:`provenance` (git commit, the
protocol's configuration, the runner, the machine), written as markdown,
JSON and CSV, each atomically (:func:`write_atomic`).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import math
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from spgeo.evaluation.tables import cell, markdown_table

__all__ = ["Job", "RunnerConfig", "add_runner_arguments", "runner_config", "run_job",
           "run_jobs", "run_table", "provenance", "mean_rows", "EvalTable", "write_atomic", "THREAD_ENV"]

logger = logging.getLogger(__name__)

#: Environment of the Ray workers: one thread per worker (deterministic, no oversubscription).
THREAD_ENV = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                     "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")}


@dataclass(frozen=True)
class Job:
    """One unit of a protocol.

    Attributes:
        name: unique, human-readable (a progress bar / error label).
        fn: module-level callable (picklable by reference), ``fn(*args,
            **kwargs) -> dict`` (the row).
        args, kwargs: its picklable arguments.
        meta: fields copied into the row, first (also into an error row).
    """

    name: str
    fn: Callable[..., Dict[str, Any]]
    args: Tuple[Any, ...] = ()
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    meta: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RunnerConfig:
    """How :func:`run_jobs` runs the jobs.

    Attributes:
        workers: Ray CPUs of an embedded local Ray (0: local backend unless
            ``address`` is set).
        address: address of an existing Ray cluster (``"auto"``,
            ``"ray://host:10001"``, ``"host:6379"``); None: none.
        progress: tqdm progress bar across the jobs.
        desc: the bar's label.
    """

    workers: int = 0
    address: Optional[str] = None
    progress: bool = True
    desc: str = "eval"

    def __post_init__(self) -> None:
        if int(self.workers) < 0:
            raise ValueError(f"RunnerConfig.workers must be >= 0, got {self.workers}")

    @property
    def backend(self) -> str:
        """``"ray"`` when ``workers`` or ``address`` is set, else ``"local"``."""
        return "ray" if (self.workers or self.address) else "local"

    def describe(self) -> Dict[str, Any]:
        return {"backend": self.backend, "workers": self.workers or None, "address": self.address}


def add_runner_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--workers N`` and ``--address ADDR`` (see :func:`runner_config`)."""
    g = parser.add_argument_group("distributed (Ray; pip install spgeo[distributed])")
    g.add_argument("--workers", type=int, default=0, metavar="N",
                   help="run the jobs on an embedded local Ray with N CPUs (default 0: "
                        "sequentially in this process)")
    g.add_argument("--address", default=None, metavar="ADDR",
                   help="run the jobs on an existing Ray cluster (e.g. 'auto', "
                        "'ray://head:10001')")


def runner_config(args: argparse.Namespace, desc: str = "eval",
                  progress: Optional[bool] = None) -> RunnerConfig:
    """:class:`RunnerConfig` from :func:`add_runner_arguments`' options
    (``progress`` None: not ``args.no_progress`` when present, else True).
    Raises ``ValueError`` for a negative ``--workers``."""
    if progress is None:
        progress = not getattr(args, "no_progress", False)
    return RunnerConfig(workers=int(args.workers or 0), address=args.address,
                        progress=progress, desc=desc)


# ------------------------------------------------------------------ running
def _error_row(job: Job, exc: BaseException) -> Dict[str, Any]:
    return {"job": job.name, **dict(job.meta), "error": f"{type(exc).__name__}: {exc}"}


def _importable(job: Job) -> Job:
    """``job`` with a ``fn`` defined in ``__main__`` (``python -m MODULE``)
    replaced by the same function of the module imported by name, so that
    Ray workers (whose ``__main__`` is theirs) unpickle it by reference."""
    import importlib

    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if getattr(job.fn, "__module__", None) != "__main__" or spec is None:
        return job
    fn = getattr(importlib.import_module(spec.name), job.fn.__qualname__, None)
    if fn is None:
        return job
    return Job(job.name, fn, job.args, job.kwargs, job.meta)


def run_job(job: Job) -> Dict[str, Any]:
    """``job``'s row: ``{"job", **meta, **fn(...)}`` with ``error`` None, or
    the error row when ``fn`` raises an ``Exception`` or returns no dict."""
    try:
        out = job.fn(*job.args, **dict(job.kwargs))
        if not isinstance(out, Mapping):
            raise TypeError(f"job {job.name!r} returned {type(out).__name__}, not a dict")
    except Exception as exc:  # a failed job is a row, never a lost run
        logger.warning("job %s failed: %s: %s", job.name, type(exc).__name__, exc,
                       exc_info=logger.isEnabledFor(logging.DEBUG))
        return _error_row(job, exc)
    row = {"job": job.name, **dict(job.meta), **dict(out)}
    row.setdefault("error", None)
    return row


def run_jobs(jobs: Sequence[Job], config: RunnerConfig = RunnerConfig(),
             on_row: Optional[Callable[[int, Dict[str, Any]], None]] = None
             ) -> List[Dict[str, Any]]:
    """Run every job (:class:`RunnerConfig` picks the backend); the rows in
    the order of ``jobs``.  ``on_row(index, row)`` is called in this process
    as each job finishes (completion order).  Raises ``ImportError`` (with
    the install hint) when Ray is asked for and missing, ``ValueError`` for
    duplicate job names."""
    from tqdm import tqdm

    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ValueError(f"run_jobs: duplicate job names in {names}")
    rows: List[Optional[Dict[str, Any]]] = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc=config.desc, unit="job", disable=not config.progress,
               dynamic_ncols=True)

    def done(i: int, row: Dict[str, Any]) -> None:
        rows[i] = row
        bar.set_postfix_str(f"{jobs[i].name}{' FAILED' if row.get('error') else ''}",
                            refresh=False)
        bar.update(1)
        if on_row is not None:
            on_row(i, row)

    try:
        if config.backend == "local":
            for i, job in enumerate(jobs):
                bar.set_postfix_str(job.name, refresh=True)
                done(i, run_job(job))
        else:
            _run_ray(jobs, config, done)
    finally:
        bar.close()
    return [r for r in rows if r is not None]


def _run_ray(jobs: Sequence[Job], config: RunnerConfig,
             done: Callable[[int, Dict[str, Any]], None]) -> None:
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("--workers/--address need Ray: pip install 'spgeo[distributed]' "
                          "(or 'ray[default]')") from exc
    started = False
    if not ray.is_initialized():
        kw = dict(runtime_env={"env_vars": dict(THREAD_ENV)}, include_dashboard=False,
                  log_to_driver=False, logging_level=logging.WARNING)
        if config.address:
            ray.init(address=config.address, **kw)
        else:
            ray.init(num_cpus=int(config.workers), **kw)
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
        index = {task.remote(_importable(job)): i for i, job in enumerate(jobs)}
        pending = list(index)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                i = index[ref]
                try:
                    row = ray.get(ref)
                except Exception as exc:  # worker crashed, out of memory, cancelled
                    lines = [ln for ln in str(exc).splitlines() if ln.strip()]
                    row = {"job": jobs[i].name, **dict(jobs[i].meta),
                           "error": f"{type(exc).__name__}: {lines[-1] if lines else ''}"}
                done(i, row)
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------ provenance
def _git(args: Sequence[str], cwd: Path) -> Optional[str]:
    try:
        p = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def provenance(config: Optional[Mapping[str, Any]] = None,
               runner: Optional[RunnerConfig] = None) -> Dict[str, Any]:
    """Where a table comes from: ``commit`` (``git rev-parse HEAD`` of the
    checkout spgeo is imported from, else ``"spgeo <version>"``), ``dirty``
    (uncommitted changes to tracked files; None outside git), ``spgeo``
    version, ``python``, ``hostname``, ``cpu_count``, ``platform``, ``argv``,
    ``time`` (UTC, ISO 8601), the protocol's ``config`` and the ``runner``."""
    import spgeo

    here = Path(spgeo.__file__).resolve().parent
    commit = _git(["rev-parse", "HEAD"], here)
    status = _git(["status", "--porcelain", "--untracked-files=no"], here) if commit else None
    return {"commit": commit or f"spgeo {spgeo.__version__}",
            "dirty": None if status is None else bool(status),
            "spgeo": spgeo.__version__, "python": platform.python_version(),
            "hostname": socket.gethostname(), "cpu_count": os.cpu_count(),
            "platform": platform.platform(), "argv": list(sys.argv),
            "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "config": dict(config or {}),
            "runner": (runner or RunnerConfig()).describe()}


# ------------------------------------------------------------------ the table
def _number(v: Any) -> Optional[float]:
    """A finite float from a Python / numpy number; None for anything else (bools too)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def mean_rows(rows: Sequence[Mapping[str, Any]], keys: Sequence[str],
              group_by: Sequence[str] = ()) -> List[Dict[str, Any]]:
    """Per group (the distinct ``group_by`` values, in first-appearance
    order): the group's fields, ``n`` (rows without error), ``failed`` and,
    per key in ``keys``, the mean of its finite numeric values over the rows
    without error (None if there are none)."""
    groups: Dict[Tuple, List[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(g) for g in group_by), []).append(r)
    out = []
    for gvals, members in groups.items():
        ok = [r for r in members if not r.get("error")]
        m: Dict[str, Any] = dict(zip(group_by, gvals))
        m.update(n=len(ok), failed=len(members) - len(ok))
        for k in keys:
            if k in group_by:
                continue
            vals = [x for x in (_number(r.get(k)) for r in ok) if x is not None]
            m[k] = sum(vals) / len(vals) if vals else None
        out.append(m)
    return out


def _md(columns: Sequence[Tuple[str, str, int]], rows: Sequence[Mapping[str, Any]],
        max_error: int = 120) -> List[str]:
    """:func:`~spgeo.evaluation.tables.markdown_table` of ``columns`` ``(header,
    key, digits)`` over ``rows`` (cells by :func:`~spgeo.evaluation.tables.cell`);
    an ``error`` cell longer than ``max_error`` is cut with ``...``."""
    def text(key: str, digits: int, r: Mapping[str, Any]) -> str:
        s = cell(r.get(key), digits)
        return s[:max_error - 3] + "..." if key == "error" and len(s) > max_error else s

    return markdown_table([h for h, _, _ in columns],
                          [[text(k, d, r) for _, k, d in columns] for r in rows])


@dataclass
class EvalTable:
    """Merged rows of a protocol.

    Attributes:
        rows: one dict per job (:func:`run_jobs`), in job order.
        columns: ``(header, key, digits)`` of the markdown table (digits:
            decimals of float values); the CSV has the keys (or
            ``csv_columns``).
        group_by: keys whose distinct values get their own mean row.
        id_keys: numeric keys that identify a row (a seed, a frame count):
            never averaged.
        provenance: :func:`provenance`.
        csv_columns: CSV columns (default: the keys of ``columns``).
        note: text printed under the markdown table (units, protocol).
    """

    rows: List[Dict[str, Any]]
    columns: Sequence[Tuple[str, str, int]]
    group_by: Sequence[str] = ()
    id_keys: Sequence[str] = ()
    provenance: Dict[str, Any] = field(default_factory=dict)
    csv_columns: Optional[Sequence[str]] = None
    note: str = ""

    @property
    def means(self) -> List[Dict[str, Any]]:
        """:func:`mean_rows` over the table's numeric columns."""
        return mean_rows(self.rows, self._mean_keys(), self.group_by)

    def _mean_keys(self) -> List[str]:
        skip = {"error", *self.group_by, *self.id_keys}
        return [k for _, k, _ in self.columns if k not in skip]

    @property
    def failed(self) -> List[Dict[str, Any]]:
        return [r for r in self.rows if r.get("error")]

    def markdown(self, rows_only: bool = False) -> str:
        """The rows' table; unless ``rows_only``, the note, the means table and
        a provenance line."""
        lines = _md(self.columns, self.rows)
        if rows_only:
            return "\n".join(lines)
        if self.note:
            lines += ["", self.note]
        mean_cols = ([(g, g, 0) for g in self.group_by] + [("n ok", "n", 0), ("failed", "failed", 0)]
                     + [c for c in self.columns if c[1] in self._mean_keys()
                        and any(_number(r.get(c[1])) is not None for r in self.rows)])
        lines += ["", "Means over the rows without error:", ""] + _md(mean_cols, self.means)
        p = self.provenance
        if p:
            run = p.get("runner", {})
            lines += ["", f"Provenance: commit {p.get('commit')}"
                      f"{' (uncommitted changes)' if p.get('dirty') else ''}, spgeo "
                      f"{p.get('spgeo')}, Python {p.get('python')}, {p.get('hostname')} "
                      f"({p.get('cpu_count')} CPUs), backend {run.get('backend')}"
                      f"{' x' + str(run['workers']) if run.get('workers') else ''}"
                      f"{' at ' + run['address'] if run.get('address') else ''}, {p.get('time')}."]
        return "\n".join(lines)

    def to_dict(self) -> Dict[str, Any]:
        return {"rows": list(self.rows), "means": self.means, "provenance": self.provenance}

    def csv(self) -> str:
        buf = io.StringIO()
        cols = list(self.csv_columns or [k for _, k, _ in self.columns])
        w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        w.writerows(self.rows)
        return buf.getvalue()

    def write(self, out: Path, stem: str) -> Dict[str, Path]:
        """``out/<stem>.md``, ``.json`` (rows, means, provenance) and ``.csv``
        (the rows), each written atomically; returns the paths."""
        from spgeo.jsonio import json_default

        out = Path(out)
        paths = {ext: out / f"{stem}.{ext}" for ext in ("md", "json", "csv")}
        write_atomic(paths["json"], json.dumps(self.to_dict(), indent=1, default=json_default))
        write_atomic(paths["csv"], self.csv())
        write_atomic(paths["md"], self.markdown() + "\n")
        return paths


def run_table(jobs: Sequence[Job], runner: RunnerConfig,
              make_table: Callable[[List[Dict[str, Any]]], EvalTable],
              out: Optional[Path] = None, stem: str = "results") -> EvalTable:
    """:func:`run_jobs`, then ``make_table(rows)``; with ``out``, the table of
    the rows finished so far (in job order) is rewritten after each job
    (:meth:`EvalTable.write`), so an interrupted run keeps what it did."""
    finished: Dict[int, Dict[str, Any]] = {}

    def on_row(i: int, row: Dict[str, Any]) -> None:
        finished[i] = row
        make_table([finished[k] for k in sorted(finished)]).write(out, stem)

    table = make_table(run_jobs(jobs, runner, on_row if out is not None else None))
    if out is not None:
        table.write(out, stem)
    return table


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder
    and ``os.replace`` (readers never see a partial file); creates the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
