"""Keyframes that left the VO's window, kept on disk (bounded memory).

A keyframe whose variables the window's smoother marginalised never changes
again (:class:`spgeo.vo.smoother.WindowMapper`): :class:`spgeo.vo.Odometry`
*retires* it (:meth:`spgeo.vo.map.MapKeyframe.retire`).  Its pose and median
depth stay in memory (the trajectory needs them); its input image and
primitives go to a :class:`KeyframeStore` (one pickle file per keyframe, exact
arrays), and its pyramid, points and pixel caches are dropped.  Whatever needs
them afterwards (the keyframe clouds of :meth:`Odometry.save`, a COLMAP
export, :attr:`Odometry.keyframes`) reads them back one keyframe at a time, so
memory does not grow with the number of keyframes.
"""
from __future__ import annotations

import os
import pickle
import shutil
import tempfile
import weakref
from pathlib import Path
from typing import Optional, Tuple, Union

import numpy as np

from ..primitives import PrimitiveSet

__all__ = ["KeyframeStore"]


class KeyframeStore:
    """Image and primitives of retired keyframes, one file per keyframe.

    Args:
        folder: where the files go (created; left in place).  Default None: a
            temporary folder, made at the first :meth:`put` and removed when the
            store is garbage-collected or the interpreter exits.
    """

    def __init__(self, folder: Optional[Union[str, os.PathLike]] = None) -> None:
        self._folder: Optional[Path] = None if folder is None else Path(folder)
        self._temporary = folder is None
        self._finalizer: Optional[weakref.finalize] = None

    @property
    def folder(self) -> Optional[Path]:
        """The folder (None while a temporary store holds nothing)."""
        return self._folder

    @staticmethod
    def _name(k: int) -> str:
        return f"keyframe_{int(k):06d}.pkl"

    def _path(self, k: int) -> Path:
        if self._folder is None:
            self._folder = Path(tempfile.mkdtemp(prefix="spgeo-vo-keyframes-"))
            self._finalizer = weakref.finalize(self, shutil.rmtree, str(self._folder), True)
        self._folder.mkdir(parents=True, exist_ok=True)
        return self._folder / self._name(k)

    def put(self, k: int, image: np.ndarray, primitives: PrimitiveSet) -> None:
        """Store keyframe ``k``'s input image and primitives (replaces a previous one)."""
        path = self._path(k)
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump((np.asarray(image), primitives), fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)

    def get(self, k: int) -> Tuple[np.ndarray, PrimitiveSet]:
        """``(image, primitives)`` of keyframe ``k``, equal to what :meth:`put`
        stored.  Raises ``KeyError`` when ``k`` was never stored."""
        path = None if self._folder is None else self._folder / self._name(k)
        if path is None or not path.is_file():
            raise KeyError(f"keyframe {k} is not in the store")
        with open(path, "rb") as fh:
            image, prims = pickle.load(fh)
        return image, prims

    def close(self) -> None:
        """Remove a temporary store's folder now (a given folder is left alone)."""
        if self._finalizer is not None:
            self._finalizer()
