"""Loop closure inside the VO (docs/design.md §5.2): the :class:`spgeo.loop.LoopCloser`
of the current map segment, fed by :class:`spgeo.vo.Odometry`.

Loops are closed *within a map segment* only: segments (re-initialisations) have
different, unknown scales, and the loop closer's pose graph links consecutive
keyframes by odometry edges of scale 1, so each segment gets its own
:class:`~spgeo.loop.LoopCloser` (its first keyframe holds the gauge of the
correction) and the keyframes of earlier segments never move.
"""
from __future__ import annotations

import logging
import time
from typing import Dict, List, Mapping, Optional, Sequence

import numpy as np

from ..camera import PinholeCamera
from ..loop import LoopCloser, LoopClosureConfig, LoopCorrection
from ..similarity import sim3_parts
from .landmarks import LandmarkMap
from .map import MapKeyframe

__all__ = ["SegmentLoopClosure"]

log = logging.getLogger(__name__)


class SegmentLoopClosure:
    """Loop detection and correction over the current map segment's keyframes.

    Args:
        camera: the camera of the keyframe images (the odometry's input camera).
        config: :class:`~spgeo.loop.LoopClosureConfig`.

    Attributes:
        accepted: one JSON-ready dict per accepted loop (segment, keyframe pair and
            their frame numbers, ``S_cand_query`` (4x4, as detected: candidate camera
            from query camera) and its scale, the largest rotation sigma (deg) and the
            log-scale sigma of its information, matches, inliers, neighbour support,
            the number of keyframes corrected and the range of their depth factors).
        seconds: total time spent (features, detection, correction).
    """

    def __init__(self, camera: PinholeCamera, config: LoopClosureConfig) -> None:
        self.camera = camera
        self.config = config
        self.segment: Optional[int] = None
        self.closer: Optional[LoopCloser] = None
        self.accepted: List[dict] = []
        self._frames: Dict[int, int] = {}   # keyframe index -> frame number
        self._rejected_before = 0     # rejections of earlier segments' closers
        self.seconds = 0.0

    def add_keyframes(self, segment: int, keyframes: Sequence[MapKeyframe],
                      landmarks: Optional[LandmarkMap] = None) -> Optional[LoopCorrection]:
        """Register the keyframes of ``keyframes`` (the current segment's, in order,
        live) not registered yet, the newest last; a new ``segment`` starts a new
        loop closer.  With the odometry's ``landmarks`` (the new keyframes' already
        associated), keyframes the new one is connected to by landmarks are not loop
        candidates (:meth:`connected_from`).  Returns the correction of an accepted
        loop (not yet applied to the keyframes: :meth:`spgeo.vo.Odometry` does
        that), or None."""
        t = time.perf_counter()
        if segment != self.segment:
            if self.closer is not None:
                self._rejected_before += self.closer.n_rejected
            self.segment, self.closer = segment, LoopCloser(self.camera, self.config)
        ids = self.closer.database.ids()
        corr = None
        for kf in keyframes:
            if ids and kf.index <= ids[-1]:
                continue
            self._frames[kf.index] = kf.frame
            depth = kf.keyframe.primitives.depth_map()
            n_loops = len(self.closer.loops)
            loop = self.closer.add_keyframe(kf.index, kf.image, depth, kf.keyframe.T_world_kf,
                                            self.connected_from(kf.index, landmarks))
            if loop is not None:
                found = [self._describe(lp) for lp in self.closer.loops[n_loops:]]
                corr = self.closer.correct(apply=True)
                self._record(found, corr)
        self.seconds += time.perf_counter() - t
        return corr

    def connected_from(self, k: int, landmarks: Optional[LandmarkMap]) -> Optional[int]:
        """The oldest keyframe that keyframe ``k`` is connected to by ``landmarks``:
        ``k`` observes ``min_neighbour_inliers`` landmarks first seen in keyframe ``f``
        or earlier; keyframes from ``f - neighbour_radius`` on are connected (the map
        already holds them together: no loop needed).  None without landmarks or
        with too few."""
        if landmarks is None:
            return None
        vcfg = self.config.verification
        first = sorted(lm.first_seen for lm in landmarks.observed_in(k))
        if len(first) < vcfg.min_neighbour_inliers:
            return None
        return first[vcfg.min_neighbour_inliers - 1] - vcfg.neighbour_radius

    def _describe(self, loop) -> dict:
        """A loop as detected (JSON-ready), before a correction rescales it."""
        sig = np.sqrt(np.diag(np.linalg.inv(loop.information)))
        return {
            "segment": int(self.segment), "query_keyframe": int(loop.query_id),
            "candidate_keyframe": int(loop.candidate_id),
            "query_frame": int(self._frames[loop.query_id]),
            "candidate_frame": int(self._frames[loop.candidate_id]),
            "scale": float(sim3_parts(loop.S_cand_query)[2]),
            "S_cand_query": np.asarray(loop.S_cand_query, dtype=float).tolist(),
            "sigma_rotation_deg": float(np.degrees(sig[:3].max())),
            "sigma_log_scale": float(sig[6]),
            "matches": int(loop.n_matches), "inliers": int(loop.n_inliers),
            "inlier_ratio": float(loop.inlier_ratio),
            "neighbour_support": int(loop.neighbour_support)}

    def _record(self, found: List[dict], corr: LoopCorrection) -> None:
        scales = np.array([corr.scales[k] for k in corr.kf_ids])
        for d in found:
            self.accepted.append({**d, "n_keyframes_corrected": len(corr.kf_ids),
                                  "scale_range": [float(scales.min()), float(scales.max())]})
            log.info("loop closure: keyframe %d -> %d applied to %d keyframes",
                     d["query_keyframe"], d["candidate_keyframe"], len(corr.kf_ids))

    def update_poses(self, T_world_kf: Mapping[int, np.ndarray]) -> None:
        """The odometry's latest (smoothed) poses of registered keyframes."""
        if self.closer is None:
            return
        entries = self.closer.database.entries
        self.closer.update_poses({k: T for k, T in T_world_kf.items() if k in entries})

    @property
    def n_rejected(self) -> int:
        """Candidates rejected by verification or the neighbour check, all segments."""
        return self._rejected_before + (0 if self.closer is None else self.closer.n_rejected)

    def report(self) -> Dict[str, object]:
        """``{"accepted": [...], "rejected": count, "seconds": total}`` (JSON-ready)."""
        return {"accepted": list(self.accepted), "rejected": int(self.n_rejected),
                "seconds": float(self.seconds)}
