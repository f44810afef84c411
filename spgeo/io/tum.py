"""TUM trajectory files and per-frame status files as :mod:`spgeo.io` offers them.

The format and the one reader / writer are :mod:`spgeo.tum_files` (plain arrays,
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
