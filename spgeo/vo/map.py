"""The VO's keyframe map (docs/design.md §5): its keyframes (:class:`MapKeyframe`:
numbers, image, the current :class:`~spgeo.vo.keyframe.Keyframe`, or once retired its
final pose with image and primitives in the store), keyframes in creation order, map
segments, the store of retired keyframes, the frames anchored to keyframes,
the supporting frames' smoothed poses, the supporting-frame candidates of the
newest keyframe, and one :meth:`KeyframeMap.apply_similarity` that moves all of
it with its keyframes (loop correction).

The map holds state and makes its own changes (its methods: anchoring frames, new
keyframes and segments, handing over candidates, applying a back-end update with
:meth:`KeyframeMap.apply_update`, the one similarity move
:meth:`KeyframeMap.apply_similarity`); :class:`spgeo.vo.Odometry` decides (tracking,
keyframes, when to map) and the back end (:mod:`spgeo.vo.backend`, reached through
:mod:`spgeo.vo.mapping_port`) computes the updates on its own copies.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from ..similarity import moved_frame
from .keyframe_store import KeyframeStore
from .result import FrameResult, FrameStatus
from .keyframe import with_shape_values
from .tracking import Keyframe

__all__ = ["KeyframeMap", "MapKeyframe", "SupportCandidate"]

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
    frame: int          # frame number (-1: a saved map's keyframe, no frame of this run)
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


@dataclass
class SupportCandidate:
    """A frame tracked against the latest keyframe (supporting-frame candidate):
    its image, ``T_kf_frame`` (4x4) and affine brightness ``(a, b)``."""

    frame: int
    image: np.ndarray
    T_kf_frame: np.ndarray
    brightness: np.ndarray

    def scaled(self, s: float) -> "SupportCandidate":
        """This candidate with its translation multiplied by ``s`` (its keyframe's
        depth units changed by ``s``), a copy."""
        T = np.array(self.T_kf_frame, dtype=float)
        T[:3, 3] *= s
        return SupportCandidate(self.frame, self.image, T, self.brightness)


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
        kfs: keyframe index -> :class:`~spgeo.vo.map.MapKeyframe`.
        order: keyframe indices in creation order (``0 .. n - 1``).
        live: the keyframes not retired, in creation order.
        seg_kfs: the current segment's keyframes (those the window may reach).
        scaled_segments: the segments whose keyframe 0 came with its scale (a
            keyframe of a saved map the run entered): tracked against at once.
        segment: the current map segment's number (0, 1, ...).
        store: the keyframe store.
        anchors: frame number -> ``(k, T_kf_frame, median depth of k then)`` of a
            frame tracked against keyframe ``k``.
        support_pose: frame number -> smoothed ``T_world_frame`` of a supporting
            frame (from the back end's updates, :meth:`apply_update`).
        candidates: supporting-frame candidates of the newest keyframe.
        landmarks: the current segment's landmarks as the last applied update
            left them (:class:`~spgeo.vo.landmark_snapshot.LandmarkSnapshot`), or
            None (none yet, or without landmarks).
    """

    def __init__(self, window: int, levels: int, n_support: int,
                 store: Optional[KeyframeStore] = None) -> None:
        self.window, self.levels, self.n_support = window, levels, n_support
        self.kfs: Dict[int, MapKeyframe] = {}
        self.order: List[int] = []
        self.live: List[int] = []
        self.seg_kfs: List[int] = []
        self.scaled_segments: set = set()
        self.segment = 0
        self.store = store if store is not None else KeyframeStore()
        self.anchors: Dict[int, Anchor] = {}
        self.support_pose: Dict[int, np.ndarray] = {}
        self.candidates: List[SupportCandidate] = []
        self.landmarks = None

    # ------------------------------------------------------------ keyframes
    @property
    def next_index(self) -> int:
        """The index the next keyframe gets."""
        return len(self.order)

    @property
    def latest(self) -> MapKeyframe:
        """The current segment's newest keyframe."""
        return self.kfs[self.seg_kfs[-1]]

    @property
    def tracking(self) -> bool:
        """Frames of the current segment are tracked against its map: it has
        keyframe 1, or its keyframe 0 came with its scale (:attr:`seg_scaled`)."""
        return len(self.seg_kfs) >= 2 or (self.segment in self.scaled_segments
                                          and len(self.seg_kfs) == 1)

    def add(self, kf: MapKeyframe, new_segment: bool = False, scaled: bool = False) -> None:
        """Append keyframe ``kf`` (index :attr:`next_index`) to the map and to the
        current segment (``new_segment``: as the segment's keyframe 0, ``scaled``:
        one that comes with its scale, :attr:`scaled_segments`); its frame is no longer
        anchored (a keyframe's pose is its own)."""
        self.kfs[kf.index] = kf
        self.order.append(kf.index)
        self.live.append(kf.index)
        self.anchors.pop(kf.frame, None)
        if new_segment:
            self.seg_kfs = [kf.index]
            if scaled:
                self.scaled_segments.add(kf.segment)
        else:
            self.seg_kfs.append(kf.index)

    def window_kfs(self, extra: int = 0) -> List[MapKeyframe]:
        """The current segment's last ``window + extra`` keyframes, oldest first."""
        return [self.kfs[k] for k in self.seg_kfs[-(self.window + extra):]]

    def older_in_window(self) -> List[MapKeyframe]:
        """The current segment's window keyframes before the newest, newest first
        (relocalisation's order)."""
        return [self.kfs[k] for k in reversed(self.seg_kfs[-self.window:-1])]

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
        with at least two keyframes or a keyframe 0 that came with its scale."""
        if uses_depth:
            return list(self.order)
        per_segment: Dict[int, int] = {}
        for k in self.order:
            per_segment[self.kfs[k].segment] = per_segment.get(self.kfs[k].segment, 0) + 1
        return [k for k in self.order if per_segment[self.kfs[k].segment] >= 2
                or self.kfs[k].segment in self.scaled_segments]

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
        since tracking (:meth:`relative_pose`)."""
        return self.kfs[k].T_world_kf @ self.relative_pose(k, T_kf_frame, median_then)

    def relative_pose(self, k: int, T_kf_frame: np.ndarray, median_then: float) -> np.ndarray:
        """``T_kf_frame`` (tracked against keyframe ``k`` when its median depth was
        ``median_then``) in ``k``'s current depth units: its translation rescaled by
        the change of the median depth since (mapping refines the keyframe's
        scales; the tracked translation was measured in the old units); a copy."""
        T = np.array(T_kf_frame, dtype=float)
        if median_then > 0:
            T[:3, 3] *= self.kfs[k].median_depth / median_then
        return T

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

    # ------------------------------------------------------------ changes
    def anchor(self, frame: int, k: int, T_kf_frame: np.ndarray, median_then: float) -> None:
        """Frame ``frame`` tracked against keyframe ``k`` at ``T_kf_frame`` (4x4),
        ``median_then`` the keyframe's median depth then (:meth:`frame_pose`)."""
        self.anchors[frame] = (k, T_kf_frame, median_then)

    def unanchor(self, frame: int) -> None:
        """Frame ``frame`` no longer follows a keyframe (e.g. lost when tracked again)."""
        self.anchors.pop(frame, None)

    def begin_segment(self) -> None:
        """A new map segment (re-initialisation): its keyframe 0 comes next
        (:meth:`add` with ``new_segment``); the old segment's landmarks are
        dropped (another scale)."""
        self.segment += 1
        self.landmarks = None

    def replace_keyframe(self, k: int, keyframe: Keyframe) -> None:
        """Live keyframe ``k``'s :class:`Keyframe` becomes ``keyframe`` (e.g. an
        initialisation's solved keyframe 0)."""
        self.kfs[k].keyframe = keyframe

    def take_candidates(self) -> List[SupportCandidate]:
        """The newest keyframe's supporting-frame candidates, handed over (the
        list starts empty for the next keyframe)."""
        taken, self.candidates = self.candidates, []
        return taken

    def apply_update(self, upd, primitive_model: str, follow_newest: bool
                     ) -> Tuple[Dict[int, Keyframe], Optional[np.ndarray]]:
        """Apply a back end's :class:`~spgeo.vo.backend.MappingUpdate`: its loop
        correction first (:meth:`apply_loop_correction`, ``follow_newest`` passed
        on), then the refreshed keyframes (the back end's own objects where it
        sent them, else :func:`~spgeo.vo.keyframe.with_shape_values` of ours:
        equal numbers), the supporting frames' poses, the landmarks (of this
        segment), a window restart (the
        segment keeps its last two keyframes) and retirement.  Returns
        ``(changed, W)``: keyframe index -> the new :class:`Keyframe` of every
        live keyframe that changed, and the loop correction's world similarity of
        the newest keyframe for the caller's motion model (None: no loop
        correction, or it left the newest keyframe or ``follow_newest`` is off)."""
        changed: Dict[int, Keyframe] = {}
        W = None
        if upd.loop is not None:
            W = self.apply_loop_correction(upd.loop, follow_newest)
            changed.update({k: self.kfs[k].keyframe for k in upd.loop.kf_ids
                            if not self.kfs[k].retired})
        for j, (T, th) in sorted(upd.keyframes.items()):
            mk = self.kfs[j]
            built = upd.built.get(j)
            mk.keyframe = (built if built is not None
                           else with_shape_values(mk.keyframe, th, primitive_model, T))
            changed[j] = mk.keyframe
        self.support_pose.update(upd.support_pose)
        if upd.snapshot is not None and upd.snapshot.segment == self.segment:
            self.landmarks = upd.snapshot
        if upd.restarted:
            self.seg_kfs = self.seg_kfs[-2:]
        self.retire_outside_window()
        return {k: kf for k, kf in changed.items() if not self.kfs[k].retired}, W

    def adopt_retracked(self, kf: MapKeyframe, retracked: Sequence) -> None:
        """Frames tracked again against the live keyframe ``kf`` (``retracked``:
        :class:`~spgeo.vo.frame_tracker.RetrackedFrame`; an initialisation's
        buffer against its solved keyframe 0, or the frames of a solve beside the
        tracker against keyframe 1): the ones tracked become anchored to ``kf``
        and supporting-frame candidates, the others lose their anchor.  Their
        :class:`FrameResult` is the caller's to rewrite."""
        for r in retracked:
            if r.ok:
                self.anchors[r.frame] = (kf.index, r.T_kf_frame, kf.keyframe.median_depth)
                self.candidates.append(SupportCandidate(r.frame, r.image, r.T_kf_frame,
                                                        r.brightness))
            else:
                self.anchors.pop(r.frame, None)

    def apply_loop_correction(self, corr, follow_newest: bool) -> Optional[np.ndarray]:
        """Move the segment's map by a :class:`spgeo.loop.LoopCorrection`: every
        keyframe's pose and depths (:meth:`MapKeyframe.correct`), then what
        follows them (:meth:`apply_similarity` with ``follow_newest``; the
        candidates' translations in the previous keyframe's depth units).
        Returns :meth:`apply_similarity`'s similarity of the newest keyframe."""
        for k in corr.kf_ids:
            self.kfs[k].correct(corr.T_world_kf[k], corr.scales[k])
        s_prev = corr.scales.get(self.seg_kfs[-2], 1.0) if len(self.seg_kfs) >= 2 else 1.0
        return self.apply_similarity(corr.W_new_old, s_prev, follow_newest)

    def apply_similarity(self, W_new_old: Dict[int, np.ndarray], candidate_scale: float,
                         follow_newest: bool = True) -> Optional[np.ndarray]:
        """The one similarity move of what follows keyframes whose map moved by the
        world similarities ``W_new_old`` (keyframe index -> 4x4 ``S_world_kf(new) @
        inv(T_world_kf(old))``; the keyframes themselves are the caller's): frames
        anchored to a keyframe follow it in :meth:`frame_poses` through its pose
        and median depth; the supporting frames' smoothed poses move by their
        keyframe's ``W`` (:func:`spgeo.similarity.moved_frame`); when the
        segment's newest keyframe moved and ``follow_newest`` (else what follows
        the newest keyframe is left to the caller), the candidates' translations
        (in its depth units) are multiplied by ``candidate_scale`` and its ``W``
        is returned: the caller's motion model follows it
        (:meth:`~spgeo.vo.motion.MotionModel.follow`).  Otherwise None."""
        sup = self.support_pose
        for f in list(sup):
            k = self.anchors[f][0] if f in self.anchors else None
            if k in W_new_old:
                sup[f] = moved_frame(W_new_old[k], sup[f])
        newest = self.seg_kfs[-1] if self.seg_kfs else None
        if not follow_newest or newest not in W_new_old:
            return None
        self.candidates = [c.scaled(candidate_scale) for c in self.candidates]
        return W_new_old[newest]
