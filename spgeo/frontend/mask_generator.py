"""Automatic mask generation over a promptable segmenter (docs/design.md §3).

Random point prompts, stability filter, smallest stable candidate,
prompt-inside rule, box-NMS, then active prompts in the uncovered area.  Masks
are not split into connected parts (the pipeline does that for every
front-end).  Prompts are integer pixels ``(u, v)`` (column, row) with pixel
centres at integers, as :mod:`spgeo.camera`.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, List, Optional, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from .base import Segmentation

if TYPE_CHECKING:  # annotations only
    from .onnx_sam import SamEmbedding, SegmentModel

__all__ = ["SamMaskGeneratorConfig", "SamMaskGenerator", "box_nms", "mask_boxes",
           "stability_scores"]

logger = logging.getLogger(__name__)


# ------------------------------------------------------------ mask utilities
def stability_scores(logits: np.ndarray, threshold: float = 0.0, offset: float = 1.0
                     ) -> np.ndarray:
    """SAM's stability score: IoU of ``logits > t + offset`` and ``logits > t - offset``.

    Over the last two axes; the first mask lies inside the second, so the IoU
    is the ratio of their areas.  Empty masks score 0.
    """
    flat = logits.reshape(*logits.shape[:-2], -1)
    inter = np.count_nonzero(flat > threshold + offset, axis=-1)
    union = np.count_nonzero(flat > threshold - offset, axis=-1)
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def mask_boxes(regions: Sequence[np.ndarray], width: int) -> np.ndarray:
    """(N, 4) inclusive pixel boxes ``(u0, v0, u1, v1)`` of flat-index regions."""
    boxes = np.zeros((len(regions), 4), dtype=np.int64)
    for i, r in enumerate(regions):
        v, u = np.divmod(r, width)
        boxes[i] = (u.min(), v.min(), u.max(), v.max())
    return boxes


def box_nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy box NMS; returns kept indices ordered by decreasing score.

    Boxes are inclusive pixel boxes ``(u0, v0, u1, v1)`` (area counts pixels).
    A box is removed when its IoU with a higher-scored kept box exceeds
    ``iou_threshold``.  Ties in score keep the earlier index.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    n = len(boxes)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-scores, kind="stable")
    b = boxes[order]
    area = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0])
                 + 1, 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1])
                 + 1, 0, None)
    inter = iw * ih
    iou = inter / (area[:, None] + area[None, :] - inter)
    alive = np.ones(n, dtype=bool)
    for i in range(n):
        if alive[i]:
            alive[i + 1:] &= ~(iou[i, i + 1:] > iou_threshold)
    return order[alive]


# ---------------------------------------------------------- mask generator
@config_class
@dataclass(frozen=True)
class SamMaskGeneratorConfig:
    """docs/design.md §3 segment generation.

    Attributes:
        num_prompts: uniformly random single positive point prompts (300).
        num_active_prompts: prompts sampled afterwards in the area no kept mask
            covers (100; 0 disables the active pass).
        seed: seed of the prompt RNG (prompts and jitter are deterministic).
        stability_threshold: keep a candidate if its stability score is at
            least this (0.90).
        stability_offset: logit offset of the stability score around the mask
            threshold (1.0: IoU of ``logits > +1`` and ``logits > -1``).
        nms_iou: box-NMS IoU threshold (0.8), ranked by predicted IoU.
        active_jitter: uniform jitter (pixels, +-) of the active-prompt grid (3.0).
        keep_all_candidates: keep every stable candidate of a query that
            contains its prompt instead of only the smallest (the authors'
            re-run for depth completion when coverage is low).  False.
        chunk_size: prompts decoded before their logits are reduced to masks
            (bounds memory; 16).
    """

    num_prompts: int = 300
    num_active_prompts: int = 100
    seed: int = 0
    stability_threshold: float = 0.90
    stability_offset: float = 1.0
    nms_iou: float = 0.8
    active_jitter: float = 3.0
    keep_all_candidates: bool = False
    chunk_size: int = 16

    def __post_init__(self) -> None:
        if self.num_prompts < 0 or self.num_active_prompts < 0:
            raise ValueError("SamMaskGeneratorConfig: prompt counts must be >= 0")
        if not 0.0 <= self.stability_threshold <= 1.0:
            raise ValueError("SamMaskGeneratorConfig.stability_threshold must lie in [0, 1]")
        if self.stability_offset < 0 or self.active_jitter < 0:
            raise ValueError("SamMaskGeneratorConfig: stability_offset and active_jitter must "
                             "be >= 0")
        if not 0.0 < self.nms_iou <= 1.0:
            raise ValueError("SamMaskGeneratorConfig.nms_iou must lie in (0, 1]")
        if self.chunk_size < 1:
            raise ValueError("SamMaskGeneratorConfig.chunk_size must be >= 1")


@dataclass
class _Kept:
    regions: List[np.ndarray] = field(default_factory=list)
    anchors: List[int] = field(default_factory=list)
    scores: List[float] = field(default_factory=list)
    queries: int = 0
    dropped_stability: int = 0
    dropped_prompt_outside: int = 0
    removed_nms: int = 0

    def subset(self, keep: np.ndarray) -> "_Kept":
        out = dataclasses.replace(self, regions=[self.regions[i] for i in keep],
                                  anchors=[self.anchors[i] for i in keep],
                                  scores=[self.scores[i] for i in keep])
        out.removed_nms = self.removed_nms + len(self.regions) - len(keep)
        return out


class SamMaskGenerator:
    """:class:`~spgeo.frontend.base.Segmenter` over a :class:`SegmentModel` (docs/design.md §3).

    Per query (one positive point): the decoder's candidates (usually 3) are
    kept if their stability score >= ``stability_threshold``; the smallest
    kept one (pixel count at the mask threshold) is the query's mask; the
    query is dropped if no candidate is stable or the chosen mask does not
    contain the prompt pixel.  Masks are box-NMSed (ranked by predicted IoU).
    Then ``num_active_prompts`` prompts are placed on a jittered grid over the
    uncovered pixels, filtered the same way, NMSed among themselves and
    appended.  Anchor = prompt pixel; score = predicted IoU.

    ``Segmentation.meta`` holds: ``queries`` (all decoder queries),
    ``initial_queries``, ``active_prompts`` (number of active queries),
    ``dropped_stability``, ``dropped_prompt_outside``, ``removed_nms`` (counts
    of queries, or of candidates with ``keep_all_candidates``),
    ``num_initial`` / ``num_active`` (regions from each pass; the first
    ``num_initial`` regions come from the random prompts), ``coverage_initial``
    / ``coverage_final`` (fraction of pixels covered), ``initial_prompts_uv`` /
    ``active_prompts_uv`` ((K, 2) int pixels queried), ``candidates_per_query``
    and ``keep_all_candidates``.
    """

    def __init__(self, model: SegmentModel,
                 config: SamMaskGeneratorConfig = SamMaskGeneratorConfig()) -> None:
        self.model = model
        self.config = config

    # ---- prompts
    @staticmethod
    def random_prompts(height: int, width: int, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` distinct uniformly random pixels as (n, 2) int ``(u, v)``."""
        n = min(int(n), height * width)
        flat = np.sort(rng.choice(height * width, size=n, replace=False))
        v, u = np.divmod(flat, width)
        return np.stack([u, v], axis=1).astype(np.int64)

    @staticmethod
    def active_prompts(uncovered: np.ndarray, n: int, jitter: float,
                       rng: np.random.Generator) -> np.ndarray:
        """Up to ``n`` (u, v) pixels on a jittered grid over ``uncovered`` (H, W) bool.

        The grid spacing starts at ``sqrt(#uncovered / n)`` and shrinks until
        at least ``n`` grid points fall on uncovered pixels (or spacing 1);
        only uncovered points are kept, subsampled at random to ``n``.
        """
        uncovered = np.asarray(uncovered, dtype=bool)
        h, w = uncovered.shape
        n_unc = int(uncovered.sum())
        if n <= 0 or n_unc == 0:
            return np.zeros((0, 2), dtype=np.int64)
        spacing = max(1.0, float(np.sqrt(n_unc / n)))
        flat = np.zeros(0, dtype=np.int64)
        for _ in range(40):
            gv, gu = np.meshgrid(np.arange(spacing / 2, h, spacing),
                                 np.arange(spacing / 2, w, spacing), indexing="ij")
            ju = rng.uniform(-jitter, jitter, gu.shape)
            jv = rng.uniform(-jitter, jitter, gv.shape)
            u = np.clip(np.rint(gu + ju), 0, w - 1).astype(np.int64).ravel()
            v = np.clip(np.rint(gv + jv), 0, h - 1).astype(np.int64).ravel()
            ok = uncovered[v, u]
            flat = np.unique(v[ok] * w + u[ok])
            if len(flat) >= n or spacing <= 1.0:
                break
            spacing = max(1.0, spacing * 0.8)
        if len(flat) > n:
            flat = np.sort(rng.choice(flat, size=n, replace=False))
        v, u = np.divmod(flat, w)
        return np.stack([u, v], axis=1).astype(np.int64)

    # ---- queries
    def _query(self, embedding: SamEmbedding, prompts: np.ndarray) -> Tuple[_Kept, int]:
        cfg = self.config
        h, w = embedding.image_size
        thr = self.model.mask_threshold
        kept = _Kept(queries=len(prompts))
        n_cand = 0
        for s in range(0, len(prompts), cfg.chunk_size):
            pts = prompts[s:s + cfg.chunk_size]
            logits, iou = self.model.predict(embedding, pts)
            q, c = logits.shape[:2]
            n_cand = c
            flat = logits.reshape(q, c, h * w)
            masks = flat > thr
            area = np.count_nonzero(masks, axis=-1)
            stab = stability_scores(logits, thr, cfg.stability_offset)
            stable = (stab >= cfg.stability_threshold) & (area > 0)
            prompt_flat = pts[:, 1] * w + pts[:, 0]
            inside = masks[np.arange(q)[:, None], np.arange(c)[None, :], prompt_flat[:, None]]
            if cfg.keep_all_candidates:
                kept.dropped_stability += int(np.count_nonzero(~stable))
                kept.dropped_prompt_outside += int(np.count_nonzero(stable & ~inside))
                sel_q, sel_c = np.nonzero(stable & inside)
            else:
                any_stable = stable.any(axis=1)
                choice = np.argmin(np.where(stable, area, np.iinfo(np.int64).max), axis=1)
                chosen_inside = inside[np.arange(q), choice]
                kept.dropped_stability += int(np.count_nonzero(~any_stable))
                kept.dropped_prompt_outside += int(np.count_nonzero(any_stable & ~chosen_inside))
                sel_q = np.flatnonzero(any_stable & chosen_inside)
                sel_c = choice[sel_q]
            for qi, ci in zip(sel_q, sel_c):
                kept.regions.append(np.flatnonzero(masks[qi, ci]))
                kept.anchors.append(int(prompt_flat[qi]))
                kept.scores.append(float(iou[qi, ci]))
        return kept, n_cand

    def _nms(self, kept: _Kept, width: int) -> _Kept:
        if not kept.regions:
            return kept
        keep = box_nms(mask_boxes(kept.regions, width), np.asarray(kept.scores),
                       self.config.nms_iou)
        return kept.subset(keep)

    @staticmethod
    def _coverage(regions: Sequence[np.ndarray], h: int, w: int) -> np.ndarray:
        covered = np.zeros(h * w, dtype=bool)
        for r in regions:
            covered[r] = True
        return covered.reshape(h, w)

    # ---- public
    def segment_with_prompts(self, image: np.ndarray, camera: PinholeCamera,
                             prompts_uv: np.ndarray,
                             rng: Optional[np.random.Generator] = None) -> Segmentation:
        """Run docs/design.md §3 with the given initial prompts ((K, 2) int ``(u, v)``)."""
        cfg = self.config
        image = camera.check_image(image)
        h, w = camera.height, camera.width
        prompts = np.asarray(prompts_uv).reshape(-1, 2)
        if prompts.size and (not np.all(np.isfinite(prompts)) or np.any(prompts < 0)
                             or np.any(prompts[:, 0] > w - 1) or np.any(prompts[:, 1] > h - 1)):
            raise ValueError(f"prompts must be pixels inside the {w}x{h} image")
        prompts = np.rint(prompts).astype(np.int64)
        rng = np.random.default_rng(cfg.seed) if rng is None else rng
        embedding = self.model.encode(image)

        first, n_cand = self._query(embedding, prompts)
        first = self._nms(first, w)
        covered = self._coverage(first.regions, h, w)
        cov_initial = float(covered.mean())

        active_pts = self.active_prompts(~covered, cfg.num_active_prompts, cfg.active_jitter, rng)
        second, n_cand2 = self._query(embedding, active_pts)
        second = self._nms(second, w)
        n_cand = n_cand or n_cand2

        regions = first.regions + second.regions
        cov_final = float(self._coverage(regions, h, w).mean())
        meta = {
            "segmenter": f"sam-onnx/{self.model.config.flavour}",
            "queries": first.queries + second.queries,
            "initial_queries": first.queries,
            "active_prompts": second.queries,
            "dropped_stability": first.dropped_stability + second.dropped_stability,
            "dropped_prompt_outside": first.dropped_prompt_outside + second.dropped_prompt_outside,
            "removed_nms": first.removed_nms + second.removed_nms,
            "num_initial": len(first.regions),
            "num_active": len(second.regions),
            "coverage_initial": cov_initial,
            "coverage_final": cov_final,
            "initial_prompts_uv": prompts,
            "active_prompts_uv": active_pts,
            "candidates_per_query": int(n_cand),
            "keep_all_candidates": bool(cfg.keep_all_candidates),
        }
        logger.debug("SamMaskGenerator: %d queries -> %d + %d regions (coverage %.3f -> %.3f)",
                     meta["queries"], meta["num_initial"], meta["num_active"], cov_initial,
                     cov_final)
        return Segmentation(h, w, regions, np.asarray(first.anchors + second.anchors, np.int64),
                            np.asarray(first.scores + second.scores, np.float64), meta)

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        """Segment ``image`` (float [0, 1], (H, W, 3) or (H, W), matching ``camera``)."""
        rng = np.random.default_rng(self.config.seed)
        prompts = self.random_prompts(camera.height, camera.width, self.config.num_prompts, rng)
        return self.segment_with_prompts(image, camera, prompts, rng)
