"""The VO's keyframe map (docs/design.md §5): keyframes in creation order, map
segments, the store of retired keyframes, the frames anchored to keyframes,
the supporting frames' smoothed poses, the supporting-frame candidates of the
newest keyframe, and one :meth:`KeyframeMap.apply_similarity` that moves all of
it with its keyframes (loop correction and global refinement).

The map holds state; :class:`spgeo.vo.Odometry` decides (tracking, keyframes,
mapping) and :class:`spgeo.vo.mapping.WindowMapper` smooths the window, writing
the supporting frames' poses into :attr:`KeyframeMap.support_pose`.
"""
from __future__ import annotations

from typing import Callable, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from ..loop.sim3 import moved_frame
from .keyframe_store import KeyframeStore
from .mapping import MapKeyframe, SupportCandidate
from .motion import MotionModel
from .result import FrameResult, FrameStatus
from .tracking import Keyframe

__all__ = ["KeyframeMap"]

#: a frame's anchor: (keyframe index, T_kf_frame, the keyframe's median depth then)
Anchor = Tuple[int, np.ndarray, float]


class KeyframeMap:
    """Keyframes and what follows them.

    Args:
        window: keyframes of the current segment kept live (the smoother's window).
        levels: pyramid levels of a keyframe read back from the store.
        n_support: supporting frames per keyframe (bounds :attr:`candidates`).
        store: the :class:`~spgeo.vo.keyframe_store.KeyframeStore` of retired
            keyframes (default None: a temporary folder).

    Attributes:
        kfs: keyframe index -> :class:`~spgeo.vo.mapping.MapKeyframe`.
        order: keyframe indices in creation order (``0 .. n - 1``).
        live: the keyframes not retired, in creation order.
        seg_kfs: the current segment's keyframes (those the window may reach).
        segment: the current map segment's number (0, 1, ...).
        store: the keyframe store.
        anchors: frame number -> ``(k, T_kf_frame, median depth of k then)`` of a
            frame tracked against keyframe ``k``.
        support_pose: frame number -> smoothed ``T_world_frame`` of a supporting
            frame (written by the window smoother).
        candidates: supporting-frame candidates of the newest keyframe.
    """

    def __init__(self, window: int, levels: int, n_support: int,
                 store: Optional[KeyframeStore] = None) -> None:
        self.window, self.levels, self.n_support = window, levels, n_support
        self.kfs: Dict[int, MapKeyframe] = {}
        self.order: List[int] = []
        self.live: List[int] = []
        self.seg_kfs: List[int] = []
        self.segment = 0
        self.store = store if store is not None else KeyframeStore()
        self.anchors: Dict[int, Anchor] = {}
        self.support_pose: Dict[int, np.ndarray] = {}
        self.candidates: List[SupportCandidate] = []

    # ------------------------------------------------------------ keyframes
    @property
    def next_index(self) -> int:
        """The index the next keyframe gets."""
        return len(self.order)

    @property
    def latest(self) -> MapKeyframe:
        """The current segment's newest keyframe."""
        return self.kfs[self.seg_kfs[-1]]

    def add(self, kf: MapKeyframe, new_segment: bool = False) -> None:
        """Append keyframe ``kf`` (index :attr:`next_index`) to the map and to the
        current segment (``new_segment``: as the segment's keyframe 0)."""
        self.kfs[kf.index] = kf
        self.order.append(kf.index)
        self.live.append(kf.index)
        if new_segment:
            self.seg_kfs = [kf.index]
        else:
            self.seg_kfs.append(kf.index)

    def window_kfs(self, extra: int = 0) -> List[MapKeyframe]:
        """The current segment's last ``window + extra`` keyframes, oldest first."""
        return [self.kfs[k] for k in self.seg_kfs[-(self.window + extra):]]

    def segment_live(self) -> List[MapKeyframe]:
        """The current segment's keyframes not retired, in order."""
        return [self.kfs[j] for j in self.seg_kfs if not self.kfs[j].retired]

    def live_poses(self) -> Dict[int, np.ndarray]:
        """Keyframe index -> ``T_world_kf`` of the live keyframes."""
        return {j: self.kfs[j].T_world_kf for j in self.live}

    def retire_outside_window(self) -> None:
        """Retire the keyframes outside the current segment's last ``window``
        (marginalised by the smoother, or of an earlier segment: final)."""
        keep = set(self.seg_kfs[-self.window:])
        for k in [k for k in self.live if k not in keep]:
            self.kfs[k].retire(self.store)
        self.live = [k for k in self.live if k in keep]

    def restore(self, k: int) -> Tuple[np.ndarray, Keyframe]:
        """``(input image, Keyframe)`` of keyframe ``k`` (read from the store if retired)."""
        return self.kfs[k].restore(self.store, self.levels)

    def iter_keyframes(self, indices: Optional[Iterable[int]] = None
                       ) -> Iterator[Tuple[int, np.ndarray, Keyframe]]:
        """``(k, input image, Keyframe)`` of keyframes ``indices`` (default: all),
        in the order given, read back from the store one at a time."""
        for k in (self.order if indices is None else indices):
            yield (k, *self.restore(k))

    def keyframes_with_depth(self, uses_depth: bool) -> List[int]:
        """Indices of the keyframes whose primitives carry depth: all with a
        depth-using front-end (``uses_depth``); monocular, those of segments
        with at least two keyframes."""
        if uses_depth:
            return list(self.order)
        per_segment: Dict[int, int] = {}
        for k in self.order:
            per_segment[self.kfs[k].segment] = per_segment.get(self.kfs[k].segment, 0) + 1
        return [k for k in self.order if per_segment[self.kfs[k].segment] >= 2]

    # ------------------------------------------------------------ frames
    def add_candidate(self, cand: SupportCandidate) -> None:
        """Keep ``cand`` as a supporting-frame candidate of the newest keyframe
        (every other one dropped when more than ``max(8 n_support, 16)``)."""
        self.candidates.append(cand)
        cap = max(8 * self.n_support, 16)
        if len(self.candidates) > cap:
            self.candidates = self.candidates[::2]

    def frame_pose(self, k: int, T_kf_frame: np.ndarray, median_then: float) -> np.ndarray:
        """``T_world_frame`` of a frame tracked against keyframe ``k``: the
        keyframe's latest pose composed with the tracked relative pose, whose
        translation is rescaled by the change of the keyframe's median depth
        since tracking (mapping refines the keyframe's scales; the tracked
        translation was measured in the old depth units)."""
        kf = self.kfs[k]
        T = np.array(T_kf_frame, dtype=float)
        if median_then > 0:
            T[:3, 3] *= kf.median_depth / median_then
        return kf.T_world_kf @ T

    def frame_poses(self, frames: Sequence[FrameResult]) -> Tuple[np.ndarray, np.ndarray]:
        """``(poses (n, 4, 4), is_keyframe (n,))`` of ``frames`` (every frame so
        far): a keyframe's pose, else a supporting frame's smoothed pose, else
        the pose anchored to its keyframe (:meth:`frame_pose`), else a lost
        frame keeps the previous frame's pose, else its online pose."""
        n = len(frames)
        poses = np.empty((n, 4, 4))
        is_kf = np.zeros(n, dtype=bool)
        kf_of_frame = {kf.frame: kf for kf in self.kfs.values()}
        for i, f in enumerate(frames):
            if i in kf_of_frame:
                poses[i] = kf_of_frame[i].T_world_kf
                is_kf[i] = True
            elif i in self.support_pose:
                poses[i] = self.support_pose[i]
            elif i in self.anchors and self.anchors[i][0] in self.kfs:
                poses[i] = self.frame_pose(*self.anchors[i])
            elif f.status is FrameStatus.LOST and i > 0:
                poses[i] = poses[i - 1]
            else:
                poses[i] = f.T_world_cam
        return poses, is_kf

    # ------------------------------------------------------------ corrections
    def apply_similarity(self, kf_ids: Iterable[int],
                         move_keyframe: Callable[[MapKeyframe], np.ndarray],
                         motion: MotionModel,
                         candidate_scale: Callable[[Dict[int, np.ndarray]], float]) -> bool:
        """Move keyframes ``kf_ids`` and what follows them.

        Each keyframe is moved by ``move_keyframe`` (its pose and depths, the
        caller's arithmetic), which returns its world similarity ``W_new_old``
        (``S_world_kf(new) @ inv(T_world_kf(old))``, 4x4).  Frames anchored to a
        keyframe follow it in :meth:`frame_poses` through its pose and median
        depth; the supporting frames' smoothed poses move by their keyframe's
        ``W`` (:func:`spgeo.loop.sim3.moved_frame`); when the segment's newest
        keyframe moved, ``motion``'s poses move by its ``W`` and the
        candidates' translations (in their keyframe's depth units) are
        multiplied by ``candidate_scale(W)``.  Returns whether the newest
        keyframe moved."""
        W = {k: move_keyframe(self.kfs[k]) for k in kf_ids}
        sup = self.support_pose
        for f in list(sup):
            k = self.anchors[f][0] if f in self.anchors else None
            if k in W:
                sup[f] = moved_frame(W[k], sup[f])
        newest = self.seg_kfs[-1] if self.seg_kfs else None
        if newest not in W:
            return False
        motion.move(lambda T: moved_frame(W[newest], T))
        s = candidate_scale(W)
        for c in self.candidates:
            c.T_kf_frame = c.T_kf_frame.copy()
            c.T_kf_frame[:3, 3] *= s
        return True
