"""Classical (model-free) segmenter: OpenCV-contrib superpixels / graph segmentation.

:class:`ClassicalSegmenter` is spgeo's offline default front-end segmenter: it
needs no model files.  It cuts the image into a *partition* with one of

* ``"slic"``, ``"slico"``, ``"mslic"`` — simple linear iterative clustering and
  its zero-parameter / manifold variants (``cv2.ximgproc.createSuperpixelSLIC``),
* ``"seeds"`` — superpixels extracted via energy-driven sampling
  (``cv2.ximgproc.createSuperpixelSEEDS``),
* ``"lsc"`` — linear spectral clustering (``cv2.ximgproc.createSuperpixelLSC``),
* ``"graph"`` — Felzenszwalb-Huttenlocher graph segmentation
  (``cv2.ximgproc.segmentation.createGraphSegmentation``),

then post-processes the label image identically for every method:

1. every label is split into its 4-connected components (one vectorised
   ``scipy.ndimage.label`` call on a 2x-refined grid whose links exist only
   between equal labels);
2. components smaller than ``min_area_frac * H * W`` pixels are handled as
   ``small_components`` says: ``"drop"`` (default) removes them, so their
   pixels are covered by no region — the same rule docs/design.md §3 applies to
   SAM masks and that the primitive pipeline applies after its own splitting;
   ``"merge"`` merges each into the adjacent region with which it shares the
   longest boundary, giving an exact partition (every pixel in exactly one
   region).  ``"drop"`` is the default because the tiny components are mostly
   slivers along surface boundaries (anti-aliased edge pixels) and merging
   them raises the under-segmentation error (``evaluation/frontend/segmenters.py``,
   results in docs/results.md);
3. anchors are each region's most interior pixel (maximum of the Euclidean
   distance to the nearest pixel of another region or the image border); scores
   are 1.0.

The superpixel computation may run on a down-scaled copy of the image
(``working_width``); labels are brought back to the input resolution with
nearest-neighbour upsampling, which keeps regions 4-connected.  The segment
count is specified resolution-independently by ``num_segments``.
Everything is deterministic.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np
from scipy import ndimage

from ..camera import PinholeCamera
from ..configs import config_class
from ..images import to_float_image
from .base import Segmentation, config_with_overrides

__all__ = ["ClassicalSegmenterConfig", "ClassicalSegmenter", "METHODS",
           "split_connected_labels", "interior_anchors", "labels_to_segmentation"]

logger = logging.getLogger(__name__)

#: Supported values of :attr:`ClassicalSegmenterConfig.method`.
METHODS = ("slic", "slico", "mslic", "seeds", "lsc", "graph")

_SLIC_ALGORITHMS = {"slic": "SLIC", "slico": "SLICO", "mslic": "MSLIC"}


@config_class
@dataclass(frozen=True)
class ClassicalSegmenterConfig:
    """Configuration of :class:`ClassicalSegmenter`.

    Attributes:
        method: one of :data:`METHODS`.  Default ``"graph"``, chosen with
            ``evaluation/frontend/segmenters.py`` on the synthetic scenes
            (results in docs/results.md).
        num_segments: target number of superpixels for the SLIC family, SEEDS
            and LSC (independent of resolution; SLIC/LSC turn it into a region
            size ``sqrt(h * w / num_segments)`` at the working resolution).  The
            final count differs (connectivity splitting, small-component
            handling).  Ignored by ``"graph"``.  Default 200.
        compactness: SLIC ``ruler`` (spatial vs. colour weight; larger gives
            more regular superpixels; ignored by SLICO, which adapts it) and,
            divided by 100, LSC's ``ratio``.  Default 10.
        num_iterations: iterations of SLIC / SEEDS / LSC.  Default 10.
        slic_min_element_percent: SLIC/LSC connectivity enforcement: merge
            pieces smaller than this percentage of the nominal superpixel size.
            Default 25.
        seeds_num_levels: SEEDS block levels.  Default 4.
        seeds_prior: SEEDS boundary smoothness prior (0..5).  Default 2.
        seeds_histogram_bins: SEEDS colour histogram bins per channel.  Default 5.
        seeds_double_step: SEEDS refines twice per block level.  Default False.
        graph_sigma: Gaussian smoothing of the graph method.  Default 0.5.
        graph_k: graph method scale parameter ``k`` (larger: fewer, larger
            segments) for a working image 320 pixels wide; scaled linearly
            with the working width, which keeps the segment count roughly
            resolution independent.  Default 150.
        graph_min_size: graph method minimum component size in pixels of a
            320x240 working image (scaled with the pixel count).  Default 50.
        color_space: ``"rgb"`` (default) or ``"lab"`` (CIE L*a*b*): colour
            space the segmentation works in.  Grey images are used as they
            are.
        blur_sigma: Gaussian pre-smoothing (pixels at the working resolution)
            before segmentation; 0 disables.  Default 0.
        working_width: segment a copy resized to this width (aspect kept) when
            the image is wider; ``None`` works at full resolution.  Default 320.
        min_area_frac: components smaller than ``min_area_frac * H * W`` pixels
            (input resolution) are small (docs/design.md §3).  Default 1e-3.
        small_components: ``"drop"`` (default; see the module docstring) or
            ``"merge"`` (exact partition of the image).
    """

    method: str = "graph"
    num_segments: int = 200
    compactness: float = 10.0
    num_iterations: int = 10
    slic_min_element_percent: int = 25
    seeds_num_levels: int = 4
    seeds_prior: int = 2
    seeds_histogram_bins: int = 5
    seeds_double_step: bool = False
    graph_sigma: float = 0.5
    graph_k: float = 150.0
    graph_min_size: int = 50
    color_space: str = "rgb"
    blur_sigma: float = 0.0
    working_width: Optional[int] = 320
    min_area_frac: float = 1e-3
    small_components: str = "drop"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"ClassicalSegmenterConfig: method must be one of {METHODS}, "
                             f"got {self.method!r}")
        if int(self.num_segments) < 1:
            raise ValueError(f"ClassicalSegmenterConfig: num_segments must be >= 1, "
                             f"got {self.num_segments}")
        if int(self.num_iterations) < 1:
            raise ValueError("ClassicalSegmenterConfig: num_iterations must be >= 1")
        if not (self.compactness > 0 and np.isfinite(self.compactness)):
            raise ValueError("ClassicalSegmenterConfig: compactness must be finite and > 0")
        if self.color_space not in ("lab", "rgb"):
            raise ValueError(f"ClassicalSegmenterConfig: color_space must be 'lab' or 'rgb', "
                             f"got {self.color_space!r}")
        if self.small_components not in ("merge", "drop"):
            raise ValueError("ClassicalSegmenterConfig: small_components must be 'merge' or "
                             f"'drop', got {self.small_components!r}")
        if not (0.0 <= self.min_area_frac < 1.0):
            raise ValueError(f"ClassicalSegmenterConfig: min_area_frac must be in [0, 1), "
                             f"got {self.min_area_frac}")
        if self.working_width is not None and int(self.working_width) < 8:
            raise ValueError("ClassicalSegmenterConfig: working_width must be >= 8 or None")
        if self.blur_sigma < 0 or self.graph_sigma < 0 or self.graph_k <= 0:
            raise ValueError("ClassicalSegmenterConfig: blur_sigma, graph_sigma must be >= 0 "
                             "and graph_k > 0")


# ----------------------------------------------------------------------------- helpers
def split_connected_labels(labels: np.ndarray) -> Tuple[np.ndarray, int]:
    """Relabel so that every label is one 4-connected component.

    Vectorised: one ``scipy.ndimage.label`` call on a (2H-1, 2W-1) grid in
    which pixels sit at even coordinates and a link cell between two
    4-neighbours is set only when their labels are equal.

    Returns ``(components, n)``: int32 (H, W) labels in ``[0, n)``, numbered in
    raster order of each component's first pixel.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.size == 0:
        raise ValueError(f"labels must be a non-empty (H, W) array, got shape {labels.shape}")
    h, w = labels.shape
    grid = np.zeros((2 * h - 1, 2 * w - 1), dtype=np.uint8)
    grid[::2, ::2] = 1
    grid[::2, 1::2] = labels[:, 1:] == labels[:, :-1]
    grid[1::2, ::2] = labels[1:, :] == labels[:-1, :]
    comp, n = ndimage.label(grid)  # default structure: 4-connectivity
    return (comp[::2, ::2] - 1).astype(np.int32), int(n)


def _adjacent_pairs(labels: np.ndarray) -> np.ndarray:
    """(M, 2) label pairs (a != b) of all horizontally / vertically adjacent pixels."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    diff = a != b
    a, b = a[diff], b[diff]
    return np.stack([np.concatenate([a, b]), np.concatenate([b, a])], axis=1)


def _merge_small(labels: np.ndarray, n: int, min_area: float,
                 pixel_weight: Optional[np.ndarray] = None) -> Tuple[np.ndarray, int]:
    """Merge components smaller than ``min_area`` pixels into a neighbour.

    ``pixel_weight`` (H, W) gives the area of each pixel (input-resolution
    pixels it stands for when working on a down-scaled label image).

    Each round, every small component that touches a large one merges into the
    large neighbour with which it shares the longest boundary (ties: larger
    area, then lower label); small components surrounded only by small ones
    wait for the next round.  If no component is large, the largest counts as
    large.  Returns relabelled ``(labels, n)`` with labels ``0..n-1``.
    """
    labels = np.asarray(labels, dtype=np.int32)
    weights = None if pixel_weight is None else pixel_weight.ravel()
    for _ in range(10_000):
        area = np.bincount(labels.ravel(), weights, minlength=n)
        small = area < min_area
        if not small.any() or n <= 1:
            break
        if small.all():
            small[np.argmax(area)] = False
        pairs = _adjacent_pairs(labels)
        pairs = pairs[small[pairs[:, 0]] & ~small[pairs[:, 1]]]
        if pairs.size == 0:  # pragma: no cover - a connected image always has a pair
            break
        key = pairs[:, 0].astype(np.int64) * n + pairs[:, 1]
        ukey, count = np.unique(key, return_counts=True)
        src, dst = ukey // n, ukey % n
        order = np.lexsort((dst, -area[dst], -count, src))
        src, dst = src[order], dst[order]
        first = np.r_[True, src[1:] != src[:-1]]
        target = np.arange(n)
        target[src[first]] = dst[first]
        used = np.zeros(n, dtype=bool)
        used[target] = True
        new_id = (np.cumsum(used) - 1).astype(np.int32)
        labels = new_id[target][labels]
        n = int(used.sum())
    return labels, n


def interior_anchors(labels: np.ndarray, n: int) -> np.ndarray:
    """(n,) flat index of the most interior pixel of each label of ``labels``.

    Interior = Euclidean distance to the nearest pixel of another label or to
    the outside of the image (one ``cv2.distanceTransform`` for all labels);
    ties go to the first pixel in raster order.  Labels must be ``0..n-1``,
    each present.
    """
    h, w = labels.shape
    padded = np.pad(labels, 1, mode="constant", constant_values=-1)
    c = padded[1:-1, 1:-1]
    inner = ((padded[:-2, 1:-1] == c) & (padded[2:, 1:-1] == c)
             & (padded[1:-1, :-2] == c) & (padded[1:-1, 2:] == c))
    dist = cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    flat_lab = labels.ravel()
    flat_d = dist.ravel()
    best = ndimage.maximum(flat_d, flat_lab, np.arange(n))
    best = np.asarray(best, dtype=np.float32).reshape(n)
    cand = np.flatnonzero(flat_d >= best[flat_lab])
    lab_c = flat_lab[cand]
    # first candidate (raster order) per label
    first = np.full(n, -1, dtype=np.int64)
    order = np.argsort(lab_c, kind="stable")
    lab_sorted = lab_c[order]
    starts = np.r_[True, lab_sorted[1:] != lab_sorted[:-1]]
    first[lab_sorted[starts]] = cand[order[starts]]
    if np.any(first < 0):  # pragma: no cover - every label has a pixel
        raise RuntimeError("interior_anchors: a label has no pixel")
    return first


def labels_to_segmentation(labels: np.ndarray, valid: Optional[np.ndarray] = None,
                           meta: Optional[dict] = None,
                           anchors: Optional[np.ndarray] = None) -> Segmentation:
    """Build a :class:`Segmentation` from an (H, W) label image with labels ``0..n-1``.

    ``valid`` (n,) bool selects the labels kept as regions (default: all).
    ``anchors`` (n,) flat anchor indices default to :func:`interior_anchors`;
    scores are 1.0.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.size == 0:
        raise ValueError(f"labels must be a non-empty (H, W) array, got shape {labels.shape}")
    h, w = labels.shape
    flat = labels.ravel()
    if flat.min() < 0:
        raise ValueError("labels must be >= 0")
    n = int(flat.max()) + 1
    if anchors is None:
        anchors = interior_anchors(labels, n)
    anchors = np.asarray(anchors, dtype=np.int64)
    # group pixel indices per label: stable counting-style sort
    sort_dtype = np.uint16 if n <= np.iinfo(np.uint16).max else np.int64
    order = np.argsort(flat.astype(sort_dtype), kind="stable")
    counts = np.bincount(flat, minlength=n)
    regions = np.split(order.astype(np.int64), np.cumsum(counts)[:-1])
    keep = np.arange(n) if valid is None else np.flatnonzero(valid)
    return Segmentation(h, w, [regions[i] for i in keep], anchors[keep],
                        np.ones(keep.size), dict(meta or {}))


# ----------------------------------------------------------------------------- segmenter
class ClassicalSegmenter:
    """Superpixel / graph segmenter implementing :class:`spgeo.frontend.base.Segmenter`.

    See the module docstring for the algorithm and
    :class:`ClassicalSegmenterConfig` for the options.  ``segment`` returns
    non-overlapping 4-connected regions of at least ``min_area_frac * H * W``
    pixels, each with an interior anchor and score 1.0; they cover every pixel
    except those of dropped small components (all pixels with
    ``small_components="merge"``).  ``meta``
    holds ``method``, ``num_raw_labels``, ``num_components``,
    ``num_small`` (merged or dropped), ``coverage`` (fraction of pixels in a
    region), ``working_size``, ``regions_4connected`` (True),
    ``min_region_pixels`` (the smallest region's pixel count) and ``time_s``.
    """

    def __init__(self, config: Optional[ClassicalSegmenterConfig] = None, **overrides) -> None:
        self.config = config_with_overrides(ClassicalSegmenterConfig, config, overrides)

    # -------------------------------------------------------------- internals
    def _prepare(self, image: np.ndarray) -> np.ndarray:
        """uint8 working image (H', W', C) in the configured colour space."""
        cfg = self.config
        img8 = np.round(image * 255.0).astype(np.uint8)
        h, w = img8.shape[:2]
        if cfg.working_width is not None and w > cfg.working_width:
            ww = int(cfg.working_width)
            wh = max(1, int(round(h * ww / w)))
            img8 = cv2.resize(img8, (ww, wh), interpolation=cv2.INTER_AREA)
        if cfg.blur_sigma > 0:
            img8 = cv2.GaussianBlur(img8, (0, 0), cfg.blur_sigma)
        if img8.ndim == 3 and cfg.color_space == "lab":
            img8 = cv2.cvtColor(img8, cv2.COLOR_RGB2LAB)
        if img8.ndim == 2:
            img8 = img8[..., None]
        return np.ascontiguousarray(img8)

    def _raw_labels(self, img: np.ndarray) -> np.ndarray:
        cfg = self.config
        h, w, c = img.shape
        if cfg.method in _SLIC_ALGORITHMS or cfg.method == "lsc":
            region = max(2, int(round(np.sqrt(h * w / float(cfg.num_segments)))))
            if cfg.method == "lsc":
                sp = cv2.ximgproc.createSuperpixelLSC(img, region_size=region,
                                                      ratio=float(cfg.compactness) / 100.0)
            else:
                algo = getattr(cv2.ximgproc, _SLIC_ALGORITHMS[cfg.method])
                sp = cv2.ximgproc.createSuperpixelSLIC(img, algorithm=algo, region_size=region,
                                                       ruler=float(cfg.compactness))
            sp.iterate(int(cfg.num_iterations))
            if cfg.slic_min_element_percent > 0:
                sp.enforceLabelConnectivity(int(cfg.slic_min_element_percent))
            return sp.getLabels()
        if cfg.method == "seeds":
            sp = cv2.ximgproc.createSuperpixelSEEDS(
                w, h, c, int(cfg.num_segments), int(cfg.seeds_num_levels), int(cfg.seeds_prior),
                int(cfg.seeds_histogram_bins), bool(cfg.seeds_double_step))
            sp.iterate(img, int(cfg.num_iterations))
            return sp.getLabels()
        # graph
        # k scales with the image width (keeps the segment count roughly constant
        # across resolutions); min_size with the area
        gs = cv2.ximgproc.segmentation.createGraphSegmentation(
            sigma=float(cfg.graph_sigma), k=float(cfg.graph_k) * (w / 320.0),
            min_size=max(1, int(round(cfg.graph_min_size * (h * w) / (320.0 * 240.0)))))
        return gs.processImage(img)

    # -------------------------------------------------------------- public API
    def label_image(self, image: np.ndarray, camera: Optional[PinholeCamera] = None
                    ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
        """Dense result: ``(labels, keep, anchors, meta)``.

        ``labels`` is an int32 (H, W) image of 4-connected components numbered
        ``0..n-1``; ``keep`` (n,) bool marks the components returned as regions
        (all of them unless ``small_components="drop"``); ``anchors`` (n,) are
        flat pixel indices of each component's most interior pixel.
        """
        t0 = time.perf_counter()
        if camera is not None:
            camera.check_image(image)
        image = to_float_image(image)
        cfg = self.config
        h_full, w_full = image.shape[:2]
        work = self._prepare(image)
        raw = np.asarray(self._raw_labels(work), dtype=np.int32)
        comp, n = split_connected_labels(raw)
        h, w = comp.shape
        # nearest mapping of full-resolution rows / columns to working ones
        # (pixel centres aligned; monotone with unit steps, so 4-connected
        # components stay 4-connected and distinct after upsampling)
        rows = np.minimum(((np.arange(h_full) + 0.5) * (h / h_full)).astype(np.int64), h - 1)
        cols = np.minimum(((np.arange(w_full) + 0.5) * (w / w_full)).astype(np.int64), w - 1)
        row_mult = np.bincount(rows, minlength=h).astype(np.float64)
        col_mult = np.bincount(cols, minlength=w).astype(np.float64)
        weight = row_mult[:, None] * col_mult[None, :]  # full-res pixels per working pixel
        min_area = cfg.min_area_frac * h_full * w_full
        area = np.bincount(comp.ravel(), weight.ravel(), minlength=n)
        num_small = int(np.count_nonzero(area < min_area))
        if cfg.small_components == "merge" and num_small:
            comp, n = _merge_small(comp, n, min_area, weight)
            keep = np.ones(n, dtype=bool)
        else:
            keep = area >= min_area
            if not keep.any():  # never return nothing: keep the largest component
                keep[np.argmax(area)] = True
        anchors_w = interior_anchors(comp, n)
        if (h, w) != (h_full, w_full):
            # centre full-res pixel of the block that each working pixel stands for
            first_row = np.searchsorted(rows, np.arange(h))
            first_col = np.searchsorted(cols, np.arange(w))
            mid_row = first_row + (row_mult.astype(np.int64) - 1) // 2
            mid_col = first_col + (col_mult.astype(np.int64) - 1) // 2
            anchors = mid_row[anchors_w // w] * w_full + mid_col[anchors_w % w]
            comp = comp[rows[:, None], cols[None, :]]
        else:
            anchors = anchors_w
        kept_sizes = np.bincount(comp.ravel(), minlength=n)[keep]
        covered = kept_sizes.sum()
        meta = {
            "method": cfg.method,
            "num_raw_labels": int(raw.max()) + 1,
            "num_components": int(area.size),
            "num_small": num_small,
            "small_components": cfg.small_components,
            "coverage": float(covered) / float(h_full * w_full),
            "working_size": (w, h),
            # every region is one 4-connected component of at least this many pixels
            "regions_4connected": True,
            "min_region_pixels": int(kept_sizes.min()),
            "time_s": time.perf_counter() - t0,
        }
        return comp, keep, anchors, meta

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        """Segment ``image`` (float32 [0, 1], (H, W, 3) RGB or (H, W) grey matching ``camera``)."""
        t0 = time.perf_counter()
        labels, keep, anchors, meta = self.label_image(image, camera)
        seg = labels_to_segmentation(labels, keep, meta, anchors)
        seg.meta["time_s"] = time.perf_counter() - t0
        logger.debug("ClassicalSegmenter(%s): %d regions (%d small %s), coverage %.4f, %.1f ms",
                     meta["method"], len(seg), meta["num_small"], self.config.small_components,
                     meta["coverage"], 1e3 * seg.meta["time_s"])
        return seg

    def __repr__(self) -> str:
        return f"ClassicalSegmenter({self.config!r})"
