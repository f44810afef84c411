"""Choose a depth source per region by its error on held-out sparse points.

Several candidate depth sources can complete the same sparse points (the
primitive completion, linear interpolation, IP-Basic, a network's depth
aligned to the points, ...).  None wins everywhere, so the points decide:

1. **folds** — the image is cut into square blocks of ``block`` mean point
   spacings (``sqrt(H W / P)`` pixels) and the blocks holding points are dealt
   to ``folds`` folds by a seeded permutation (:func:`fold_ids`;
   deterministic): a held-out point's nearest training point is about a
   point spacing away or more, as far as the pixels between the sparse
   points are from them, so a candidate that only reproduces its inputs at
   their pixels (interpolation at clustered corners) gains nothing.
2. **held-out residuals** — every candidate is fitted ``folds`` times, each
   time on all points but one fold, and read at the held-out fold's pixels;
   each point thus gets one held-out prediction per candidate, and a
   residual ``log prediction - log depth`` (:func:`heldout_log_residuals`).
3. **blends** — the hypotheses are the log-linear blends
   ``exp(sum_c w_c log D_c)`` of the candidates' maps with weights ``w`` on
   the simplex in steps of ``blend_step`` (:func:`blend_weights`; the pure
   candidates are its corners, ``blend_step=1`` leaves only them); a blend's
   held-out error at a point is ``|sum_c w_c r_c|`` of the candidates'
   residuals there.  Errors of different candidates partly cancel, so a blend
   often beats each of its parts.
4. **regions** — the image is cut into regions (the primitives; pixels of no
   primitive form one region per image cell).  A region's score of a blend is
   the mean held-out error of the points inside it, shrunk towards the score
   of its image cell with the weight of ``prior_points`` points, and the
   cell's score towards the global mean in the same way
   (:func:`region_scores`): a region with many points decides by itself, one
   with few or none follows its cell, a cell with few follows the image.
5. **margin** — a blend's score is multiplied by ``1 + margin (1 - w_f)``,
   ``w_f`` its weight on the ``fallback`` candidate (linear interpolation in
   the completion): a candidate replaces the fallback only where its
   held-out error is below ``1 / (1 + margin)`` of the fallback's, and a
   blend moves off the fallback only as far as its gain pays for.  Where the
   points cannot tell the candidates apart (clustered points: every candidate
   predicts the held-out points about equally well) the fallback, whose error
   the completion must never exceed, is kept.
6. **winner** — per region the blend of the lowest score; the candidates are
   refitted on all points (kept in ``HeldoutChoice.maps`` for
   :func:`rank_agreement`) and each pixel takes its region's blend of them
   (:func:`choose_by_heldout`).

Candidates are callables ``fit(uv, depth) -> (H, W)`` metres (finite and > 0
everywhere) with ``uv`` (K, 2) pixel coordinates (u = column, v = row, of the
map's pixels) and ``depth`` (K,) metres.  Nothing here knows what a candidate
is: the same choice can pick between hypotheses elsewhere.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable, Dict, Mapping, Optional, Tuple

import numpy as np

from ..configs import config_class

__all__ = ["ChooseConfig", "HeldoutChoice", "Candidate", "fold_ids", "heldout_log_residuals",
           "blend_weights", "region_labels", "region_scores", "choose_by_heldout",
           "rank_agreement"]

log = logging.getLogger(__name__)

#: ``fit(uv (K, 2), depth (K,) metres) -> (H, W) metres``, finite and > 0.
Candidate = Callable[[np.ndarray, np.ndarray], np.ndarray]


@config_class
@dataclass(frozen=True)
class ChooseConfig:
    """Options of :func:`choose_by_heldout`.

    Attributes:
        folds: number of folds K (>= 2); every point is held out once.
        seed: seed of the fold permutation.
        block: side of the held-out image blocks in mean point spacings
            (``sqrt(H W / P)`` pixels; > 0).  Small values hold out single
            points.
        prior_points: weight, in points, of the cell's score in a region's
            score and of the global score in a cell's (>= 0; 0: a region with
            a held-out point decides by its points alone).
        grid: (columns, rows) of the image cells (each >= 1).
        blend_step: step of the blend weights on the simplex (``1 / blend_step``
            a whole number >= 1; 1.0: the pure candidates only).
        fallback: name of the candidate kept where the others do not beat it
            by ``margin`` (module docstring, step 5; ignored when no
            candidate has that name).
        margin: a blend's score is multiplied by ``1 + margin`` times its
            weight off the fallback (>= 0; 0: the lowest score wins;
            docs/results.md, issue 54, says why 0.4: 0.5 and 0.6 give up the
            primitives' robustness to outlier points).
    """

    folds: int = 5
    seed: int = 0
    block: float = 2.0
    prior_points: float = 10.0
    grid: Tuple[int, int] = (4, 3)
    blend_step: float = 0.25
    fallback: str = "linear"
    margin: float = 0.4

    def __post_init__(self) -> None:
        if int(self.folds) != self.folds or self.folds < 2:
            raise ValueError(f"ChooseConfig: folds must be an integer >= 2, got {self.folds}")
        if not (np.isfinite(self.block) and self.block > 0):
            raise ValueError(f"ChooseConfig: block must be > 0, got {self.block}")
        if not (np.isfinite(self.prior_points) and self.prior_points >= 0):
            raise ValueError(f"ChooseConfig: prior_points must be >= 0, got {self.prior_points}")
        if len(self.grid) != 2 or min(int(g) for g in self.grid) < 1:
            raise ValueError(f"ChooseConfig: grid must be two integers >= 1, got {self.grid}")
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(f"ChooseConfig: margin must be >= 0, got {self.margin}")
        n = 1.0 / self.blend_step if np.isfinite(self.blend_step) and self.blend_step > 0 else 0
        if not (n >= 1 and abs(n - round(n)) < 1e-9):
            raise ValueError(f"ChooseConfig: 1 / blend_step must be a whole number >= 1, "
                             f"got blend_step {self.blend_step}")


@dataclass
class HeldoutChoice:
    """Result of :func:`choose_by_heldout`.

    Attributes:
        depth: (H, W) metres, each pixel its region's blend of the candidates
            fitted on all points.
        names: the C candidate names, in the order of the indices below.
        winner: (H, W) int16 index into ``names`` of the candidate of the
            largest weight in each pixel's blend.
        region_winner: (R,) the same per region of ``regions``.
        region_weights: (R, C) blend weights per region (rows sum to 1).
        heldout_error: (C,) mean held-out ``|log error|`` of each candidate over
            all points (the global score).
        point_errors: (C, P) held-out ``|log error|`` per candidate and point.
        folds: (P,) fold of each point.
        regions: (H, W) int64 region per pixel (:func:`region_labels`).
        maps: name -> (H, W) metres, every candidate fitted on all points.
    """

    depth: np.ndarray
    names: Tuple[str, ...]
    winner: np.ndarray
    region_winner: np.ndarray
    region_weights: np.ndarray
    heldout_error: np.ndarray
    point_errors: np.ndarray
    folds: np.ndarray
    regions: np.ndarray
    maps: Dict[str, np.ndarray]

    def __repr__(self) -> str:
        """One line: candidates with their held-out error and regions won."""
        won = self.region_counts()
        items = ", ".join(f"{n} {e:.3f} ({won.get(n, 0)} regions)"
                          for n, e in zip(self.names, self.heldout_error))
        return (f"HeldoutChoice({self.regions.max() + 1 if self.regions.size else 0} regions, "
                f"{self.point_errors.shape[1]} points; held-out |log error|: {items})")

    def pixel_counts(self) -> Dict[str, int]:
        """Pixels whose blend weighs each candidate most (name -> count)."""
        c = np.bincount(self.winner.ravel(), minlength=len(self.names))
        return {n: int(c[i]) for i, n in enumerate(self.names)}

    def region_counts(self) -> Dict[str, int]:
        """Regions whose blend weighs each candidate most (name -> count)."""
        c = np.bincount(self.region_winner, minlength=len(self.names))
        return {n: int(c[i]) for i, n in enumerate(self.names)}


def fold_ids(uv: np.ndarray, shape: Tuple[int, int], folds: int, block: float = 2.0,
             seed: int = 0) -> np.ndarray:
    """(P,) fold index in ``[0, folds)`` per point, whole image blocks per fold.

    Args:
        uv: (P, 2) pixel coordinates (u = column, v = row).
        shape: (H, W) of the image, pixels.
        folds: number of folds (>= 2).
        block: block side in mean point spacings ``sqrt(H W / P)`` (> 0); the
            side is halved until at least ``folds`` blocks hold points (when
            the points allow).
        seed: seed of ``numpy.random.default_rng`` permuting the blocks,
            which are then dealt to the folds round-robin.
    Returns:
        (P,) int64; deterministic for given arguments.
    Raises:
        ValueError: ``folds < 2`` or ``block <= 0``.
    """
    if int(folds) < 2 or not block > 0:
        raise ValueError(f"fold_ids: need folds >= 2 and block > 0, got {folds}, {block}")
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    h, w = int(shape[0]), int(shape[1])
    side = max(1.0, float(block) * np.sqrt(h * w / max(uv.shape[0], 1)))
    while True:
        per_row = int(w // side) + 1
        key = (uv[:, 1] // side).astype(np.int64) * per_row + (uv[:, 0] // side).astype(np.int64)
        uniq, inv = np.unique(key, return_inverse=True)
        if uniq.size >= min(int(folds), uv.shape[0]) or side <= 1.0:
            break
        side = max(1.0, side / 2)
    perm = np.random.default_rng(seed).permutation(uniq.size)
    of_block = np.empty(uniq.size, np.int64)
    of_block[perm] = np.arange(uniq.size) % int(folds)
    return of_block[inv.reshape(-1)]


def heldout_log_residuals(candidates: Mapping[str, Candidate], uv: np.ndarray,
                          depth: np.ndarray, folds: np.ndarray) -> np.ndarray:
    """(C, P) ``log(prediction) - log(depth)`` of each candidate at each point,
    the prediction fitted on the points of the other folds.

    Args:
        candidates: name -> :data:`Candidate` (C of them, dict order kept);
            each is fitted once per fold.
        uv: (P, 2) integer-valued pixel coordinates (u, v) inside the maps.
        depth: (P,) metres > 0.
        folds: (P,) fold per point (:func:`fold_ids`).
    Returns:
        (C, P) float64; NaN where a prediction is not finite and > 0.
    """
    uv = np.asarray(uv).reshape(-1, 2)
    u, v = uv[:, 0].astype(np.int64), uv[:, 1].astype(np.int64)
    logd = np.log(np.asarray(depth, dtype=np.float64))
    res = np.full((len(candidates), uv.shape[0]), np.nan)
    for f in np.unique(folds):
        test = folds == f
        train = ~test
        for c, fit in enumerate(candidates.values()):
            pred = np.asarray(fit(uv[train], depth[train]), dtype=np.float64)[v[test], u[test]]
            ok = np.isfinite(pred) & (pred > 0)
            r = np.full(pred.shape, np.nan)
            r[ok] = np.log(pred[ok]) - logd[test][ok]
            res[c, test] = r
    return res


def blend_weights(n_candidates: int, step: float = 0.25) -> np.ndarray:
    """(K, C) weights on the simplex in steps of ``step``: every row >= 0,
    summing to 1; the C pure candidates first (in candidate order), then the
    mixtures, so that ties favour a pure candidate and the first one.

    Args:
        n_candidates: C >= 1.
        step: ``1 / step`` a whole number >= 1.
    Returns:
        (K, C) float64 with ``K = binomial(1 / step + C - 1, C - 1)``.
    """
    import itertools

    n = int(round(1.0 / step))
    c = int(n_candidates)
    rows = [w for w in itertools.product(range(n + 1), repeat=c) if sum(w) == n]
    w = np.array(rows, dtype=np.float64).reshape(-1, c) / n
    pure = np.flatnonzero(w.max(1) == 1.0)
    pure = pure[np.argsort(w[pure].argmax(1))]
    return np.concatenate([w[pure], w[w.max(1) < 1.0]])


def region_labels(labels: np.ndarray, grid: Tuple[int, int]) -> Tuple[np.ndarray, np.ndarray]:
    """Regions and their image cells from a label image.

    Args:
        labels: (H, W) int, region id >= 0 (e.g. a primitive) or -1 (none).
        grid: (columns, rows) of the image cells.
    Returns:
        ``(regions, cell)``: (H, W) int64 region per pixel, the labels
        renumbered densely and every unlabelled pixel in one region per
        cell; (R,) the cell of each region (the cell of its pixel centroid).
    """
    labels = np.asarray(labels)
    h, w = labels.shape
    gx, gy = int(grid[0]), int(grid[1])
    rows, cols = np.mgrid[0:h, 0:w]
    pix_cell = (rows * gy // h) * gx + cols * gx // w
    key = np.where(labels >= 0, labels.astype(np.int64), -1 - pix_cell)
    _, regions = np.unique(key.ravel(), return_inverse=True)
    regions = regions.reshape(h, w)
    n = int(regions.max()) + 1
    cnt = np.bincount(regions.ravel(), minlength=n)
    cy = np.bincount(regions.ravel(), rows.ravel(), n) / cnt
    cx = np.bincount(regions.ravel(), cols.ravel(), n) / cnt
    cell = (np.minimum(cy, h - 1).astype(np.int64) * gy // h) * gx + \
        np.minimum(cx, w - 1).astype(np.int64) * gx // w
    return regions, cell


def _shrunk(err: np.ndarray, group: np.ndarray, n_groups: int, prior: np.ndarray,
            weight: float) -> np.ndarray:
    """(C, G) ``(sum of err in group + weight * prior) / (count + weight)``;
    ``prior`` (C, G); groups without points and ``weight`` 0 take the prior."""
    from scipy.sparse import csr_matrix

    onehot = csr_matrix((np.ones(group.size), (np.arange(group.size), group)),
                        shape=(group.size, n_groups))
    tot = np.asarray((onehot.T @ err.T).T).reshape(err.shape[0], n_groups)
    cnt = np.bincount(group, minlength=n_groups)[None, :].astype(np.float64)
    den = cnt + weight
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (tot + weight * prior) / den
    return np.where(den > 0, out, prior)


def region_scores(err: np.ndarray, point_region: np.ndarray, cell: np.ndarray,
                  prior_points: float) -> np.ndarray:
    """(C, R) score of each candidate per region (module docstring, step 3).

    Args:
        err: (C, P) held-out ``|log error|`` of each candidate (or blend of
            candidates) at each point: the absolute value of
            :func:`heldout_log_residuals` (of a blend, ``|weights @ residuals|``
            as :func:`choose_by_heldout` passes it); non-finite entries count as
            the largest finite error of that point (a candidate that cannot
            predict a point is the worst there).
        point_region: (P,) region of each point in ``[0, R)``.
        cell: (R,) cell of each region (from :func:`region_labels`).
        prior_points: shrinkage weight in points (>= 0).
    Returns:
        (C, R) float64.
    """
    err = np.asarray(err, dtype=np.float64)
    fin = np.isfinite(err)
    worst = np.where(fin, err, -np.inf).max(0, initial=0.0)
    err = np.where(fin, err, worst[None, :])
    n_regions = cell.size
    n_cells = int(cell.max()) + 1 if cell.size else 0
    glob = err.mean(1, keepdims=True) if err.shape[1] else np.zeros((err.shape[0], 1))
    point_cell = cell[point_region]
    by_cell = _shrunk(err, point_cell, n_cells, np.repeat(glob, n_cells, 1), prior_points)
    return _shrunk(err, point_region, n_regions, by_cell[:, cell], prior_points)


def choose_by_heldout(candidates: Mapping[str, Candidate], uv: np.ndarray, depth: np.ndarray,
                      labels: np.ndarray, config: ChooseConfig = ChooseConfig(),
                      fitted: Optional[Mapping[str, np.ndarray]] = None) -> HeldoutChoice:
    """Per region, the blend of the candidates of the lowest held-out error
    (module docstring).

    Args:
        candidates: name -> :data:`Candidate` (at least one); the first wins ties.
        uv: (P, 2) integer-valued pixel coordinates (u, v) inside the (H, W) maps.
        depth: (P,) metres > 0.
        labels: (H, W) int region label (>= 0) or -1 (no region).
        config: :class:`ChooseConfig`.
        fitted: optional name -> (H, W) map already fitted on all points (not
            refitted).
    Returns:
        :class:`HeldoutChoice`.
    Raises:
        ValueError: no candidate, fewer points than ``config.folds``, points
            outside the label image, a depth that is not finite and > 0.
    """
    uv = np.asarray(uv).reshape(-1, 2).astype(np.int64)
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    labels = np.asarray(labels)
    _check_choice_inputs(candidates, uv, depth, labels, config)
    names = tuple(candidates)
    folds = fold_ids(uv, labels.shape, config.folds, config.block, config.seed)
    res = heldout_log_residuals(candidates, uv, depth, folds)
    regions, cell = region_labels(labels, config.grid)
    blends = blend_weights(len(names), config.blend_step)
    scores = region_scores(np.abs(blends @ _worst_filled(res)), regions[uv[:, 1], uv[:, 0]],
                           cell, config.prior_points)
    scores = _with_margin(scores, blends, names, config)
    weights = blends[np.argmin(scores, 0)]                          # (R, C)
    maps = dict(fitted or {})
    log_depth = np.zeros(labels.shape)
    for c, name in enumerate(names):
        if name not in maps:
            maps[name] = np.asarray(candidates[name](uv, depth), dtype=np.float64)
        if weights[:, c].any():
            log_depth += weights[:, c][regions] * np.log(maps[name])
    region_winner = np.argmax(weights, 1).astype(np.int16)
    err = np.abs(res)
    with np.errstate(invalid="ignore"):
        heldout = np.nanmean(err, 1) if err.size else np.zeros(len(names))
    log.debug("held-out choice: errors %s", dict(zip(names, np.round(heldout, 4))))
    return HeldoutChoice(np.exp(log_depth), names, region_winner[regions], region_winner,
                         weights, heldout, np.where(np.isfinite(err), err, np.inf), folds,
                         regions, {n: maps[n] for n in names})


def _with_margin(scores: np.ndarray, blends: np.ndarray, names: Tuple[str, ...],
                 config: ChooseConfig) -> np.ndarray:
    """(K, R) ``scores`` of the blends times ``1 + margin * (1 - w_fallback)``
    (module docstring, step 5)."""
    if config.margin <= 0 or config.fallback not in names:
        return scores
    f = names.index(config.fallback)
    return scores * (1.0 + config.margin * (1.0 - blends[:, f]))[:, None]


def _worst_filled(res: np.ndarray) -> np.ndarray:
    """(C, P) residuals with each non-finite entry replaced by the largest
    finite ``|residual|`` of that point (a candidate that cannot predict a
    point is the worst there; 0 when none can)."""
    fin = np.isfinite(res)
    worst = np.where(fin, np.abs(res), -np.inf).max(0, initial=0.0)
    return np.where(fin, res, worst[None, :])


def _check_choice_inputs(candidates, uv, depth, labels, config) -> None:
    """:func:`choose_by_heldout`'s *Raises*."""
    if not candidates:
        raise ValueError("choose_by_heldout: no candidate")
    if not isinstance(config, ChooseConfig):
        raise TypeError(f"config must be a ChooseConfig, got {type(config).__name__}")
    if depth.size != uv.shape[0] or depth.size < config.folds:
        raise ValueError(f"choose_by_heldout: need as many depths as pixels and at least "
                         f"{config.folds} points, got {depth.size} depths for {uv.shape[0]} "
                         "pixels")
    if not np.all(np.isfinite(depth) & (depth > 0)):
        raise ValueError("choose_by_heldout: depths must be finite and > 0")
    h, w = labels.shape
    if uv.size and (uv.min() < 0 or uv[:, 0].max() >= w or uv[:, 1].max() >= h):
        raise ValueError(f"choose_by_heldout: a point lies outside the {w}x{h} label image")


def rank_agreement(choice: HeldoutChoice, reference: np.ndarray) -> Dict[str, float]:
    """How well the held-out score ranks the candidates as the dense error does.

    Args:
        choice: a :class:`HeldoutChoice` (its ``maps``, ``regions``, scores).
        reference: (H, W) reference depth, metres; 0 / NaN / inf = no reference.
    Returns:
        ``spearman``: Spearman correlation over the candidates of the global
        held-out error (``heldout_error``) with the dense mean ``|log error|``
        (NaN for fewer than two candidates or ties everywhere);
        ``region_agreement``: fraction of the referenced pixels whose region's
        blend weighs most the candidate of the lowest dense mean ``|log
        error|`` in that region; ``oracle_log_error`` / ``chosen_log_error``:
        the dense mean ``|log error|`` of the per-region dense-best pure
        candidates and of the choice (``choice.depth``).
    """
    ref = np.asarray(reference, dtype=np.float64)
    ok = np.isfinite(ref) & (ref > 0)
    reg = choice.regions[ok]
    n = int(choice.regions.max()) + 1
    cnt = np.bincount(reg, minlength=n).astype(np.float64)
    logr = np.log(ref[ok])
    dense = np.stack([np.abs(np.log(np.maximum(choice.maps[c][ok], 1e-9)) - logr)
                      for c in choice.names])                       # (C, Q)
    per_region = np.stack([np.bincount(reg, e, n) for e in dense])  # (C, R) sums
    best = np.argmin(per_region, 0)
    has = cnt > 0
    agree = float(cnt[has & (best == choice.region_winner)].sum() / max(cnt.sum(), 1.0))
    chosen = np.abs(np.log(np.maximum(choice.depth[ok], 1e-9)) - logr)
    return {"spearman": _spearman(choice.heldout_error, dense.mean(1)),
            "region_agreement": agree,
            "oracle_log_error": float(per_region.min(0).sum() / max(cnt.sum(), 1.0)),
            "chosen_log_error": float(chosen.mean()) if chosen.size else float("nan")}


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman rank correlation of two (C,) vectors (average ranks for ties); NaN when
    undefined."""
    from scipy.stats import spearmanr

    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan")
    return float(spearmanr(a, b).correlation)
