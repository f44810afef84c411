"""VOID reader (Wong et al., RA-L 2020, release layout) and its depth-file format.

Release layout (from the official README of ``alexklwong/void-dataset``)::

    void_release/
      void_150/ | void_500/ | void_1500/          # 150 / 500 / 1500 sparse points
        data/<sequence>/
          image/<timestamp>.png                  # RGB, 640x480
          sparse_depth/<timestamp>.png           # uint16, metres * 256, 0 = missing
          validity_map/<timestamp>.png           # uint16, 256 where a sparse point, else 0
          ground_truth/<timestamp>.png           # uint16, metres * 256, 0 = missing
          absolute_pose/<timestamp>.txt
          K.txt                                  # 3x3 intrinsics (numpy text)
        {train,test}_{image,sparse_depth,validity_map,ground_truth,absolute_pose,intrinsics}.txt

The list files hold one path per line relative to ``void_release``
(``void_150/data/<sequence>/image/<timestamp>.png``, the intrinsics lists point
at the sequence's ``K.txt``).  Encodings follow the official
``src/data_utils.py`` (``load_depth``: uint16 PNG / 256, ``<= 0`` missing;
``load_validity_map``: values {0, 256}).  The images are used with ``K.txt`` as
they are (no undistortion).

:class:`VOIDDataset` yields :class:`VOIDSample` s (image, sparse depth,
validity, ground truth, camera), not :class:`~spgeo.frame.Frame` s, so it is not
one of the :func:`spgeo.datasets.open_dataset` kinds.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Union

import cv2
import numpy as np

from ..camera import PinholeCamera
from .files import PathLike, read_depth_png, read_rgb

__all__ = ["VOID_SPLITS", "VOID_LIST_KINDS", "VOIDSample", "VOIDDataset", "check_void_split",
           "read_void_depth", "write_void_depth"]

#: Sparse-point densities of the release (folder ``void_<split>``).
VOID_SPLITS = ("150", "500", "1500")
#: Kinds of the ``<subset>_<kind>.txt`` list files read (``absolute_pose`` is not read).
VOID_LIST_KINDS = ("image", "sparse_depth", "validity_map", "ground_truth", "intrinsics")


def check_void_split(split: Union[str, int]) -> str:
    """``split`` as a string of :data:`VOID_SPLITS`; ``ValueError`` otherwise."""
    split = str(split)
    if split not in VOID_SPLITS:
        raise ValueError(f"VOID split must be one of {VOID_SPLITS}, got {split!r}")
    return split


# ----------------------------------------------------------------- depth files
def read_void_depth(path: PathLike) -> np.ndarray:
    """A VOID 16-bit depth PNG as float64 metres (value / 256; 0 = missing)."""
    return np.nan_to_num(read_depth_png(path, 256.0, dtype=np.float64), nan=0.0)


def write_void_depth(path: PathLike, depth: np.ndarray) -> None:
    """Write metres as a VOID 16-bit PNG (``round(depth * 256)``; NaN / <= 0 /
    beyond 255.99 m -> 0 = missing)."""
    d = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0) & (d * 256.0 <= 65535)
    raw = np.where(ok, np.rint(np.where(ok, d, 0) * 256.0), 0).astype(np.uint16)
    if not cv2.imwrite(os.fspath(path), raw):
        raise OSError(f"could not write {path}")


# ----------------------------------------------------------------- reader
@dataclass
class VOIDSample:
    """One VOID test item.

    Attributes:
        name: ``<sequence>/<timestamp>``.
        image: float32 (H, W, 3) RGB in [0, 1].
        sparse_depth: float64 (H, W) metres, 0 = missing.
        validity_map: bool (H, W), True at sparse points.
        ground_truth: float64 (H, W) metres, 0 = missing.
        camera: intrinsics from ``K.txt``.
        paths: source file of each kind.
    """

    name: str
    image: np.ndarray
    sparse_depth: np.ndarray
    validity_map: np.ndarray
    ground_truth: np.ndarray
    camera: PinholeCamera
    paths: Dict[str, str] = field(default_factory=dict)


def _read_list(path: Path) -> List[str]:
    if not path.is_file():
        raise FileNotFoundError(f"VOID list file not found: {path}")
    return [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]


class VOIDDataset:
    """Lazy random-access reader of one VOID density and subset.

    Args:
        root: the ``void_release`` folder (holding ``void_150/`` ...) or a
            ``void_<split>`` folder itself.
        split: ``"150"``, ``"500"`` or ``"1500"`` (an int is accepted).
        subset: ``"test"`` (default) or ``"train"``.

    ``validity_map`` and ``intrinsics`` lists are optional: without them the
    validity is ``sparse_depth > 0`` and ``K.txt`` is taken from the sequence
    folder (``image/..``).  Raises ``FileNotFoundError`` for a missing root or
    list file and ``ValueError`` for lists of different lengths or entries
    whose file names do not match.
    """

    def __init__(self, root: PathLike, split: Union[str, int] = "150",
                 subset: str = "test") -> None:
        split = check_void_split(split)
        if subset not in ("test", "train"):
            raise ValueError(f"VOID subset must be 'test' or 'train', got {subset!r}")
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"VOID root not found: {root}")
        folder = f"void_{split}"
        if (root / folder).is_dir():
            self.split_dir = root / folder
        elif root.name == folder:
            self.split_dir = root
        else:
            raise FileNotFoundError(f"{root} holds no {folder}/ folder (expected the void_release "
                                    f"layout)")
        self.split, self.subset = split, subset
        self.release_dir = self.split_dir.parent
        lists: Dict[str, List[str]] = {}
        for kind in VOID_LIST_KINDS:
            p = self.split_dir / f"{subset}_{kind}.txt"
            if p.is_file():
                lists[kind] = _read_list(p)
            elif kind in ("image", "sparse_depth", "ground_truth"):
                raise FileNotFoundError(f"VOID list file not found: {p}")
        n = len(lists["image"])
        for kind, entries in lists.items():
            if len(entries) != n:
                raise ValueError(f"VOID {folder}/{subset}_{kind}.txt has {len(entries)} entries, "
                                 f"{subset}_image.txt has {n}")
        for kind in ("sparse_depth", "validity_map", "ground_truth"):
            if kind in lists:
                bad = [i for i, (a, b) in enumerate(zip(lists["image"], lists[kind]))
                       if os.path.basename(a) != os.path.basename(b)]
                if bad:
                    raise ValueError(f"VOID lists disagree: entry {bad[0]} of {subset}_image.txt "
                                     f"and {subset}_{kind}.txt name different files")
        self.lists = lists
        self.name = f"VOID-{split} {subset}"

    def __len__(self) -> int:
        return len(self.lists["image"])

    def resolve(self, entry: str) -> Path:
        """File of a list entry: relative to ``void_release`` (official), to the
        density folder, absolute, or any prefix ending in ``void_<split>/``."""
        p = Path(entry)
        cands = [p] if p.is_absolute() else []
        cands += [self.release_dir / entry, self.split_dir / entry]
        key = f"void_{self.split}/"
        if key in entry.replace(os.sep, "/"):
            cands.append(self.split_dir / entry.replace(os.sep, "/").split(key, 1)[1])
        for c in cands:
            if c.is_file():
                return c
        raise FileNotFoundError(f"VOID file of list entry {entry!r} not found (tried "
                                f"{', '.join(str(c) for c in cands)})")

    def __getitem__(self, i: int) -> VOIDSample:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"VOID index {i} out of range for {n} samples")
        i %= n
        paths = {k: self.resolve(v[i]) for k, v in self.lists.items()}
        img_path = paths["image"]
        if "intrinsics" not in paths:
            paths["intrinsics"] = img_path.parent.parent / "K.txt"
            if not paths["intrinsics"].is_file():
                raise FileNotFoundError(f"VOID intrinsics not found: {paths['intrinsics']}")
        image = read_rgb(img_path)
        h, w = image.shape[:2]
        try:
            K = np.loadtxt(paths["intrinsics"], dtype=np.float64)
        except ValueError as exc:
            raise ValueError(f"malformed intrinsics file {paths['intrinsics']}: {exc}") from None
        if K.shape != (3, 3):
            raise ValueError(f"{paths['intrinsics']}: expected a 3x3 matrix, got shape {K.shape}")
        cam = PinholeCamera.from_K(K, w, h)
        sparse = read_void_depth(paths["sparse_depth"])
        gt = read_void_depth(paths["ground_truth"])
        if "validity_map" in paths:
            validity = read_void_depth(paths["validity_map"]) > 0
        else:
            validity = sparse > 0
        for what, arr in (("sparse depth", sparse), ("ground truth", gt),
                          ("validity map", validity)):
            if arr.shape != (h, w):
                raise ValueError(f"VOID sample {img_path}: {what} is {arr.shape[::-1]}, image is "
                                 f"{(w, h)}")
        sparse = np.where(validity, sparse, 0.0)
        seq = img_path.parent.parent.name
        return VOIDSample(f"{seq}/{img_path.stem}", image, sparse, validity, gt, cam,
                          {k: str(v) for k, v in paths.items()})

    def __iter__(self):
        return (self[i] for i in range(len(self)))
