"""Outputs that are either complete or absent: atomic files and staged folders.

* :func:`prepare_output_file` / :func:`write_bytes_atomic`: one file, written to a
  temporary name in its folder and renamed over the target (``os.replace``), so a
  reader never sees half a file and a failure leaves the previous file unchanged.
* :class:`StagedFolder`: a command's output folder.  The location is checked
  before any work (:func:`check_output_folder`); the run writes into a temporary
  sibling folder; :meth:`StagedFolder.commit` writes the manifest
  :data:`MANIFEST` (status, command, time, and ``"files"``: every file of the
  folder with what it is and its units, :func:`describe_folder`) and renames the
  folder into place,
  replacing a previous spgeo output as a whole (two runs are never mixed in one
  folder).  Leaving the ``with`` block without a commit (an exception, Ctrl-C)
  removes the temporary folder and leaves the target as it was.
* :func:`replace_dir`: the rename-into-place step, and :func:`staged_directory`,
  a folder written under a temporary sibling name and renamed into place
  (the exports of :mod:`spgeo.io.colmap_export` and :mod:`spgeo.io.nerfstudio_export`).
* :func:`check_writable_parent`: the parent of an output folder exists (or is
  created) and a folder can really be made in it.

A folder is recognised as a previous spgeo output by its manifest; a non-empty
folder without one is never replaced or written into.

What a file is (:class:`FileInfo`) is said once, by the code that writes it: a
writer returns its paths and keeps a table of descriptions beside its code
(``spgeo vo``: :meth:`spgeo.apps.vo_outcome.VORun.describe_files`); a command
passes them to :meth:`StagedFolder.commit`.  Files nobody described get the
generic description of :data:`FILE_REGISTRY` (``report.json``), else
``"what": null``: the manifest lists every file either way.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import Dict, Iterator, List, Mapping, Optional, Union

from ..validation import InputError

__all__ = ["MANIFEST", "prepare_output_file", "write_bytes_atomic", "replace_dir",
           "staged_directory", "check_writable_parent", "check_output_folder", "read_manifest",
           "StagedFolder", "FileInfo", "FILE_REGISTRY", "describe_folder"]

PathLike = Union[str, os.PathLike]

#: the manifest file of an spgeo output folder (JSON: status, command, time, files)
MANIFEST = ".spgeo-output.json"


@dataclass(frozen=True)
class FileInfo:
    """What one output file is: a manifest entry's ``"what"`` and ``"units"``.

    Attributes:
        what: what the file holds and its format, in a sentence.
        units: the units of its numbers (positions, timestamps), or None where
            none apply.
    """

    what: str
    units: Optional[str] = None


#: generic descriptions of files that several commands write with one meaning, by
#: :func:`fnmatch.fnmatchcase` pattern of the path relative to the output folder ('/'
#: separators); used where the command described nothing (:func:`describe_folder`)
FILE_REGISTRY: Dict[str, FileInfo] = {
    "report.json": FileInfo("the command's report (JSON): statistics, configuration and "
                            "results", "as each key says"),
}


def describe_folder(folder: PathLike, described: Optional[Mapping[PathLike, FileInfo]] = None,
                    registry: Optional[Mapping[str, FileInfo]] = None) -> List[Dict[str, object]]:
    """One manifest entry per file under ``folder`` (recursively, sorted by path;
    the manifest :data:`MANIFEST` itself left out): ``{"path": relative path with
    '/' separators, "what", "units", "bytes"}``.

    ``described`` maps a file's path (absolute, or relative to ``folder``) to its
    :class:`FileInfo`; a file it does not name gets the first matching pattern
    of ``registry`` (default :data:`FILE_REGISTRY`), else ``what`` and ``units``
    None.  A described path that is not a file of the folder raises
    ``ValueError`` (a description of a file that was not written).
    """
    root = Path(folder)
    registry = FILE_REGISTRY if registry is None else registry
    infos: Dict[str, FileInfo] = {}
    for path, info in (described or {}).items():
        p = Path(path)
        rel = (p.relative_to(root) if p.is_absolute() else p).as_posix()
        if not (root / rel).is_file():
            raise ValueError(f"describe_folder: {rel} is described but is not a file of {root}")
        infos[rel] = info
    entries = []
    for p in sorted(q for q in root.rglob("*") if q.is_file()):
        rel = p.relative_to(root).as_posix()
        if rel == MANIFEST:
            continue
        info = infos.get(rel) or next((v for k, v in registry.items() if fnmatchcase(rel, k)),
                                      None)
        entries.append({"path": rel, "what": None if info is None else info.what,
                        "units": None if info is None else info.units,
                        "bytes": p.stat().st_size})
    return entries


def prepare_output_file(path: PathLike, what: str = "output") -> str:
    """Check that a file can be written at ``path`` before any work is done.

    Creates the parent folder if needed.  Raises :class:`InputError` when
    ``path`` is a folder, when the parent cannot be created (a file in its
    way) or is not writable; returns ``os.fspath(path)``.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise InputError(f"{what} path {path} is a folder; expected a file name")
    folder = os.path.dirname(os.path.abspath(path))
    _make_folder(folder, f"the folder of {what} {path}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {what} {path}: folder {folder} is not writable")
    return path


def _make_folder(folder: str, what: str) -> None:
    try:
        os.makedirs(folder, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"cannot create {what}: a file is in the way") from None
    except OSError as exc:
        raise InputError(f"cannot create {what}: {exc.strerror or exc}") from None


def _cannot_write(what: str, path: PathLike, folder: PathLike, exc: OSError) -> InputError:
    """The error of a temporary file or folder that cannot be created in ``folder``."""
    return InputError(f"cannot write {what} {path}: {exc.strerror or exc} (in folder {folder})")


def write_bytes_atomic(path: PathLike, data: bytes, what: str = "output") -> str:
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder,
    then ``os.replace`` (readers never see a partial file; on any error the
    temporary file is removed and an existing ``path`` is left unchanged).
    Checks the location with :func:`prepare_output_file`; returns the path."""
    path = prepare_output_file(path, what)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp",
                                   dir=folder)
    except OSError as exc:
        raise _cannot_write(what, path, folder, exc) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)   # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def replace_dir(new: Path, target: Path) -> None:
    """Rename folder ``new`` onto ``target`` (same file system), moving an existing
    ``target`` aside first and deleting it afterwards; on failure the old
    ``target`` is put back."""
    new, target = Path(new), Path(target)
    old: Optional[Path] = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
        os.rename(target, old / "x")
    try:
        os.rename(new, target)
    except BaseException:
        if old is not None:
            os.rename(old / "x", target)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def read_manifest(folder: PathLike) -> Optional[dict]:
    """The manifest of an spgeo output folder, or None when there is none
    (or it cannot be read)."""
    try:
        return json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def check_output_folder(path: PathLike, what: str = "--out") -> Path:
    """``path`` as an absolute Path after checking, before any work, that a run may
    write its output folder there: absent (its parent creatable and writable), an
    empty folder, or a previous spgeo output (it holds :data:`MANIFEST`).  Raises
    :class:`InputError` naming the path otherwise (a file, a folder holding other
    files, a parent that is a file or not writable)."""
    p = Path(os.path.abspath(os.fspath(path)))
    if p.exists() or p.is_symlink():
        if not p.is_dir():
            raise InputError(f"{what} {path} exists and is not a folder")
        if any(p.iterdir()) and read_manifest(p) is None:
            raise InputError(f"{what} {path} is a folder holding files that spgeo did not "
                             f"write (no {MANIFEST}); give an empty or new folder, or the "
                             "folder of a previous spgeo run to replace it")
    check_writable_parent(p, what)
    return p


def check_writable_parent(path: PathLike, what: str = "output") -> Path:
    """The parent folder of ``path`` (a folder to be written by renaming a
    temporary sibling into place), after creating it if needed and making and
    removing a probe folder in it.  Raises :class:`InputError` naming ``path``
    when it cannot be created (a file in the way) or written."""
    p = Path(os.path.abspath(os.fspath(path)))
    parent = p.parent
    _make_folder(str(parent), f"the parent folder of {what} {path}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {what} {path}: folder {parent} is not writable")
    try:    # a real probe (os.access says yes to root, and on some file systems)
        os.rmdir(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".probe", dir=parent))
    except OSError as exc:
        raise _cannot_write(what, path, parent, exc) from None
    return parent


@contextlib.contextmanager
def staged_directory(target: PathLike) -> Iterator[Path]:
    """``with staged_directory(target) as tmp:`` write the folder's content under
    ``tmp`` (a new temporary sibling of ``target``); on a normal exit ``tmp``
    replaces ``target`` (:func:`replace_dir`), on an exception it is removed and
    ``target`` is left as it was.  The parent of ``target`` is created."""
    target = Path(os.path.abspath(os.fspath(target)))
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o755)   # mkdtemp creates 0700
        replace_dir(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


class StagedFolder:
    """An output folder written completely or not at all (module docstring).

    ``with StagedFolder(out, command="spgeo vo") as st:`` write files under
    ``st.path`` (a temporary sibling of ``out``), then ``st.commit(status)``.
    The location is checked in the constructor (:func:`check_output_folder`,
    :class:`InputError`), so a bad ``out`` fails before any computation.

    Args:
        target: the output folder.
        what: how messages name it (e.g. ``"--out"``).
        command: recorded in the manifest.
    """

    def __init__(self, target: PathLike, what: str = "--out", command: str = "") -> None:
        self.target = check_output_folder(target, what)
        self.command = command
        self.path: Optional[Path] = None
        self.committed = False

    def __enter__(self) -> "StagedFolder":
        try:
            self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.", suffix=".tmp",
                                              dir=self.target.parent))
        except OSError as exc:
            raise _cannot_write("the output folder", self.target, self.target.parent,
                                exc) from None
        os.chmod(self.path, 0o755)   # mkdtemp creates 0700
        return self

    def commit(self, status: str = "complete",
               described: Optional[Mapping[PathLike, FileInfo]] = None, **info) -> Path:
        """Write the manifest (``status``: ``"complete"``, ``"flagged"``,
        ``"interrupted"``, ...; ``info`` added; ``"files"``: every file written,
        :func:`describe_folder` with ``described``) and move the folder into
        place; returns the target."""
        if self.path is None:
            raise RuntimeError("StagedFolder.commit outside its with block")
        manifest = {"status": status, "command": self.command,
                    "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **info,
                    "files": describe_folder(self.path, described)}
        (self.path / MANIFEST).write_text(json.dumps(manifest, indent=1, default=str) + "\n",
                                          encoding="utf-8")
        replace_dir(self.path, self.target)
        self.committed = True
        return self.target

    def __exit__(self, exc_type, exc, tb) -> bool:
        if not self.committed and self.path is not None:
            shutil.rmtree(self.path, ignore_errors=True)
        return False
