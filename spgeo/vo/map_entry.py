"""Entering a saved map (``spgeo vo --load-map DIR``, issue 53): the first frames of a
run are relocalised into a :class:`~spgeo.vo.saved_map.SavedMap` until one is placed;
the saved keyframe it was placed against and the ones before it in its saved segment
(up to ``window`` in all) become the keyframes of the run's first map segment, with
their poses and scales, the one it was placed against the newest (so the run continues
in the saved map's world frame and units, tracked at once, with no two-view
initialisation; the window smoother holds their poses at the saved ones).

Relocalisation is the one tracking decision (:meth:`FrameTracker.track
<spgeo.vo.frame_tracker.FrameTracker.track>`) against a saved keyframe: from its own
pose, then from the PnP pose on the saved landmarks (its segment's), then from the PnP
pose on the keyframe's features lifted by its primitives' depth.  The keyframes tried
for a frame are at most :data:`MAX_CANDIDATES`: those that last saw the most landmarks
the frame's features match first, then the newest (a run that continues where the
saved one stopped is placed against its last keyframe).  A frame not placed is lost
(at the identity: no trajectory line); after ``max_lost_frames`` frames not placed the
run gives up and starts a map of its own (:attr:`MapEntry.given_up`).
"""
from __future__ import annotations

import logging
from typing import Dict, List, Optional, Tuple

import numpy as np

from .config import OdometryConfig
from .frame_tracker import FrameTracker
from .landmark_snapshot import LandmarkSnapshot
from .map import MapKeyframe
from .saved_map import SavedKeyframe, SavedMap
from .tracking import TrackResult

__all__ = ["MapEntry", "MAX_CANDIDATES"]

log = logging.getLogger(__name__)

#: saved keyframes tried per frame (each costs a photometric track and, with the feature
#: retry, its features once)
MAX_CANDIDATES = 6


class MapEntry:
    """Relocalising a run's first frames into a saved map (module docstring).

    Args:
        saved: the map (already checked to fit the run,
            :meth:`SavedMap.check_fits`).
        tracker: the odometry's :class:`FrameTracker`.
        config: the odometry's :class:`OdometryConfig` (``keyframe_levels``,
            ``selection``, ``max_lost_frames``, ``feature_retry``).

    Attributes:
        tries: frames tried so far.
    """

    def __init__(self, saved: SavedMap, tracker: FrameTracker, config: OdometryConfig) -> None:
        self.saved, self._tracker, self._config = saved, tracker, config
        self.tries = 0
        self._built: Dict[int, MapKeyframe] = {}

    @property
    def given_up(self) -> bool:
        """``max_lost_frames`` frames were tried and none was placed."""
        return self.tries >= self._config.max_lost_frames

    def step(self, image: np.ndarray, index: int, segment: int
             ) -> Optional[Tuple[List[MapKeyframe], TrackResult, Optional[LandmarkSnapshot]]]:
        """Relocalise the frame ``image`` (processing size): ``(keyframes, track
        result, landmarks)`` when it is placed — the saved keyframe it was placed
        against, last, after those before it in its saved segment (at most
        ``window`` in all), as map keyframes ``index, index + 1, ...`` of ``segment``
        (frame number -1, every shape prior at ``render_prior_weight``: their scales
        are the saved map's), and the saved landmarks of its segment (None: none) —
        else None.  Logs a warning when it gives up (:attr:`given_up`)."""
        self.tries += 1
        for kf in self._candidates(image):
            mkf = self._keyframe(kf)
            lms = self.saved.landmarks
            lms = lms if lms is not None and lms.segment == kf.segment else None
            tr = self._tracker.track(mkf, image, [lambda kf=kf: kf.T_world_kf], np.zeros(2),
                                     features=True, landmarks=lms)
            if tr is not None and tr.ok:
                log.info("relocalised into the saved map against its keyframe %d (frame %d of "
                         "the run that saved it)", kf.index, kf.frame)
                kfs = [self._keyframe(k) for k in self._before(kf)] + [mkf]
                self._built.clear()
                w = float(self._config.render_prior_weight)
                return [MapKeyframe(index + j, -1, k.image, k.keyframe, segment,
                                    prior_weights=np.full(len(k.keyframe.primitives), w))
                        for j, k in enumerate(kfs)], tr, lms
        if self.given_up:
            log.warning("not relocalised into the saved map in %d frames; the run starts a "
                        "map of its own", self.tries)
        return None

    def _candidates(self, image: np.ndarray) -> List[SavedKeyframe]:
        """The saved keyframes to try for ``image``: by landmark votes, then newest."""
        kfs = self.saved.keyframes
        votes = np.zeros(len(kfs))
        lms = self.saved.landmarks
        if lms is not None and len(lms) and self._config.feature_retry.enabled:
            _, desc = self._tracker.frame_features(image)
            pairs = lms.matches(desc, self._config.feature_retry.features)
            seen = lms.keyframes[pairs[:, 0]] if len(pairs) else np.zeros(0, np.int64)
            position = {(kf.segment, kf.index): i for i, kf in enumerate(kfs)}
            for k in seen:
                i = position.get((lms.segment, int(k)))
                if i is not None:
                    votes[i] += 1
        order = sorted(range(len(kfs)), key=lambda i: (-votes[i], -i))
        return [kfs[i] for i in order[:MAX_CANDIDATES]]

    def _before(self, kf: SavedKeyframe) -> List[SavedKeyframe]:
        """The saved keyframes before ``kf`` in its segment that join it in the
        window (``window - 1`` at most, oldest first)."""
        same = [k for k in self.saved.keyframes if k.segment == kf.segment]
        i = next(j for j, k in enumerate(same) if k.index == kf.index)
        return same[max(0, i - self._config.window + 1):i]

    def _keyframe(self, kf: SavedKeyframe) -> MapKeyframe:
        """The map keyframe of saved ``kf`` to track against (built once; its
        feature-cache key negative, apart from the run's own keyframes)."""
        if kf.index not in self._built:
            keyframe = kf.keyframe(self._config.keyframe_levels, self._config.selection)
            self._built[kf.index] = MapKeyframe(-1 - kf.index, -1, kf.image, keyframe,
                                                kf.segment)
        return self._built[kf.index]
