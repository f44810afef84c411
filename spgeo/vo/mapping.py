"""The keyframes of the VO's map: :class:`MapKeyframe` (numbers, image, the current
:class:`~spgeo.vo.keyframe.Keyframe`, or once retired its final pose with image and
primitives in the :class:`~spgeo.vo.keyframe_store.KeyframeStore`) and
:class:`SupportCandidate` (a frame tracked against the latest keyframe, which the window
smoother, :class:`spgeo.vo.smoother.WindowMapper`, may take as a supporting frame).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from .tracking import Keyframe

__all__ = ["MapKeyframe", "SupportCandidate"]


@dataclass
class MapKeyframe:
    """A keyframe of the map: numbers, input image and its current
    :class:`~spgeo.vo.tracking.Keyframe` (pose and primitives).

    A *retired* keyframe (:meth:`retire`: it left the window, its state is
    final) holds only its numbers, pose and median depth: ``image`` and
    ``keyframe`` are None, its image and primitives are in a
    :class:`~spgeo.vo.keyframe_store.KeyframeStore` (:meth:`restore`).
    """

    index: int          # keyframe number
    frame: int          # frame number
    image: Optional[np.ndarray]
    keyframe: Optional[Keyframe]
    segment: int = 0
    map_pixels: Optional[tuple] = None   # cached mapping pixels (pixels and image never change)
    prior_weights: Optional[np.ndarray] = None   # (N,) weights of the shape priors
    _final: Optional[tuple] = None   # retired: (T_world_kf, median depth, selection)
    _log_scale_shift: float = 0.0    # retired: added to the stored log-scales (loop closure)

    @property
    def retired(self) -> bool:
        return self._final is not None

    @property
    def T_world_kf(self) -> np.ndarray:
        """4x4 camera-to-world pose (the keyframe's current one)."""
        return self._final[0] if self._final is not None else self.keyframe.T_world_kf

    @property
    def median_depth(self) -> float:
        """Median depth of the keyframe's points (current scales)."""
        return self._final[1] if self._final is not None else self.keyframe.median_depth

    def retire(self, store) -> None:
        """Put image and primitives into ``store`` (a
        :class:`~spgeo.vo.keyframe_store.KeyframeStore`) and drop everything
        else but the pose and median depth; no-op when already retired."""
        if self._final is not None:
            return
        kf = self.keyframe
        store.put(self.index, self.image, kf.primitives)
        self._final = (kf.T_world_kf.copy(), float(kf.median_depth), kf.selection)
        self.image = self.keyframe = None
        self.map_pixels = self.prior_weights = None

    def input_image(self, store) -> np.ndarray:
        """The input image (for a retired keyframe read from ``store``, without
        building the :class:`Keyframe` as :meth:`restore` does)."""
        return self.image if self._final is None else store.get(self.index)[0]

    def restore(self, store, levels: int) -> Tuple[np.ndarray, Keyframe]:
        """``(input image, Keyframe)``: the live ones, or for a retired keyframe
        the stored image and primitives at its final pose (the
        :class:`Keyframe` built again with ``levels`` pyramid levels: equal to
        the one it had)."""
        if self._final is None:
            return self.image, self.keyframe
        image, prims = store.get(self.index)
        if self._log_scale_shift != 0.0:
            prims = prims.with_log_scales(prims.log_scales + self._log_scale_shift)
        return image, Keyframe.build(image, prims, self._final[0], levels, self._final[2])

    def correct(self, T_world_kf: np.ndarray, scale: float) -> None:
        """Apply a loop correction (:class:`spgeo.loop.LoopCorrection`): the new
        rigid pose and every depth multiplied by ``scale`` (log-scales ``+= log
        scale``).  A retired keyframe keeps the shift and applies it when read
        back (:meth:`restore`); its stored file is not rewritten."""
        shift = float(np.log(scale))
        T = np.array(T_world_kf, dtype=float)
        if self._final is not None:
            self._final = (T, self._final[1] * float(scale), self._final[2])
            self._log_scale_shift += shift
            return
        prims = self.keyframe.primitives
        self.keyframe = self.keyframe.rebuilt(prims.with_log_scales(prims.log_scales + shift), T)

    def replace_state(self, keyframe: Keyframe, store) -> None:
        """Take the pose and primitives of ``keyframe`` (this keyframe rebuilt
        with new shapes and pose, e.g. by the global bundle adjustment: same
        image and primitive pixels).  A live keyframe keeps it as its
        ``keyframe``; a retired one rewrites its primitives in ``store`` (a
        :class:`~spgeo.vo.keyframe_store.KeyframeStore`; any loop-closure shift
        is then part of them) and keeps the new pose and median depth."""
        if self._final is None:
            self.keyframe = keyframe
            return
        image, _ = store.get(self.index)
        store.put(self.index, image, keyframe.primitives)
        self._final = (np.array(keyframe.T_world_kf, dtype=float), float(keyframe.median_depth),
                       self._final[2])
        self._log_scale_shift = 0.0


@dataclass
class SupportCandidate:
    """A frame tracked against the latest keyframe (supporting-frame candidate):
    its image, ``T_kf_frame`` (4x4) and affine brightness ``(a, b)``."""

    frame: int
    image: np.ndarray
    T_kf_frame: np.ndarray
    brightness: np.ndarray
