"""TUM trajectory files and per-frame status files.

TUM format (one pose per line, camera-to-world ``T_world_cam``)::

    # comment lines start with '#'
    timestamp tx ty tz qx qy qz qw

Quaternions are Hamilton ``(qx, qy, qz, qw)`` (:mod:`spgeo.geometry`).  Files
written here have exactly 8 space-separated columns per pose line, so
``evo_ape tum gt.txt est.txt -as`` reads them unchanged.  Per-frame status flags
go into a separate ``timestamp status [extra...]`` file, by default
``<stem>.status.txt`` beside the trajectory (evo rejects extra columns).  Frames
without a pose are omitted from the trajectory file and appear only in the
status file.  The file reading and writing is :mod:`spgeo.tum_files` (plain arrays,
re-exported here); :func:`read_tum` gives a :class:`~spgeo.trajectory.Trajectory`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Union

from spgeo.trajectory import Trajectory
from spgeo.tum_files import read_status, read_tum_arrays, status_path_for, write_status, write_tum

__all__ = ["read_tum", "write_tum", "status_path_for", "write_status", "read_status"]

PathLike = Union[str, Path]


def read_tum(path: PathLike) -> Trajectory:
    """Read a TUM trajectory file as a :class:`~spgeo.trajectory.Trajectory` (status ``ok``).

    Skips blank lines and lines starting with ``#``; text after a ``#`` on a
    pose line is ignored too (files written by other tools).  Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` (naming the file
    and line) for a line without 8 finite numbers or an invalid quaternion.
    """
    return Trajectory(*read_tum_arrays(path))
