"""The keyframe database of loop closure: per keyframe its features lifted to 3-D and
its camera-to-world pose, and the retrieval of loop candidates for a query keyframe
(descriptor matching against every keyframe old enough, docs/design.md §5.2)."""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Dict, List, Optional

import numpy as np

from ..geometry import check_pose
from .config import PlaceRecognitionConfig
from .verify import KeyframeFeatures, match_features

__all__ = ["DatabaseEntry", "Candidate", "KeyframeDatabase"]

log = logging.getLogger(__name__)


@dataclass
class DatabaseEntry:
    """One stored keyframe: ``features`` (camera frame, its depth units) and
    ``T_world_kf`` (rigid camera-to-world, the latest pose the odometry gave)."""

    kf_id: int
    features: KeyframeFeatures
    T_world_kf: np.ndarray


@dataclass
class Candidate:
    """A loop candidate: keyframe ``kf_id`` and its matches ``pairs`` (M, 2)
    ``(index in the candidate's features, index in the query's)``."""

    kf_id: int
    pairs: np.ndarray

    @property
    def n_matches(self) -> int:
        return len(self.pairs)


class KeyframeDatabase:
    """Keyframes by id (ids increase with time), searched by descriptor matching.

    Args:
        config: :class:`PlaceRecognitionConfig`.
    """

    def __init__(self, config: PlaceRecognitionConfig = PlaceRecognitionConfig()) -> None:
        self.config = config
        self.entries: Dict[int, DatabaseEntry] = {}

    def __len__(self) -> int:
        return len(self.entries)

    def ids(self) -> List[int]:
        """Stored keyframe ids, ascending."""
        return sorted(self.entries)

    def add(self, kf_id: int, features: KeyframeFeatures, T_world_kf: np.ndarray) -> None:
        """Store a keyframe (replacing one with the same id).  Float descriptors whose
        values are whole numbers in [0, 255] (OpenCV's SIFT) are kept as uint8, a
        quarter of the memory (:func:`~spgeo.twoview.backends.ratio_matches` matches them
        as the float32 values they are)."""
        d = features.descriptors
        if d is not None and d.dtype == np.float32 and d.size and d.min() >= 0 \
                and d.max() <= 255 and np.array_equal(d, np.round(d)):
            features = replace(features, descriptors=d.astype(np.uint8))
        self.entries[int(kf_id)] = DatabaseEntry(int(kf_id), features,
                                                 check_pose(T_world_kf, "T_world_kf").copy())

    def eligible(self, query_id: int, connected_from: Optional[int] = None) -> List[int]:
        """Ids old enough to close a loop with ``query_id`` (at most
        ``query_id - min_keyframe_gap``, and below ``connected_from`` when given: the
        keyframes from there on are already connected to the query), ascending."""
        limit = int(query_id) - self.config.min_keyframe_gap
        if connected_from is not None:
            limit = min(limit, int(connected_from) - 1)
        return [k for k in self.ids() if k <= limit]

    def matches(self, kf_id: int, query: KeyframeFeatures) -> np.ndarray:
        """(M, 2) matches ``(index in keyframe kf_id, index in query)``."""
        return match_features(self.entries[kf_id].features, query, self.config.features)

    def candidates(self, query_id: int, query: KeyframeFeatures,
                   connected_from: Optional[int] = None) -> List[Candidate]:
        """Eligible keyframes (:meth:`eligible`) with at least ``min_matches`` matches to
        ``query``, most matches first, at most ``max_candidates``."""
        found = []
        for k in self.eligible(query_id, connected_from):
            pairs = self.matches(k, query)
            if len(pairs) >= self.config.min_matches:
                found.append(Candidate(k, pairs))
        found.sort(key=lambda c: (-c.n_matches, c.kf_id))
        log.debug("loop query %d: %d candidates", query_id, len(found))
        return found[:self.config.max_candidates]
