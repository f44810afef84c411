"""Building the VO's keyframes (docs/design.md §5.1, *Keyframes*; when a frame
becomes one is :class:`~spgeo.vo.keyframe_policy.KeyframePolicy`'s decision): a frame's
primitives from the front-end, their log-scales (keyframe 0 of a segment: one
constant; later keyframes: rendered from the window, then the reverse scale
check), the primitive-model ablation, and the keyframe's pyramid."""
from __future__ import annotations

import dataclasses
import logging
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from ..frontend import PrimitiveFrontEnd
from ..primitives import PrimitiveSet
from .config import OdometryConfig
from ..primitive_models import apply_primitive_model
from .map import MapKeyframe
from .rendering import init_scales_from_render, render_primitives
from .scale_check import reverse_scale_check
from .tracking import Keyframe

__all__ = ["KeyframeBuilder", "RENDER_SPLAT"]

log = logging.getLogger(__name__)

#: splat size (pixels) when rendering the window into a new keyframe
RENDER_SPLAT = 2


class KeyframeBuilder:
    """Builds the :class:`~spgeo.vo.tracking.Keyframe` of a frame for one
    :class:`~spgeo.vo.Odometry` (processing ``camera``, ``config``, ``frontend``).

    Attributes:
        scale_checks: one dict per reverse scale check (keyframe, frame and the
            :class:`~spgeo.vo.scale_check.ScaleCheck` fields), for the report.
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig,
                 frontend: PrimitiveFrontEnd) -> None:
        self.camera, self.config, self.frontend = camera, config, frontend
        self.scale_checks: List[dict] = []

    def primify(self, frame: Frame) -> PrimitiveSet:
        """The front-end's primitives of ``frame`` (its depth only for a
        depth-using front-end); ``ValueError`` when there is none."""
        depth = frame.depth if self.frontend.uses_depth else None
        prims = self.frontend.primify(frame.image, self.camera, depth)
        if len(prims) == 0:
            raise ValueError("the front-end produced no primitive")
        return prims

    def first(self, frame: Frame, T_world: np.ndarray, timings: Dict[str, float],
              median_depth: Optional[float] = None) -> Keyframe:
        """Keyframe 0 of a map segment at ``T_world``: monocular, every
        primitive at depth ``median_depth`` (default 1)."""
        t = time.perf_counter()
        prims = self.primify(frame)
        if not self.frontend.uses_depth:
            s0 = 0.0 if median_depth is None else float(np.log(median_depth))
            prims = prims.with_log_scales(np.full(len(prims), s0))
        prims = apply_primitive_model(prims, self.config.primitive_model)
        timings["frontend"] = time.perf_counter() - t
        return Keyframe.build(frame.image, prims, T_world, self.config.keyframe_levels,
                              self.config.selection)

    def rendered(self, frame: Frame, idx: int, k: int, T_world: np.ndarray,
                 window: Sequence[MapKeyframe], timings: Dict[str, float],
                 prims: Optional[PrimitiveSet] = None) -> Optional[Tuple[Keyframe, np.ndarray]]:
        """Keyframe ``k`` of frame ``idx`` at ``T_world``, its primitives (``prims``:
        :meth:`primify` of ``frame`` already done) with scales rendered from the
        ``window`` keyframes (the newest last; the reverse scale check against
        it), and the weights of their scale priors.  None when the render
        reaches no primitive."""
        cfg = self.config
        t = time.perf_counter()
        prims = self.primify(frame) if prims is None else prims
        depth = render_primitives([(w.keyframe.primitives, w.keyframe.T_world_kf) for w in window],
                                  prims.camera, T_world, splat=RENDER_SPLAT,
                                  tolerance=cfg.render_tolerance)
        try:
            init = init_scales_from_render(prims, depth)
        except ValueError as exc:
            log.warning("frame %d: no keyframe (%s)", idx, exc)
            timings["frontend"] = timings.get("frontend", 0.0) + time.perf_counter() - t
            return None
        timings["frontend"] = timings.get("frontend", 0.0) + time.perf_counter() - t
        keyframe = Keyframe.build(frame.image, init.primitives, T_world, cfg.keyframe_levels,
                                  cfg.selection)
        prims = self._checked_scales(keyframe, init.primitives, window[-1], k, idx, timings)
        prims = apply_primitive_model(prims, cfg.primitive_model)
        weights = np.where(init.fallback & (not self.frontend.uses_depth),
                           cfg.scale_prior_weight, cfg.render_prior_weight)
        return keyframe.rebuilt(prims, T_world), weights

    def _checked_scales(self, keyframe: Keyframe, prims: PrimitiveSet, prev: MapKeyframe,
                        k: int, idx: int, timings: Dict[str, float]) -> PrimitiveSet:
        """``prims`` (the new keyframe ``k``'s, rendered scales) with the reverse
        scale check's correction against the previous keyframe ``prev``
        (``OdometryConfig.scale_check``; monocular front-ends only)."""
        check_cfg = self.config.scale_check
        if not check_cfg.enabled or self.frontend.uses_depth:
            return prims
        t = time.perf_counter()
        check = reverse_scale_check(keyframe, prev.image, prev.keyframe.T_world_kf,
                                    self.config.tracker, check_cfg.min_parallax,
                                    check_cfg.max_change)
        prims = prims.with_log_scales(prims.log_scales + check.log_correction)
        self.scale_checks.append({"keyframe": k, "frame": idx, **dataclasses.asdict(check)})
        timings["scale_check"] = time.perf_counter() - t
        return prims
