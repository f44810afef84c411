"""TUM trajectory files and per-frame status files, as plain arrays.

TUM format (one pose per line, camera-to-world ``T_world_cam``)::

    # comment lines start with '#'
    timestamp tx ty tz qx qy qz qw

Quaternions are Hamilton ``(qx, qy, qz, qw)`` (:mod:`spgeo.geometry`).  Files
written here have exactly 8 space-separated columns per pose line, so
``evo_ape tum gt.txt est.txt -as`` reads them unchanged.  Per-frame status flags
go into a separate ``timestamp status [extra...]`` file, by default
``<stem>.status.txt`` beside the trajectory (evo rejects extra columns).  Frames
without a pose are omitted from the trajectory file and appear only in the
status file.  This is the one TUM reader/writer of the project; it knows no
:class:`~spgeo.trajectory.Trajectory`, which builds on it
(:meth:`~spgeo.trajectory.Trajectory.save`, :meth:`~spgeo.trajectory.Trajectory.load`),
as does :func:`spgeo.io.tum.read_tum`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.geometry import pose_from_tum, pose_to_tum

__all__ = ["read_tum_arrays", "write_tum", "status_path_for", "write_status", "read_status"]

PathLike = Union[str, Path]


def read_tum_arrays(path: PathLike) -> Tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file as ``(timestamps (n,), poses (n, 4, 4) T_world_cam)``.

    Skips blank lines and lines starting with ``#``; text after a ``#`` on a
    pose line is ignored too (files written by other tools).  Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` (naming the file
    and line) for a line without 8 finite numbers or an invalid quaternion.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trajectory file not found: {path}")
    stamps: List[float] = []
    poses: List[np.ndarray] = []
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise ValueError(f"{path}:{lineno}: expected 8 columns "
                             f"'timestamp tx ty tz qx qy qz qw', got {len(parts)}")
        try:
            values = np.array([float(p) for p in parts])
            pose = pose_from_tum(values[1:])
        except ValueError as exc:
            raise ValueError(f"{path}:{lineno}: {exc}") from None
        if not math.isfinite(values[0]):
            raise ValueError(f"{path}:{lineno}: non-finite timestamp")
        stamps.append(float(values[0]))
        poses.append(pose)
    return np.array(stamps, dtype=np.float64), np.array(poses).reshape(-1, 4, 4)


def write_tum(path: PathLike, timestamps: Sequence[float], poses: Sequence[np.ndarray],
              header: Optional[Sequence[str]] = None) -> int:
    """Write a TUM trajectory file (8 columns, camera-to-world).

    Poses that are ``None`` or contain non-finite values are skipped (a frame
    without a pose has no line).  ``header`` lines are written as ``# ``
    comments first.  Creates the parent folder.  Returns the number of pose
    lines written.
    """
    path = Path(path)
    timestamps = list(timestamps)
    poses = list(poses)
    if len(timestamps) != len(poses):
        raise ValueError(f"write_tum: {len(timestamps)} timestamps for {len(poses)} poses")
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    lines = [f"# {h}" for h in (header or [])]
    lines.append("# timestamp tx ty tz qx qy qz qw (camera-to-world)")
    for ts, T in zip(timestamps, poses):
        if T is None:
            continue
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            continue
        v = pose_to_tum(T)
        lines.append(f"{float(ts):.6f} " + " ".join(f"{x:.9f}" for x in v))
        n += 1
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return n


def status_path_for(trajectory_path: PathLike) -> Path:
    """``DIR/stem.status.txt`` beside ``DIR/stem.txt``."""
    p = Path(trajectory_path)
    return p.with_name(p.stem + ".status.txt")


def write_status(path: PathLike, timestamps: Sequence[float], status: Sequence[str],
                 extra: Optional[Dict[str, Sequence[object]]] = None) -> None:
    """Write ``timestamp status [extra columns...]`` per frame (``#`` header).

    Status strings must not contain whitespace.  ``extra`` maps column names to
    per-frame values (e.g. ``{"keyframe": [0, 1, ...]}``).
    """
    timestamps, status = list(timestamps), list(status)
    if len(timestamps) != len(status):
        raise ValueError(f"write_status: {len(timestamps)} timestamps for {len(status)} flags")
    extra = dict(extra or {})
    for k, v in extra.items():
        if len(v) != len(status):
            raise ValueError(f"write_status: column {k!r} has {len(v)} values for "
                             f"{len(status)} frames")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# timestamp status " + " ".join(extra)]
    for i, (ts, s) in enumerate(zip(timestamps, status)):
        s = str(s)
        if not s or any(c.isspace() for c in s):
            raise ValueError(f"write_status: invalid status {s!r}")
        cols = [f"{float(ts):.6f}", s] + [str(v[i]) for v in extra.values()]
        lines.append(" ".join(cols))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_status(path: PathLike, with_columns: bool = False):
    """Read a status file written by :func:`write_status`.

    Returns ``(timestamps, statuses)``, or with ``with_columns``
    ``(timestamps, statuses, {column name: [str values]})`` for the extra
    columns named in the ``#`` header.  Raises ``FileNotFoundError`` or
    ``ValueError`` naming the file and line.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"status file not found: {path}")
    stamps, status = [], []
    names: List[str] = []
    columns: Dict[str, List[str]] = {}
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            head = line[1:].split()
            if not stamps and head[:2] == ["timestamp", "status"]:
                names = head[2:]
                columns = {n: [] for n in names}
            continue
        parts = line.split()
        if len(parts) < 2:
            raise ValueError(f"{path}:{lineno}: expected 'timestamp status'")
        try:
            stamps.append(float(parts[0]))
        except ValueError:
            raise ValueError(f"{path}:{lineno}: bad timestamp {parts[0]!r}") from None
        status.append(parts[1])
        if with_columns:
            if len(parts) != 2 + len(names):
                raise ValueError(f"{path}:{lineno}: expected {2 + len(names)} columns, "
                                 f"got {len(parts)}")
            for n, v in zip(names, parts[2:]):
                columns[n].append(v)
    if with_columns:
        return np.array(stamps), status, columns
    return np.array(stamps), status
