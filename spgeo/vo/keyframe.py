"""The keyframe as the photometric tracker and the mapping factors see it.

:class:`Keyframe` holds the keyframe's primitives (with their fixed
log-scales), the grey pyramid of its image and its pose, and batches the
primitives' pixels per pyramid level (:meth:`Keyframe.level_data`): level
``l`` uses the primitive pixels on the ``2^l`` lattice, keyframe intensities
from level ``l`` of the pyramid; primitives with fewer than
``min_level_pixels`` pixels at a level are left out.

A ``subsample`` stride ``s`` of :meth:`Keyframe.level_data` keeps every
``s``-th lattice pixel along each axis at a level (the tracker's decision
pixels at resolutions above 160x120, :func:`spgeo.vo.tracking.decision_stride`).

Pixel selection (``Keyframe.selection``, a
:class:`~spgeo.vo.pixels.PixelSelectionConfig`) keeps, at each level, a budget
of well-spread high-gradient pixels of the lattice (:func:`spgeo.vo.pixels.select_pixels`)
instead of all of them; the primitives keep their dense shape.  The mapping
factors take their pixels from the same :meth:`Keyframe.level_data`, so tracker
and factors keep computing one cost on the same pixels.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple, Union

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..geometry import check_pose
from ..images import Pyramid, gaussian_pyramid, to_float_image, to_gray
from ..primitive_models import from_shape_values
from ..primitives import PrimitiveSet
from .pixels import PixelSelectionConfig, gradient_magnitude, select_pixels

__all__ = ["Keyframe", "with_shape_values"]

log = logging.getLogger(__name__)


def _prepare_grey(image: np.ndarray, shape: Tuple[int, int], work_shape: Tuple[int, int],
                  name: str) -> np.ndarray:
    """float32 grey image at the primitives' resolution (as :mod:`spgeo.sfm` does)."""
    image = np.asarray(image)
    if image.ndim not in (2, 3) or image.shape[:2] != tuple(shape):
        raise ValueError(f"{name} has shape {image.shape}, expected {tuple(shape)}[+channels]")
    grey = to_gray(to_float_image(image))   # raises on NaN / inf / bad range
    if grey.shape != tuple(work_shape):
        grey = cv2.resize(grey, (work_shape[1], work_shape[0]), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(grey, dtype=np.float32)


@dataclass
class _LevelData:
    """The batched pixels of one (level, subsample) pair."""

    level: int
    entries: np.ndarray        # (K,) indices into the PrimitiveSet's entries
    points_t: np.ndarray       # (3, K) keyframe-frame points (transposed)
    ref_intensity: np.ndarray  # (K,) float64 keyframe intensities at the level
    ids: np.ndarray            # (K,) compact primitive id 0..P-1
    prim_index: np.ndarray     # (P,) original primitive index of each compact id
    n_pixels: np.ndarray       # (P,) pixels per primitive at the level

    @property
    def n_primitives(self) -> int:
        return int(self.prim_index.size)


def _points(primitives: PrimitiveSet) -> np.ndarray:
    """(K, 3) keyframe-frame points of every primitive pixel."""
    rays = primitives.camera.rays().reshape(-1, 3)[primitives.pixels]
    return rays * np.exp(primitives.scaled_log_depth())[:, None]


@dataclass
class Keyframe:
    """A keyframe as the tracker sees it.

    Attributes:
        primitives: the keyframe's :class:`PrimitiveSet` with its (fixed)
            log-scales; its camera is the working resolution.
        pyramid: grey float32 pyramid of the keyframe image at that resolution.
        T_world_kf: 4x4 camera-to-world pose of the keyframe.
        input_shape: ``(H, W)`` of the images given to :meth:`build`; frames
            passed to :func:`~spgeo.vo.tracking.track_frame` must have it too (they are resized
            to the primitives' resolution the same way).
        points: (M, 3) keyframe-frame points of all primitive entries.
        median_depth: median depth of those points.
        selection: pixel selection of :meth:`level_data` (None: every
            lattice pixel).
    """

    primitives: PrimitiveSet
    pyramid: Pyramid
    T_world_kf: np.ndarray
    input_shape: Tuple[int, int]
    points: np.ndarray
    median_depth: float
    selection: Optional[PixelSelectionConfig] = None
    _cache: Dict[tuple, _LevelData] = field(default_factory=dict, repr=False)
    # selected entries per (level, lattice, selection): they depend on the image and masks only
    _selected: Dict[tuple, np.ndarray] = field(default_factory=dict, repr=False)
    # indices of the entries on each pixel lattice (they depend on the pixels only)
    _lattice: Dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _lattice_points: Dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        """One line: primitives, resolution, median depth, position (map units)."""
        x, y, z = self.T_world_kf[:3, 3]
        cam = self.primitives.camera
        return (f"Keyframe({len(self.primitives)} primitives, {cam.width}x{cam.height}, "
                f"median depth {self.median_depth:.3f}, position [{x:.3f}, {y:.3f}, {z:.3f}])")

    @classmethod
    def build(cls, image: np.ndarray, primitives: PrimitiveSet, T_world_kf: np.ndarray,
              levels: int = 3, selection: Optional[PixelSelectionConfig] = None) -> "Keyframe":
        """Keyframe from its image (H, W[, 3]; uint8 or float [0, 1]), primitives
        and pose.  An image of another size than the primitives' camera is
        resized to it (``INTER_AREA``).  ``selection``: see :meth:`level_data`."""
        if len(primitives) == 0:
            raise ValueError("Keyframe.build: the primitive set is empty")
        T = check_pose(np.asarray(T_world_kf, dtype=np.float64), "T_world_kf")
        cam = primitives.camera
        image = np.asarray(image)
        if image.ndim not in (2, 3):
            raise ValueError(f"Keyframe.build: image must be (H, W[, C]), got {image.shape}")
        grey = _prepare_grey(image, image.shape[:2], cam.shape, "keyframe image")
        pyr = gaussian_pyramid(grey, cam, int(levels))
        X = _points(primitives)
        return cls(primitives, pyr, T.copy(), tuple(image.shape[:2]), X,
                   float(np.median(X[:, 2])), selection)

    def rebuilt(self, primitives: PrimitiveSet, T_world_kf: np.ndarray) -> "Keyframe":
        """The keyframe with new shapes / scales and pose: same image, and
        the same primitive pixels (``primitives.pixels`` and ``offsets`` equal
        to the current ones), so its pyramid and pixel selection are reused.
        Raises ValueError when the pixels differ."""
        old = self.primitives
        if not (np.array_equal(primitives.pixels, old.pixels)
                and np.array_equal(primitives.offsets, old.offsets)):
            raise ValueError("Keyframe.rebuilt: the primitives' pixels changed")
        T = check_pose(np.asarray(T_world_kf, dtype=np.float64), "T_world_kf")
        X = _points(primitives)
        return Keyframe(primitives, self.pyramid, T.copy(), self.input_shape, X,
                        float(np.median(X[:, 2])), self.selection, _selected=self._selected,
                        _lattice=self._lattice)

    @property
    def camera(self) -> PinholeCamera:
        return self.primitives.camera

    def __getstate__(self) -> dict:
        """Pickled without what is derived from the primitives alone (points,
        level data and lattices: rebuilt on load by the same code, so equal bit
        for bit); the pixel selection is kept: the mapping worker's transfer
        (:mod:`spgeo.vo.mapping_worker`; sizes in docs/history.md, issue 32)."""
        state = dict(self.__dict__)
        state.update(points=None, _cache={}, _lattice={}, _lattice_points={})
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.points = _points(self.primitives)

    def lattice_entries(self, stride: int) -> np.ndarray:
        """Indices of the primitive entries on the pixel lattice of ``stride``
        (cached)."""
        stride = int(stride)
        if stride not in self._lattice:
            w = self.primitives.camera.width
            pix = self.primitives.pixels
            self._lattice[stride] = np.flatnonzero(((pix % w) % stride == 0)
                                                   & ((pix // w) % stride == 0))
        return self._lattice[stride]

    def lattice_points(self, stride: int) -> np.ndarray:
        """(3, K) keyframe-frame points of :meth:`lattice_entries` (cached)."""
        stride = int(stride)
        if stride not in self._lattice_points:
            P = self.points if stride == 1 else self.points[self.lattice_entries(stride)]
            self._lattice_points[stride] = np.ascontiguousarray(P.T)
        return self._lattice_points[stride]

    def _select(self, level: int, lattice: int, on: np.ndarray,
                selection: PixelSelectionConfig) -> np.ndarray:
        """Mask (over all entries) of the selected lattice entries at ``level``."""
        key = (int(level), int(lattice), selection)
        if key not in self._selected:
            prims = self.primitives
            w = prims.camera.width
            stride = 2 ** int(level)
            cand = np.flatnonzero(on)
            pix = prims.pixels[cand]
            img = self.pyramid.images[level]
            sel = select_pixels(img, (pix // w) // stride, (pix % w) // stride,
                                prims.primitive_ids[cand], selection, len(prims),
                                magnitude=gradient_magnitude(img))
            self._selected[key] = cand[sel.indices]
            log.debug("keyframe level %d: %d of %d pixels selected, %d primitives without",
                      level, sel.indices.size, cand.size, sel.empty.size)
        mask = np.zeros(on.size, dtype=bool)
        mask[self._selected[key]] = True
        return mask

    def level_data(self, level: int, subsample: int = 1, min_level_pixels: int = 4,
                   selection: Union[PixelSelectionConfig, None, str] = "keyframe"
                   ) -> _LevelData:
        """Batched pixels at ``level`` (lattice ``2^level * subsample``), cached.

        With a pixel selection (``selection``; ``"keyframe"``: :attr:`selection`)
        only the lattice pixels chosen by :func:`~spgeo.vo.pixels.select_pixels`
        on the level's image (at level 0 always, above it when
        ``selection.coarse_levels == "select"``); the per-primitive means are
        taken over them.  Primitives with fewer than ``min_level_pixels``
        pixels are left out."""
        if isinstance(selection, str):
            if selection != "keyframe":
                raise ValueError("level_data: selection must be a config, None or 'keyframe'")
            selection = self.selection
        key = (int(level), int(subsample), int(min_level_pixels), selection)
        if key in self._cache:
            return self._cache[key]
        prims = self.primitives
        w = prims.camera.width
        stride = 2 ** int(level)
        lattice = stride * int(subsample)
        on = np.zeros(prims.pixels.size, dtype=bool)
        on[self.lattice_entries(lattice)] = True
        if selection is not None and (level == 0 or selection.coarse_levels == "select"):
            on = self._select(level, lattice, on, selection)
        ids_all = prims.primitive_ids
        counts = np.bincount(ids_all[on], minlength=len(prims))
        keep_prim = counts >= max(int(min_level_pixels), 1)
        entries = np.flatnonzero(on & keep_prim[ids_all])
        prim_index = np.flatnonzero(keep_prim)
        compact = np.full(len(prims), -1, dtype=np.int64)
        compact[prim_index] = np.arange(prim_index.size)
        ids = compact[ids_all[entries]]
        pix = prims.pixels[entries]
        img = self.pyramid.images[level]
        # ScaledShape: X = rays * exp(log_depth + s) (same expression as the factor)
        rays = prims.camera.rays().reshape(-1, 3)[pix]
        s = prims.log_scales[ids_all[entries]]
        X = rays * np.exp(prims.log_depth[entries] + s)[:, None]
        ref = img[(pix // w) // stride, (pix % w) // stride].astype(np.float64)
        n_pix = np.bincount(ids, minlength=prim_index.size).astype(np.float64)
        data = _LevelData(int(level), entries, np.ascontiguousarray(X.T), ref, ids, prim_index, n_pix)
        self._cache[key] = data
        return data

    def frame_pyramid(self, image: np.ndarray, levels: Optional[int] = None) -> Pyramid:
        """Grey pyramid of a frame, prepared exactly as the keyframe's."""
        grey = _prepare_grey(image, self.input_shape, self.camera.shape, "frame image")
        n = len(self.pyramid) if levels is None else min(int(levels), len(self.pyramid))
        return gaussian_pyramid(grey, self.camera, max(n, 1))


def with_shape_values(keyframe: Keyframe, thetas: np.ndarray, primitive_model: str,
                      T_world_kf: np.ndarray) -> Keyframe:
    """The keyframe rebuilt at pose ``T_world_kf`` (4x4 camera-to-world) with
    the shape variables ``thetas`` (as :func:`spgeo.primitive_models.shape_values`
    returns them for its primitives)."""
    prims = from_shape_values(keyframe.primitives, thetas, primitive_model)
    return keyframe.rebuilt(prims, T_world_kf)
