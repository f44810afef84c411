"""Keyframe scale consistency by reverse tracking (docs/design.md §5, VO:
"Scale check").

A monocular keyframe's log-scales come from the window rendered at its tracked
pose (:mod:`spgeo.vo.rendering`).  That pose's translation is measured in the
units the previous keyframe's primitives imply for tracking; the rendered
depths are not always in the same units (a flat primitive tracks as if it
were nearer than its median depth, and a pose that overshoots along the
optical axis renders the map too near), so the scale of the map can creep
keyframe after keyframe.

:func:`reverse_scale_check` measures the new keyframe's units directly: it
tracks the previous keyframe's image against the new keyframe, starting at
the previous keyframe's pose.  If the new keyframe's depths were in the same
units as the translation, the tracked translation would equal the known one;
their least-squares ratio ``k = sum(t_r . t_f) / sum(|t_f|^2)`` says by how
much they are not, and the new keyframe's log-scales are shifted by
``-log k`` (limited to ``max_change``).  Without parallax the ratio is not
observable and nothing is changed.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..geometry import invert_pose
from .config import TrackerConfig
from .keyframe import Keyframe
from .tracking import track_frame

__all__ = ["ScaleCheck", "reverse_scale_check"]

log = logging.getLogger(__name__)


@dataclass
class ScaleCheck:
    """Outcome of :func:`reverse_scale_check`.

    Attributes:
        parallax: ``|t| / median depth`` of the new keyframe relative to the
            other frame (the new keyframe's units).
        ratio: ``k``, the tracked over the known translation (least squares
            along the known one), or None (no parallax, or the track failed).
        log_correction: the shift added to every log-scale of the new
            keyframe (0 when ``reason`` is set); ``-log k`` clipped to
            ``+-log(1 + max_change)``.
        reason: why nothing was changed (``"parallax"``: too little of it;
            ``"lost"``: the reverse track failed; ``"direction"``: the tracked
            translation points against the known one) or "".
    """

    parallax: float
    ratio: Optional[float]
    log_correction: float
    reason: str = ""


def reverse_scale_check(new: Keyframe, other_image: np.ndarray, T_world_other: np.ndarray,
                        tracker: TrackerConfig = TrackerConfig(), min_parallax: float = 0.01,
                        max_change: float = 0.2) -> ScaleCheck:
    """The new keyframe's log-scale correction from tracking another frame
    (normally the previous keyframe) against it (module docstring).

    Args:
        new: the new :class:`~spgeo.vo.keyframe.Keyframe` (its primitives at
            their initial log-scales, its pose ``T_world_kf``).
        other_image: the other frame's image, the size of ``new``'s input
            images.
        T_world_other: 4x4 camera-to-world pose of the other frame, in the
            map's units (the units of the translation to be matched).
        tracker: tracker options of the reverse track.
        min_parallax: below this ``|t| / median depth`` nothing is measured.
        max_change: the correction is limited to a factor ``1 + max_change``
            either way (> 0).
    Returns:
        :class:`ScaleCheck`; apply it with
        ``primitives.with_log_scales(primitives.log_scales + check.log_correction)``.
    Raises:
        ValueError: ``max_change`` not > 0, or malformed images / poses (from
            :func:`~spgeo.vo.tracking.track_frame`).
    """
    if not max_change > 0:
        raise ValueError(f"reverse_scale_check: max_change must be > 0, got {max_change}")
    T_new_inv = invert_pose(new.T_world_kf)
    t_known = (T_new_inv @ np.asarray(T_world_other, dtype=float))[:3, 3]
    parallax = float(np.linalg.norm(t_known) / max(new.median_depth, 1e-12))
    if not parallax >= min_parallax:
        return ScaleCheck(parallax, None, 0.0, "parallax")
    tr = track_frame(new, other_image, T_world_other, (0.0, 0.0), tracker)
    if not tr.ok:
        return ScaleCheck(parallax, None, 0.0, "lost")
    t_tracked = (T_new_inv @ tr.T_world_frame)[:3, 3]
    k = float(t_tracked @ t_known / (t_known @ t_known))
    if not k > 0:
        return ScaleCheck(parallax, k, 0.0, "direction")
    limit = float(np.log1p(max_change))
    c = float(np.clip(-np.log(k), -limit, limit))
    log.debug("scale check: parallax %.3f, ratio %.3f, log-scale shift %+.3f", parallax, k, c)
    return ScaleCheck(parallax, k, c)
