"""A VO map on disk (``spgeo vo --save-map DIR`` / ``--load-map DIR``, issue 53): the
keyframes of a finished run (pose, image, scaled primitives) and the landmarks of its
last map segment, which a later run relocalises into and continues in, in the saved
map's world frame and units (:class:`spgeo.vo.map_entry.MapEntry`).

Format (version :data:`FORMAT_VERSION`; docs/design.md §5.1, *A saved map*)::

    DIR/map.json                       {"format": "spgeo-vo-map", "version": 1,
                                        "units": ..., "camera": {...},
                                        "primitive_model": ..., "keyframes": [
                                          {"index", "frame", "segment", "T_world_kf": 4x4,
                                           "image": "keyframes/keyframe_000012.npy",
                                           "primitives": "keyframes/keyframe_000012.npz"}, ...],
                                        "landmarks": "landmarks.npz" | null}
    DIR/keyframes/keyframe_<k>.npy     the processing-size input image (float32, [0, 1])
    DIR/keyframes/keyframe_<k>.npz     its scaled primitives (:meth:`PrimitiveSet.save`)
    DIR/landmarks.npz                  points (N, 3) world, descriptors (N, D) uint8,
                                       keyframes (N,), segment, features (JSON)

``camera`` is the VO's processing camera (:attr:`spgeo.vo.Odometry.camera`): a run loads
a map only at the same processing camera.  Poses are camera-to-world, in the map's
world frame; positions and depths in its ``units``
(:data:`~spgeo.trajectory.VO_UNITS`, or :data:`~spgeo.trajectory.METRES` with a
depth-reading front-end).  The folder is written atomically (a temporary sibling renamed into place).
"""
from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, List, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..geometry import check_pose
from ..io.outputs import check_writable_parent, staged_directory
from ..primitives import PrimitiveSet
from ..twoview import FeatureOptions
from ..validation import InputError
from .landmark_snapshot import LandmarkSnapshot
from .tracking import Keyframe

__all__ = ["SavedKeyframe", "SavedMap", "FORMAT", "FORMAT_VERSION"]

log = logging.getLogger(__name__)

#: ``map.json``'s ``"format"``
FORMAT = "spgeo-vo-map"
#: ``map.json``'s ``"version"``
FORMAT_VERSION = 1


@dataclass
class SavedKeyframe:
    """One keyframe of a saved map.

    Attributes:
        index: its keyframe number in the run that saved it.
        frame: its frame number in that run.
        segment: its map segment in that run.
        T_world_kf: 4x4 camera-to-world pose (map frame and units).
        image: (H, W) or (H, W, 3) float32 processing-size image in [0, 1].
        primitives: its :class:`~spgeo.primitives.PrimitiveSet` with the scales
            the run ended with (depths in the map's units).
    """

    index: int
    frame: int
    segment: int
    T_world_kf: np.ndarray
    image: np.ndarray
    primitives: PrimitiveSet

    def keyframe(self, levels: int, selection) -> Keyframe:
        """The tracker's :class:`Keyframe` of it (``levels`` pyramid levels, the
        odometry's pixel ``selection``)."""
        return Keyframe.build(self.image, self.primitives, self.T_world_kf, levels, selection)


@dataclass
class SavedMap:
    """A VO map to keep (module docstring).

    Attributes:
        camera: the processing camera of the run that saved it.
        units: :data:`~spgeo.trajectory.VO_UNITS` (one unknown scale) or
            :data:`~spgeo.trajectory.METRES`.
        primitive_model: the run's ``OdometryConfig.primitive_model``.
        keyframes: its keyframes in creation order.
        landmarks: the last segment's landmarks, or None.
    """

    camera: PinholeCamera
    units: str
    primitive_model: str
    keyframes: List[SavedKeyframe]
    landmarks: Optional[LandmarkSnapshot] = None

    @classmethod
    def of(cls, camera: PinholeCamera, units: str, primitive_model: str,
           keyframes: Iterable[Tuple[int, int, int, np.ndarray, Keyframe]],
           landmarks: Optional[LandmarkSnapshot]) -> "SavedMap":
        """A map from ``(index, frame, segment, input image, Keyframe)`` tuples."""
        kfs = [SavedKeyframe(int(k), int(f), int(s), np.array(kf.T_world_kf, dtype=float),
                             np.asarray(image, np.float32), kf.primitives)
               for k, f, s, image, kf in keyframes]
        return cls(camera, units, primitive_model, kfs, landmarks)

    def save(self, folder: Union[str, Path]) -> Path:
        """Write the map into ``folder`` (replacing a previous one atomically);
        returns the folder."""
        folder = Path(folder)
        with staged_directory(folder) as tmp:
            (tmp / "keyframes").mkdir()
            entries = [_write_keyframe(tmp, kf) for kf in self.keyframes]
            lms = None
            if self.landmarks is not None:
                lms = "landmarks.npz"
                _write_landmarks(tmp / lms, self.landmarks)
            head = {"format": FORMAT, "version": FORMAT_VERSION, "units": self.units,
                    "camera": self.camera.to_dict(), "primitive_model": self.primitive_model,
                    "keyframes": entries, "landmarks": lms}
            (tmp / "map.json").write_text(json.dumps(head, indent=1), encoding="utf-8")
        log.info("saved map: %d keyframes, %d landmarks in %s", len(self.keyframes),
                 0 if self.landmarks is None else len(self.landmarks), folder)
        return folder

    @classmethod
    def load(cls, folder: Union[str, Path]) -> "SavedMap":
        """The map written by :meth:`save` into ``folder``.

        Raises:
            InputError: ``folder`` or one of its files is missing or not a saved map
                of this version (the message names the file).
        """
        folder = Path(folder)
        head = _read_head(folder / "map.json")
        try:
            camera = PinholeCamera.from_dict(head["camera"])
            kfs = [_read_keyframe(folder, e) for e in head["keyframes"]]
            lms = head.get("landmarks")
            landmarks = None if lms is None else _read_landmarks(folder / lms)
            units, model = str(head["units"]), str(head["primitive_model"])
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{folder / 'map.json'}: not a saved spgeo map ({exc})") from None
        if not kfs:
            raise InputError(f"{folder / 'map.json'}: the saved map has no keyframe")
        return cls(camera, units, model, kfs, landmarks)

    @staticmethod
    def check_target(folder: Union[str, Path], what: str = "--save-map") -> Path:
        """``folder`` as a Path after checking, before a run, that a map may be saved
        there: absent, empty, or a saved map (replaced); raises :class:`InputError`
        naming it otherwise (a file, a folder of other files, a parent not writable)."""
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise InputError(f"{what} {folder} exists and is not a folder")
        if folder.is_dir() and any(folder.iterdir()) and not (folder / "map.json").is_file():
            raise InputError(f"{what} {folder} is a folder holding files other than a saved "
                             "map; give an empty or new folder, or a saved map to replace")
        check_writable_parent(folder, what)
        return folder

    def check_fits(self, camera: PinholeCamera, primitive_model: str, units: str,
                   where: str) -> None:
        """Raise :class:`InputError` (naming ``where``) unless a run at processing
        ``camera`` with ``primitive_model`` and position ``units`` can continue in it."""
        a, b = self.camera.to_dict(), camera.to_dict()
        if any(not np.isclose(a[k], b[k], rtol=1e-6) for k in ("fx", "fy", "cx", "cy",
                                                             "width", "height")):
            raise InputError(f"{where}: the map was saved at the processing camera {a}, this "
                             f"run works at {b} (give the same input camera and resolution)")
        if (self.primitive_model, self.units) != (primitive_model, units):
            raise InputError(f"{where}: the map was saved with primitive_model "
                             f"{self.primitive_model!r} in units {self.units!r}, this run uses "
                             f"{primitive_model!r} in {units!r}")


def _write_keyframe(folder: Path, kf: SavedKeyframe) -> dict:
    """Write one keyframe's files under ``folder``; its ``map.json`` entry."""
    stem = f"keyframes/keyframe_{kf.index:06d}"
    np.save(folder / f"{stem}.npy", np.asarray(kf.image, np.float32))
    kf.primitives.save(folder / f"{stem}.npz")
    return {"index": kf.index, "frame": kf.frame, "segment": kf.segment,
            "T_world_kf": np.asarray(kf.T_world_kf, float).tolist(),
            "image": f"{stem}.npy", "primitives": f"{stem}.npz"}


def _read_keyframe(folder: Path, entry: dict) -> SavedKeyframe:
    """One keyframe of ``map.json``'s ``entry``, its files read from ``folder``."""
    img_path, prim_path = folder / entry["image"], folder / entry["primitives"]
    try:
        image = np.load(img_path, allow_pickle=False)
        prims = PrimitiveSet.load(prim_path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{folder}: cannot read keyframe {entry.get('index')}: {exc}") from None
    T = check_pose(np.asarray(entry["T_world_kf"], dtype=float),
                   f"{folder / 'map.json'} keyframe {entry['index']} T_world_kf")
    if image.shape[:2] != (prims.camera.height, prims.camera.width):
        raise InputError(f"{img_path}: image {image.shape[1]}x{image.shape[0]} but its "
                         f"primitives are {prims.camera.width}x{prims.camera.height}")
    return SavedKeyframe(int(entry["index"]), int(entry["frame"]), int(entry["segment"]), T,
                         image.astype(np.float32), prims)


def _write_landmarks(path: Path, snap: LandmarkSnapshot) -> None:
    np.savez_compressed(path, points=snap.points, descriptors=snap.descriptors,
                        keyframes=snap.keyframes, segment=snap.segment,
                        features=json.dumps(dataclasses.asdict(snap.features)))


def _read_landmarks(path: Path) -> LandmarkSnapshot:
    try:
        with np.load(path, allow_pickle=False) as z:
            return LandmarkSnapshot(int(z["segment"]), z["points"].astype(np.float64),
                                    z["descriptors"].astype(np.uint8),
                                    z["keyframes"].astype(np.int64),
                                    FeatureOptions(**json.loads(str(z["features"]))))
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{path}: not the landmarks of a saved spgeo map ({exc})") from None


def _read_head(path: Path) -> dict:
    """``map.json`` of a saved map, checked for format and version."""
    if not path.is_file():
        raise InputError(f"{path.parent}: not a saved spgeo map (no map.json)")
    try:
        head = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise InputError(f"{path}: not a saved spgeo map (format is not {FORMAT!r})")
    if head.get("version") != FORMAT_VERSION:
        raise InputError(f"{path}: saved map version {head.get('version')!r}, this spgeo "
                         f"reads version {FORMAT_VERSION}")
    return head
