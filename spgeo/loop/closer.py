"""The loop-closure driver the odometry calls: register keyframes, detect and verify
loops, and correct all keyframes with the Sim(3) pose graph (docs/design.md §5.2).

Keyframe ids are the odometry's (increasing with time).  Poses are rigid
camera-to-world ``T_world_kf``; each keyframe's depths are in its own units (a
monocular map drifts in scale).  A correction gives every keyframe a new rigid pose and
a factor ``s`` for its depths (log-scales ``+= log s``); the driver applies it to its own
copy of the map, the odometry to its keyframes (:class:`LoopCorrection`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Dict, List, Mapping, Optional

import numpy as np

from ..camera import PinholeCamera
from ..geometry import check_pose, invert_pose
from ..similarity import moved_frame, sim3, sim3_parts
from .config import LoopClosureConfig
from .database import Candidate, KeyframeDatabase
from .pose_graph import PoseGraphResult, Sim3Edge, odometry_edges, optimise_sim3_pose_graph
from .verify import KeyframeFeatures, count_inliers, extract_features, verify_sim3

__all__ = ["LoopClosure", "LoopCorrection", "LoopCloser"]

log = logging.getLogger(__name__)


@dataclass
class LoopClosure:
    """A verified, consistent loop between keyframes ``candidate_id`` (old) and
    ``query_id`` (new).

    Attributes:
        S_cand_query: 4x4 similarity from the query's camera (its depth units) to the
            candidate's camera (its units); the scale is their depth-unit ratio.
        n_matches, n_inliers, inlier_ratio: of the verification.
        neighbour_support: neighbours of the candidate that agreed.
        information: (7, 7) information of ``S_cand_query`` (GTSAM Similarity3
            tangent, right perturbation) from the verification's refinement.
    """

    query_id: int
    candidate_id: int
    S_cand_query: np.ndarray
    n_matches: int
    n_inliers: int
    inlier_ratio: float
    neighbour_support: int
    information: np.ndarray


@dataclass
class LoopCorrection:
    """The corrected map of :meth:`LoopCloser.correct`.

    Attributes:
        kf_ids: the keyframes, ascending.
        T_world_kf: corrected rigid camera-to-world pose per keyframe id.
        scales: per keyframe id, the factor on its depths (log-scale ``+= log s``).
        W_new_old: per keyframe id, the world similarity ``S_world_kf(new) @ inv(T_world_kf(old))``
            that moves the keyframe's old map (pose and depths) to the corrected one.
        graph: the pose graph's :class:`~spgeo.loop.PoseGraphResult`.
    """

    kf_ids: List[int]
    T_world_kf: Dict[int, np.ndarray]
    scales: Dict[int, float]
    W_new_old: Dict[int, np.ndarray]
    graph: PoseGraphResult

    def frame_pose(self, kf_id: int, T_world_frame: np.ndarray) -> np.ndarray:
        """Corrected rigid camera-to-world pose of a (non-key)frame anchored to keyframe
        ``kf_id``, from its old ``T_world_frame``: the frame moves with the keyframe's map
        (its offset from the keyframe grows by the keyframe's scale)."""
        return moved_frame(self.W_new_old[kf_id], check_pose(T_world_frame, "T_world_frame"))


class LoopCloser:
    """Keyframe database, loop detection and Sim(3) correction.

    Args:
        camera: the camera of the keyframe images passed to :meth:`add_keyframe`.
        config: :class:`~spgeo.loop.LoopClosureConfig`.
    """

    def __init__(self, camera: PinholeCamera, config: LoopClosureConfig = LoopClosureConfig()
                 ) -> None:
        self.camera = camera
        self.config = config
        self.database = KeyframeDatabase(config.recognition)
        self.loops: List[LoopClosure] = []
        self.n_rejected = 0     # candidates rejected by verification or the neighbour check
        self._streak: List[LoopClosure] = []   # consecutive detections, not yet accepted

    def add_keyframe(self, kf_id: int, image: np.ndarray, depth: np.ndarray,
                     T_world_kf: np.ndarray, connected_from: Optional[int] = None
                     ) -> Optional[LoopClosure]:
        """Register a new keyframe and look for a loop to an older one.

        Args:
            kf_id: the keyframe's id, larger than every id registered before.
            image: its image (``camera``'s size).
            depth: its depth map in its own units at any resolution (NaN / <= 0 where
                unknown), e.g. ``primitives.depth_map()``.
            T_world_kf: its rigid camera-to-world pose.
            connected_from: keyframes with ids from this one on are already connected
                to the new one (e.g. it re-observes their landmarks): not candidates, as
                ORB-SLAM excludes the query's covisible keyframes; None: no such
                knowledge.
        Returns:
            the accepted :class:`LoopClosure` (it and the detections of its streak,
            :meth:`_consistent`, are appended to :attr:`loops`), or None.
        """
        ids = self.database.ids()
        if ids and int(kf_id) <= ids[-1]:
            raise ValueError(f"add_keyframe: id {kf_id} is not larger than {ids[-1]}")
        features = extract_features(image, self.camera, depth, self.config.recognition.features)
        loop = self.detect(int(kf_id), features, connected_from)
        self.database.add(int(kf_id), features, T_world_kf)
        return self._consistent(loop, ids[-1] if ids else None)

    def _consistent(self, loop: Optional[LoopClosure], previous_id: Optional[int]
                    ) -> Optional[LoopClosure]:
        """Accept ``loop`` (a detection of the newest keyframe) once it closes a streak of
        ``consistent_detections`` consecutive keyframes (``previous_id`` the keyframe
        registered before it) whose candidates lie within ``neighbour_radius`` of the
        previous one's.  The streak's loops go to :attr:`loops`."""
        vcfg = self.config.verification
        if loop is None:
            self._streak = []
            return None
        last = self._streak[-1] if self._streak else None
        if last is None or last.query_id != previous_id \
                or abs(last.candidate_id - loop.candidate_id) > vcfg.neighbour_radius:
            self._streak = []
        self._streak.append(loop)
        if len(self._streak) < vcfg.consistent_detections:
            log.debug("loop %d -> %d detected (%d of %d consistent)", loop.query_id,
                      loop.candidate_id, len(self._streak), vcfg.consistent_detections)
            return None
        self.loops.extend(self._streak)
        self._streak = []
        return loop

    def detect(self, query_id: int, features: KeyframeFeatures,
               connected_from: Optional[int] = None) -> Optional[LoopClosure]:
        """The first candidate (most matches first, older than ``connected_from``) that
        passes verification and the neighbour check, as a :class:`LoopClosure`; None
        otherwise.  Nothing is stored."""
        vcfg = self.config.verification
        for cand in self.database.candidates(query_id, features, connected_from):
            ver = verify_sim3(features, self.database.entries[cand.kf_id].features, cand.pairs,
                              vcfg)
            if not ver.accepted:
                log.debug("loop %d -> %d rejected: %s (%d of %d)", query_id, cand.kf_id, ver.reason,
                          ver.n_inliers, ver.n_matches)
                self.n_rejected += 1
                continue
            support = self._neighbour_support(query_id, cand, features, ver.S_cand_query)
            if support < vcfg.min_neighbour_support:
                log.debug("loop %d -> %d rejected: %d neighbours agree", query_id, cand.kf_id,
                          support)
                self.n_rejected += 1
                continue
            log.info("loop closed: keyframe %d -> %d (%d inliers of %d, %d neighbours agree)",
                     query_id, cand.kf_id, ver.n_inliers, ver.n_matches, support)
            return LoopClosure(query_id, cand.kf_id, ver.S_cand_query, ver.n_matches,
                               ver.n_inliers, ver.inlier_ratio, support, ver.information)
        return None

    def _neighbour_support(self, query_id: int, cand: Candidate, features: KeyframeFeatures,
                           S_cand_query: np.ndarray) -> int:
        """Neighbours of the candidate whose matches with the query the candidate's
        ``S_cand_query``, carried over by the odometry poses, explains."""
        vcfg = self.config.verification
        db = self.database
        T_world_c = db.entries[cand.kf_id].T_world_kf
        support = 0
        for n in db.eligible(query_id):
            if n == cand.kf_id or abs(n - cand.kf_id) > vcfg.neighbour_radius:
                continue
            entry = db.entries[n]
            pairs = db.matches(n, features)
            ok = np.isfinite(entry.features.points[pairs[:, 0], 0]) \
                & np.isfinite(features.points[pairs[:, 1], 0])
            pairs = pairs[ok]
            if len(pairs) < vcfg.min_neighbour_inliers:
                continue
            S_n_q = invert_pose(entry.T_world_kf) @ T_world_c @ S_cand_query
            inl = count_inliers(S_n_q, features.points[pairs[:, 1]],
                                entry.features.points[pairs[:, 0]], features.keypoints[pairs[:, 1]],
                                entry.features.keypoints[pairs[:, 0]], features.camera,
                                entry.features.camera, vcfg)
            support += int(inl.sum() >= vcfg.min_neighbour_inliers)
        return support

    def update_poses(self, T_world_kf: Mapping[int, np.ndarray]) -> None:
        """Replace stored poses with the odometry's latest (e.g. smoothed) ones."""
        for k, T in T_world_kf.items():
            self.database.entries[int(k)].T_world_kf = check_pose(T, f"T_world_kf[{k}]").copy()

    def correct(self, apply: bool = True) -> LoopCorrection:
        """Sim(3) pose graph over every registered keyframe: odometry edges between
        consecutive ids (from the stored poses, scale 1) and every accepted loop.

        Args:
            apply: also apply the correction to the stored map (poses, feature depths
                and the loops' similarities), so later loops and corrections start
                from it.
        Returns:
            :class:`LoopCorrection`.
        """
        ids = self.database.ids()
        if not ids:
            raise ValueError("LoopCloser.correct: no keyframes")
        index = {k: i for i, k in enumerate(ids)}
        poses = [self.database.entries[k].T_world_kf for k in ids]
        edges = odometry_edges(poses)
        edges += [Sim3Edge(index[lp.candidate_id], index[lp.query_id], lp.S_cand_query, loop=True,
                           information=lp.information) for lp in self.loops]
        res = optimise_sim3_pose_graph(poses, edges, self.config.pose_graph)
        corr = LoopCorrection(
            ids, {k: res.T_world_kf[i] for k, i in index.items()},
            {k: float(res.scales[i]) for k, i in index.items()},
            {k: res.S_world_kf[i] @ invert_pose(poses[i]) for k, i in index.items()}, res)
        if apply:
            self._apply(corr)
        return corr

    def _apply(self, corr: LoopCorrection) -> None:
        for k in corr.kf_ids:
            entry = self.database.entries[k]
            entry.T_world_kf = corr.T_world_kf[k].copy()
            entry.features = entry.features.scaled(corr.scales[k])
        for lp in self.loops + self._streak:
            # S' = diag(s_c) S diag(1 / s_q) in the new depth units; a right perturbation's
            # translation grows by s_q, so the information's translation rows shrink by it
            s_c, s_q = corr.scales[lp.candidate_id], corr.scales[lp.query_id]
            R, t, s = sim3_parts(lp.S_cand_query)
            lp.S_cand_query = sim3(R, s_c * t, s * s_c / s_q)
            d = np.array([1.0, 1.0, 1.0, 1.0 / s_q, 1.0 / s_q, 1.0 / s_q, 1.0])
            lp.information = lp.information * d[:, None] * d[None, :]
