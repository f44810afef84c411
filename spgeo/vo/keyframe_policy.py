"""The VO's one keyframe policy (docs/design.md §5.1, *Keyframes*): when a tracked
frame becomes a keyframe, against which reference, and whether the decision waits
for the back end (live mapping's deferral).  :class:`KeyframePolicy` decides;
:class:`spgeo.vo.Odometry` carries the decision out and
:class:`~spgeo.vo.keyframe_builder.KeyframeBuilder` builds the keyframe.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from ..geometry import rotation_angle_deg
from .config import KeyframeDecisionConfig
from .map import MapKeyframe
from .tracking import TrackResult

__all__ = ["KeyframePolicy", "UpdateSchedule", "NO_KEYFRAME", "KEYFRAME", "AFTER_UPDATE"]

#: :meth:`KeyframePolicy.decide` values: no keyframe (none wanted, or deferred), a keyframe
#: now, or the pending update applied first and the frame tracked and decided again
NO_KEYFRAME, KEYFRAME, AFTER_UPDATE = "none", "keyframe", "after_update"


class UpdateSchedule(Protocol):
    """What the policy asks of the mapping port
    (:class:`~spgeo.vo.mapping_port.MappingPort` is one)."""

    @property
    def pending(self) -> bool:
        """Whether an update is in flight."""

    def update_available(self) -> bool:
        """Whether the schedule lets a keyframe wanted now wait for it."""

    def defer_keyframe(self) -> None:
        """A keyframe decision deferred (counted in the port's record)."""


class KeyframePolicy:
    """When a frame becomes a keyframe (module docstring).

    Args:
        config: the thresholds (``OdometryConfig.keyframe``).
        port: the VO's :class:`~spgeo.vo.mapping_port.MappingPort`
            (:class:`UpdateSchedule`): whether an update is pending and whether its
            schedule lets a keyframe wait for it.
    """

    def __init__(self, config: KeyframeDecisionConfig, port: UpdateSchedule) -> None:
        self.config = config
        self._port = port

    def decide(self, tr: TrackResult, T_ref_f: np.ndarray, ref: MapKeyframe,
               latest: MapKeyframe) -> str:
        """The decision for a frame tracked ``tr`` against ``ref`` at ``T_ref_f``
        (``T_ref_frame``, translation in ``ref``'s depth units), ``latest`` the
        segment's newest keyframe.  A keyframe is wanted when ``ref`` is an older
        keyframe (relocalised: the new keyframe re-anchors the map) or a
        threshold is crossed (:meth:`crosses`).  A wanted keyframe is deferred
        (:data:`NO_KEYFRAME`, counted by the port) while an update is
        pending that the schedule does not let it wait for
        (:meth:`MappingPort.update_available`); it comes :data:`AFTER_UPDATE`
        when the pending update may move ``latest``, else :data:`KEYFRAME`."""
        if ref is latest and not self.crosses(tr, T_ref_f, latest):
            return NO_KEYFRAME
        port = self._port
        if port.pending and not port.update_available():
            port.defer_keyframe()
            return NO_KEYFRAME
        return AFTER_UPDATE if ref is latest and port.pending else KEYFRAME

    def crosses(self, tr: TrackResult, T_kf_f: np.ndarray, kf: MapKeyframe) -> bool:
        """Whether a frame tracked ``tr`` against the live keyframe ``kf`` at
        ``T_kf_f`` crosses a threshold of :class:`KeyframeDecisionConfig`: it
        leaves ``kf``'s view (:meth:`leaves_view`), moved more than
        ``max_translation`` of ``kf``'s median depth, or its relative cost
        exceeds ``max_relative_cost``."""
        rel_t = float(np.linalg.norm(T_kf_f[:3, 3])) / max(kf.keyframe.median_depth, 1e-9)
        return (self.leaves_view(tr, T_kf_f) or rel_t > self.config.max_translation
                or tr.relative_cost > self.config.max_relative_cost)

    def leaves_view(self, tr: TrackResult, T_kf_f: np.ndarray) -> bool:
        """Whether a frame tracked ``tr`` at ``T_kf_f`` (4x4) in a keyframe's camera
        no longer overlaps it: fewer than ``min_valid_fraction`` of its decision
        pixels inside the frame, or rotated more than ``max_rotation_deg``.  Also
        ends the wait for keyframe 1 (:class:`~spgeo.vo.initialisation.Initialiser`)."""
        return (tr.valid_fraction < self.config.min_valid_fraction
                or rotation_angle_deg(T_kf_f[:3, :3]) > self.config.max_rotation_deg)
