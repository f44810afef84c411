"""DSO-style selection of well-spread, high-gradient primitive pixels.

Direct sparse odometry (Engel et al., TPAMI 2017, "point selection") evaluates
its photometric cost on a budget of pixels instead of every pixel.  Here the
primitives keep their dense shape (a depth at every pixel); only the residuals
of tracking and mapping use the selected pixels.

:func:`select_pixels` works on any set of candidate pixels (the entries of a
:class:`~spgeo.primitives.PrimitiveSet` on one pyramid level's lattice):

1. gradient magnitude ``|g|`` of the image (Scharr, intensity per pixel);
2. a block-adaptive threshold: the median ``|g|`` of every ``region`` x
   ``region`` region, averaged over the 3x3 neighbouring regions, plus
   ``gradient_margin``;
3. pass ``k = 0, 1, 2``: the image is cut into blocks of ``block * 2^k``
   pixels; every block that holds no pixel selected by an earlier pass keeps
   its candidate with the largest ``|g|`` if that exceeds
   ``threshold * pass_decay^k`` (the coarser passes keep the selection spread
   over weakly textured areas);
4. the block size ``block`` is adapted (a few multiplicative steps) so that
   the total comes close to ``budget``; a remainder above it is trimmed by
   ``|g| / threshold``, never below a primitive's minimum;
5. every primitive with texture (its largest ``|g|`` reaches
   ``min_gradient``) gets at least ``min_per_primitive`` pixels, topped up
   with its strongest unselected pixels.

The total is at most ``budget`` unless the per-primitive minima alone exceed
it.  Primitives without texture get no pixel: their shape variables are held
by their priors (:attr:`PixelSelection.empty` lists them).
The selection is deterministic (ties are broken by candidate order).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from ..configs import config_class
from ..images import scharr_gradients

__all__ = ["PixelSelectionConfig", "PixelSelection", "select_pixels", "gradient_magnitude"]

#: how coarser pyramid levels choose their pixels (``PixelSelectionConfig.coarse_levels``)
COARSE_MODES = ("select", "all")


@config_class
@dataclass(frozen=True)
class PixelSelectionConfig:
    """Options of :func:`select_pixels`.

    Attributes:
        budget: target number of selected pixels (>= 1).
        region: side in pixels of the regions whose median gradient sets the
            adaptive threshold (default 32).
        gradient_margin: added to the regional median gradient (intensity
            per pixel, images in [0, 1]; default 7/255 as DSO).
        pass_decay: threshold factor of each coarser pass (default 0.75).
        passes: number of block passes (default 3: blocks ``b``, ``2b``, ``4b``).
        min_per_primitive: pixels guaranteed to every textured primitive
            (default 4, the default ``min_level_pixels``: every textured
            primitive keeps its photometric factors).
        min_gradient: a primitive whose largest gradient is below this has no
            texture and gets no pixel (default 1/255).
        adapt_steps: block-size adaptation steps towards the budget (default 4).
        boundary_margin: the block passes skip candidates within this many
            pixels (Chebyshev) of a pixel of another primitive or of no
            primitive (default 0: none skipped); the per-primitive minimum
            may still use them.  Meant for candidates on a dense grid (a
            sparser lattice makes every candidate a boundary one).
        coarse_levels: pixels of pyramid levels above 0: ``"select"`` (default)
            runs the selection on that level's image and lattice with the same
            budget, ``"all"`` keeps every lattice pixel there.
    """

    budget: int = 2000
    region: int = 32
    gradient_margin: float = 7.0 / 255.0
    pass_decay: float = 0.75
    passes: int = 3
    min_per_primitive: int = 4
    min_gradient: float = 1.0 / 255.0
    adapt_steps: int = 4
    boundary_margin: int = 0
    coarse_levels: str = "select"

    def __post_init__(self) -> None:
        if self.budget < 1 or self.region < 1 or self.passes < 1 or self.adapt_steps < 0:
            raise ValueError("PixelSelectionConfig: budget, region, passes >= 1 and "
                             "adapt_steps >= 0 required")
        if not 0 < self.pass_decay <= 1 or self.gradient_margin < 0 or self.min_gradient < 0:
            raise ValueError("PixelSelectionConfig: pass_decay in (0, 1], gradient_margin and "
                             "min_gradient >= 0 required")
        if self.min_per_primitive < 0 or self.boundary_margin < 0:
            raise ValueError("PixelSelectionConfig: min_per_primitive and boundary_margin "
                             "must be >= 0")
        if self.coarse_levels not in COARSE_MODES:
            raise ValueError(f"PixelSelectionConfig.coarse_levels must be one of {COARSE_MODES}")


@dataclass
class PixelSelection:
    """Result of :func:`select_pixels`.

    Attributes:
        indices: (S,) sorted indices into the candidates.
        counts: (P,) selected pixels per primitive.
        empty: indices of the primitives with no selected pixel.
        block: the final block size of the first pass (pixels).
    """

    indices: np.ndarray
    counts: np.ndarray
    empty: np.ndarray
    block: float


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """Scharr gradient magnitude (float32, intensity per pixel) of a grey image."""
    gu, gv = scharr_gradients(image)
    return np.sqrt(gu * gu + gv * gv)


def _threshold_map(mag: np.ndarray, region: int, margin: float) -> np.ndarray:
    """Per-pixel adaptive threshold: regional median (3x3-region mean) + margin."""
    h, w = mag.shape
    r = max(1, min(int(region), h, w))
    nh, nw = -(-h // r), -(-w // r)
    pad = np.full((nh * r, nw * r), np.nan, dtype=np.float32)
    pad[:h, :w] = mag
    med = np.nanmedian(pad.reshape(nh, r, nw, r).transpose(0, 2, 1, 3).reshape(nh, nw, -1),
                       axis=2).astype(np.float32)
    med = cv2.blur(med, (3, 3), borderType=cv2.BORDER_REPLICATE)
    return np.repeat(np.repeat(med, r, axis=0), r, axis=1)[:h, :w] + np.float32(margin)


def _rank_within(group: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Rank of every element inside its group by descending score (0 = best;
    ties by position)."""
    n = group.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((np.arange(n), -score, group))
    g = group[order]
    first = np.r_[True, g[1:] != g[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(n), 0))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n) - start
    return rank


def _interior(shape, rows: np.ndarray, cols: np.ndarray, ids: np.ndarray,
              margin: int) -> np.ndarray:
    """Candidates whose (2 margin + 1)^2 neighbourhood holds only their primitive."""
    label = np.full(shape, -1, dtype=np.int64)
    label[rows, cols] = ids
    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    lab = label.astype(np.float32)      # exact for ids < 2^24
    same = (cv2.dilate(lab, k, borderType=cv2.BORDER_REPLICATE)
            == cv2.erode(lab, k, borderType=cv2.BORDER_REPLICATE))
    return same[rows, cols]


def _block_pick(rows: np.ndarray, cols: np.ndarray, mag: np.ndarray, thr: np.ndarray,
                order: np.ndarray, block: float, passes: int, decay: float) -> np.ndarray:
    """Boolean mask of the block passes' picks (see the module docstring);
    ``order``: the candidates by descending ``mag`` (ties by position)."""
    picked = np.zeros(rows.size, dtype=bool)
    r_o, c_o, m_o, t_o = rows[order], cols[order], mag[order], thr[order]
    for k in range(passes):
        b = block * 2.0 ** k
        bid = (np.floor(r_o / b).astype(np.int64) * (int(c_o.max() // b) + 2)
               + np.floor(c_o / b).astype(np.int64))
        eligible = ~picked[order] & (m_o > t_o * decay ** k)
        if picked.any():
            covered = np.zeros(int(bid.max()) + 1, dtype=bool)
            covered[bid[picked[order]]] = True
            eligible &= ~covered[bid]
        cand = np.flatnonzero(eligible)
        if cand.size == 0:
            continue
        _, first = np.unique(bid[cand], return_index=True)   # strongest of each block
        picked[order[cand[first]]] = True
    return picked


def _top_up(picked: np.ndarray, ids: np.ndarray, mag: np.ndarray, textured: np.ndarray,
            n_prims: int, m: int) -> np.ndarray:
    """Mask of the strongest unselected pixels bringing every textured
    primitive to ``m`` picks."""
    extra = np.zeros(picked.size, dtype=bool)
    if m <= 0:
        return extra
    need = np.maximum(m - np.bincount(ids[picked], minlength=n_prims), 0) * textured
    if not need.any():
        return extra
    cand = np.flatnonzero(~picked & (need[ids] > 0))
    rank = _rank_within(ids[cand], mag[cand])
    extra[cand[rank < need[ids[cand]]]] = True
    return extra


def select_pixels(image: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  primitive_ids: np.ndarray, config: PixelSelectionConfig,
                  n_primitives: Optional[int] = None,
                  magnitude: Optional[np.ndarray] = None) -> PixelSelection:
    """Select a budget of well-spread, high-gradient candidates (module docstring).

    Args:
        image: (H, W) grey float image in [0, 1].
        rows, cols: (K,) integer pixel coordinates of the candidates in ``image``.
        primitive_ids: (K,) primitive index of each candidate (0..P-1).
        config: :class:`PixelSelectionConfig`.
        n_primitives: P (default ``max(primitive_ids) + 1``).
        magnitude: optional precomputed :func:`gradient_magnitude` of ``image``.
    Returns:
        :class:`PixelSelection`.
    Raises:
        ValueError: mismatched lengths or coordinates outside ``image``.
    """
    img = np.asarray(image)
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    cols = np.asarray(cols, dtype=np.int64).reshape(-1)
    ids = np.asarray(primitive_ids, dtype=np.int64).reshape(-1)
    if img.ndim != 2 or rows.size != cols.size or rows.size != ids.size:
        raise ValueError("select_pixels: image must be (H, W) and rows, cols, primitive_ids "
                         "of one length")
    n_prims = int(ids.max()) + 1 if n_primitives is None and ids.size else int(n_primitives or 0)
    if rows.size and (rows.min() < 0 or cols.min() < 0 or rows.max() >= img.shape[0]
                      or cols.max() >= img.shape[1]):
        raise ValueError("select_pixels: candidate coordinates outside the image")
    if rows.size == 0:
        return PixelSelection(np.zeros(0, dtype=np.int64), np.zeros(n_prims, dtype=np.int64),
                              np.arange(n_prims), 1.0)
    full = gradient_magnitude(img) if magnitude is None else np.asarray(magnitude)
    thr_map = _threshold_map(full, config.region, config.gradient_margin)
    mag = full[rows, cols].astype(np.float64)
    thr = thr_map[rows, cols].astype(np.float64)
    pmax = np.zeros(n_prims)
    np.maximum.at(pmax, ids, mag)
    textured = pmax >= config.min_gradient
    m = int(config.min_per_primitive)
    budget = int(config.budget)
    order = np.lexsort((np.arange(mag.size), -mag))
    if config.boundary_margin > 0:
        # non-interior candidates never pass the block thresholds
        thr = np.where(_interior(img.shape, rows, cols, ids, config.boundary_margin),
                       thr, np.inf)

    def run(b: float):
        picked = _block_pick(rows, cols, mag, thr, order, b, config.passes, config.pass_decay)
        return picked, _top_up(picked, ids, mag, textured, n_prims, m)

    # block size: start from the area per budget pixel, then adapt to the count
    block = max(1.0, float(np.sqrt(rows.size / budget)))
    picked, extra = run(block)
    for _ in range(config.adapt_steps):
        total = int(np.count_nonzero(picked | extra))
        if 0.9 * budget <= total <= budget or (total < budget and block <= 1.0):
            break
        block = max(1.0, block * float(np.sqrt(max(total, 1) / budget)))
        picked, extra = run(block)
    total = int(np.count_nonzero(picked | extra))
    if total > budget:
        # trim the weakest picks, keeping every primitive's strongest m
        sel = np.flatnonzero(picked)
        rank = _rank_within(ids[sel], mag[sel])
        protected = rank < m
        n_drop = min(total - budget, int(np.count_nonzero(~protected)))
        if n_drop > 0:
            free = sel[~protected]
            ratio = mag[free] / np.maximum(thr[free], 1e-12)
            drop = free[np.lexsort((np.arange(free.size), ratio))[:n_drop]]
            picked[drop] = False
            extra = _top_up(picked, ids, mag, textured, n_prims, m)
    indices = np.flatnonzero(picked | extra)
    counts = np.bincount(ids[indices], minlength=n_prims)
    return PixelSelection(indices, counts, np.flatnonzero(counts == 0), block)
