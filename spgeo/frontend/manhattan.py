"""Manhattan / vanishing-point normals: an offline, depth-free normal estimator.

Method (after Lee, Hebert and Kanade, CVPR 2009, "Geometric reasoning for single
image structure recovery"):

1. line segments (:mod:`spgeo.frontend.lines`) and their vanishing directions
   ``d_0..d_{k-1}`` (:mod:`spgeo.frontend.vanishing`, camera frame);
2. every pair of directions ``(i, j)`` at least ``min_pair_angle_deg`` apart
   spans a plane orientation with normal ``d_i x d_j``;
3. **orientation map**: each segment of class ``i`` is swept towards and away
   from the vanishing point of ``j`` (a homothety about it, or a translation
   when it lies at infinity) until it meets a segment of a third class (or the
   sweep limit); the pixels swept by class-``i`` segments towards ``j`` *and*
   by class-``j`` segments towards ``i`` may hold a plane of orientation
   ``(i, j)``.  A pixel claimed by exactly one orientation gets its label;
   others stay unknown (-1);
4. per region of a :class:`~spgeo.frontend.base.Segmentation`, two cues,
   after discarding orientations its mean ray would see at grazing incidence
   (``max_incidence_deg``): (a) segments of classes ``i`` and ``j`` lying
   *inside* the region vote for ``(i, j)`` (the smaller of the two lengths);
   (b) the histogram of the orientation-map labels of its pixels (fraction of
   the region).  The best of (a) is used when it is ``dominance`` times the
   second's, else the best of (b) when it covers at least ``min_confidence``
   of the region and ``dominance`` times the second's, else the region is
   "unknown".  The hypothesis list ranks the sum of both normalised cues.

Normals follow spgeo's convention (camera x right, y down, z forward; oriented
towards the camera, ``n . ray < 0``); unknown pixels / regions get the
fronto-parallel ``(0, 0, -1)``.  Scenes without lines give all-unknown.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import List, Optional

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..images import to_float_image
from .base import Segmentation, Segmenter, config_with_overrides
from .lines import LineDetectorConfig, LineSegments, detect_line_segments
from .vanishing import VanishingConfig, VanishingResult, estimate_vanishing_directions

__all__ = ["ManhattanNormalsConfig", "ManhattanEstimate", "ManhattanNormals",
           "orientation_map", "SharedSegmenter"]

logger = logging.getLogger(__name__)

_FRONTO = np.array([0.0, 0.0, -1.0])


@config_class
@dataclass(frozen=True)
class ManhattanNormalsConfig:
    """Options of :class:`ManhattanNormals`.

    Attributes:
        lines: line detector options.
        vanishing: vanishing-direction options.
        min_pair_angle_deg: two directions closer than this (degrees) span no
            plane orientation.
        sweep_max_frac: a sweep moves a segment by at most this fraction of the
            image diagonal (measured at the segment's midpoint).
        sweep_samples: points sampled on each blocking segment.
        min_confidence: a region's best orientation needs at least this
            fraction of the region's pixels.
        dominance: ... and at least this many times the second one's pixels
            (for the interior-line votes: the second one's vote).
        interior_offset: a line segment counts as inside a region when the
            points this many pixels to either side of it lie in the region.
        use_interior_lines: use the interior-line votes (else only the sweep
            orientation map decides).
        max_incidence_deg: a region rejects orientations that its mean viewing
            ray would see at a larger incidence angle (degrees).
    """

    lines: LineDetectorConfig = field(default_factory=LineDetectorConfig)
    vanishing: VanishingConfig = field(default_factory=VanishingConfig)
    min_pair_angle_deg: float = 30.0
    sweep_max_frac: float = 0.2
    sweep_samples: int = 5
    min_confidence: float = 0.5
    dominance: float = 2.0
    interior_offset: float = 2.0
    use_interior_lines: bool = True
    max_incidence_deg: float = 75.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_pair_angle_deg <= 90.0:
            raise ValueError(f"ManhattanNormalsConfig: min_pair_angle_deg must be in (0, 90], "
                             f"got {self.min_pair_angle_deg}")
        if self.sweep_max_frac <= 0 or self.sweep_samples < 2:
            raise ValueError("ManhattanNormalsConfig: sweep_max_frac must be > 0 and "
                             "sweep_samples >= 2")
        if not 0.0 <= self.min_confidence <= 1.0 or self.dominance < 1.0:
            raise ValueError("ManhattanNormalsConfig: min_confidence must be in [0, 1] and "
                             "dominance >= 1")


@dataclass
class ManhattanEstimate:
    """Result of :meth:`ManhattanNormals.analyse`.

    Attributes:
        normals: (H, W, 3) float32 unit normals towards the camera;
            fronto-parallel ``(0, 0, -1)`` where unknown.
        known: (H, W) bool, True where ``normals`` come from a hypothesis.
        directions: (k, 3) vanishing directions (camera frame).
        plane_pairs: (P, 2) direction indices spanning each plane orientation.
        plane_normals: (P, 3) unit normals ``d_i x d_j`` (sign arbitrary).
        pixel_label: (H, W) int plane-orientation index, -1 unknown.
        segments: the line segments; ``vanishing`` the direction estimate.
        segment_normals: (N, 3) per region of the segmentation (fronto-parallel
            when unknown); None without a segmentation.
        segment_confidence: (N,) fraction of the region's pixels supporting
            its normal (0 when unknown).
        segment_hypotheses: per region, a list of ``(plane index, confidence)``
            sorted by confidence (possibly empty).
    """

    normals: np.ndarray
    known: np.ndarray
    directions: np.ndarray
    plane_pairs: np.ndarray
    plane_normals: np.ndarray
    pixel_label: np.ndarray
    segments: LineSegments
    vanishing: VanishingResult
    segment_normals: Optional[np.ndarray] = None
    segment_confidence: Optional[np.ndarray] = None
    segment_hypotheses: Optional[List[list]] = None

    @property
    def coverage(self) -> float:
        """Fraction of pixels with a known normal."""
        return float(self.known.mean()) if self.known.size else 0.0


def _vp_homogeneous(d: np.ndarray, camera: PinholeCamera, diag: float) -> np.ndarray:
    """Vanishing point ``K d`` scaled to w = 1, or to a unit image direction with
    w = 0 when it lies farther than 1e3 diagonals (treated as at infinity)."""
    v = np.array([camera.fx * d[0] + camera.cx * d[2], camera.fy * d[1] + camera.cy * d[2], d[2]])
    if abs(v[2]) * 1e3 * diag > np.hypot(v[0], v[1]):
        return v / v[2]
    return np.array([v[0], v[1], 0.0]) / max(np.hypot(v[0], v[1]), 1e-12)


def _sweep_mask(seg_pts: np.ndarray, blockers: np.ndarray, v: np.ndarray, shape,
                max_move: float) -> np.ndarray:
    """Pixels swept by segments ``seg_pts`` (n, 4) moved towards / away from the
    vanishing point ``v`` (homogeneous, w in {0, 1}) until a blocker point
    ((m, 2) samples of the blocking segments) or ``max_move`` pixels."""
    h, w = shape
    mask = np.zeros((h, w), np.uint8)
    if seg_pts.shape[0] == 0:
        return mask
    a = np.concatenate([seg_pts[:, :2], np.ones((len(seg_pts), 1))], 1)
    b = np.concatenate([seg_pts[:, 2:], np.ones((len(seg_pts), 1))], 1)
    line = np.cross(a, b)                                  # (n, 3)
    lv = line @ v                                          # (n,)
    mid = 0.5 * (a + b)
    # pixels moved by the midpoint per unit t
    speed = np.hypot(*(v[:2] - v[2] * mid[:, :2]).T)
    ok = (np.abs(lv) > 1e-9) & (speed > 1e-9)
    t_cap = np.where(ok, max_move / np.maximum(speed, 1e-12), 0.0)
    t_hi = np.minimum(t_cap, 0.95) if v[2] != 0 else t_cap
    t_lo = -t_cap
    if blockers.shape[0] and ok.any():
        x = np.concatenate([blockers, np.ones((len(blockers), 1))], 1)   # (m, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (x @ line.T) / lv[None, :]                                # (m, n)
            # where the ray from v through x meets the segment's line
            p = np.cross(np.cross(v[None, :], x)[:, None, :], line[None, :, :])  # (m, n, 3)
            pw = p[..., 2]
            pu, pv = p[..., 0] / pw, p[..., 1] / pw
            d = (b - a)[:, :2]
            lam = ((pu - a[:, 0]) * d[:, 0] + (pv - a[:, 1]) * d[:, 1]) / np.sum(d * d, 1)
            inside = (lam >= 0) & (lam <= 1) & np.isfinite(t) & (np.abs(pw) > 1e-12)
        pos = np.where(inside & (t > 1e-6), t, np.inf).min(axis=0)
        neg = np.where(inside & (t < -1e-6), t, -np.inf).max(axis=0)
        t_hi = np.minimum(t_hi, pos)
        t_lo = np.maximum(t_lo, neg)
    big = 8.0 * max(h, w)
    for i in np.flatnonzero(ok):
        quad = []
        for t in (t_lo[i], t_hi[i]):
            for pnt in (a[i], b[i]):
                q = pnt + t * (v - v[2] * pnt)
                quad.append(q[:2])
        quad = np.array([quad[0], quad[1], quad[3], quad[2]])
        quad = np.clip(np.round(quad), -big, big).astype(np.int32)
        cv2.fillConvexPoly(mask, quad, 1)
    return mask


def _blocker_samples(pts: np.ndarray, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    return (pts[:, None, :2] * (1 - s)[None, :, None] + pts[:, None, 2:] * s[None, :, None]
            ).reshape(-1, 2)


def orientation_map(segments: LineSegments, vanishing: VanishingResult, camera: PinholeCamera,
                    config: ManhattanNormalsConfig = ManhattanNormalsConfig()):
    """Per-pixel plane orientation from the line sweeps (module docstring, step 3).

    Returns ``(pixel_label (H, W) int, plane_pairs (P, 2), plane_normals (P, 3))``.
    """
    h, w = camera.shape
    diag = float(np.hypot(w, h))
    dirs = vanishing.directions
    k = len(dirs)
    cos_min = np.cos(np.radians(config.min_pair_angle_deg))
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)
             if abs(float(dirs[i] @ dirs[j])) < cos_min]
    label = np.full((h, w), -1, np.int64)
    if not pairs:
        return label, np.zeros((0, 2), np.int64), np.zeros((0, 3))
    ends = segments.endpoints
    cls = vanishing.assignment
    vps = [_vp_homogeneous(d, camera, diag) for d in dirs]
    max_move = config.sweep_max_frac * diag
    count = np.zeros((h, w), np.int32)
    for p, (i, j) in enumerate(pairs):
        blk = _blocker_samples(ends[(cls >= 0) & (cls != i) & (cls != j)], config.sweep_samples)
        mi = _sweep_mask(ends[cls == i], blk, vps[j], (h, w), max_move)
        mj = _sweep_mask(ends[cls == j], blk, vps[i], (h, w), max_move)
        both = (mi & mj).astype(bool)
        count += both
        label[both] = p
    label[count != 1] = -1
    pairs_a = np.array(pairs, np.int64)
    normals = np.cross(dirs[pairs_a[:, 0]], dirs[pairs_a[:, 1]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return label, pairs_a, normals


def _towards_camera(n: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Flip normals ``n`` (..., 3) so that ``n . ray < 0``."""
    return np.where((np.sum(n * rays, axis=-1) > 0)[..., None], -n, n)


def _interior_line_votes(est: "ManhattanEstimate", region_of: np.ndarray, n_reg: int,
                         n_pl: int, offset: float) -> np.ndarray:
    """(n_reg, n_pl) plane-orientation votes of the segments lying inside regions.

    A segment lies inside region ``r`` when points sampled along it, shifted by
    ``offset`` pixels to either side, all fall in ``r``.  Region ``r`` gets, for
    each orientation ``(i, j)``, the smaller of its class-``i`` and class-``j``
    interior segment lengths (both directions must be seen on the plane).
    """
    score = np.zeros((n_reg, n_pl))
    cls = est.vanishing.assignment
    use = np.flatnonzero(cls >= 0)
    if use.size == 0 or len(est.plane_pairs) == 0 or n_reg == 0:
        return score
    h, w = region_of.shape
    e = est.segments.endpoints[use]
    t = np.linspace(0.15, 0.85, 7)
    du, dv = e[:, 2] - e[:, 0], e[:, 3] - e[:, 1]
    ln = np.hypot(du, dv)
    nu, nv = -dv / ln * offset, du / ln * offset
    ids = []
    for side in (-1.0, 1.0):
        u = e[:, 0, None] + t[None] * du[:, None] + side * nu[:, None]
        v = e[:, 1, None] + t[None] * dv[:, None] + side * nv[:, None]
        ui = np.clip(np.round(u).astype(np.int64), 0, w - 1)
        vi = np.clip(np.round(v).astype(np.int64), 0, h - 1)
        ids.append(region_of[vi, ui])
    ids = np.concatenate(ids, axis=1)
    r0 = ids[:, 0]
    inside = (r0 >= 0) & np.all(ids == r0[:, None], axis=1)
    k = len(est.directions)
    per_class = np.zeros((n_reg, k))
    np.add.at(per_class, (r0[inside], cls[use][inside]), ln[inside])
    pa = est.plane_pairs
    score[:, :len(pa)] = np.minimum(per_class[:, pa[:, 0]], per_class[:, pa[:, 1]])
    return score


class SharedSegmenter:
    """Wraps a :class:`Segmenter` and returns its last result again when called
    with the very same image object and camera, so that a front-end's segmenter
    and a segmentation-aware normal estimator cut the image once."""

    def __init__(self, segmenter: Segmenter) -> None:
        self.segmenter = segmenter
        self._last = None

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        if self._last is not None and self._last[0] is image and self._last[1] == camera:
            return self._last[2]
        seg = self.segmenter.segment(image, camera)
        self._last = (image, camera, seg)
        return seg

    def __repr__(self) -> str:
        return f"SharedSegmenter({self.segmenter!r})"


class ManhattanNormals:
    """Vanishing-point normals (module docstring).  Uses no depth.

    Implements :class:`spgeo.frontend.base.NormalEstimator`.  With a
    ``segmenter``, :meth:`estimate` decides one normal per region of its
    segmentation (pass a :class:`SharedSegmenter` that the front-end also uses
    to segment only once); without, it returns the per-pixel orientation map.
    """

    uses_depth: bool = False

    def __init__(self, config: Optional[ManhattanNormalsConfig] = None,
                 segmenter: Optional[Segmenter] = None, **overrides) -> None:
        self.config = config_with_overrides(ManhattanNormalsConfig, config, overrides)
        self.segmenter = segmenter

    def analyse(self, image: np.ndarray, camera: PinholeCamera,
                segmentation: Optional[Segmentation] = None) -> ManhattanEstimate:
        """Full result for ``image`` (matching ``camera``); per-region hypotheses
        when ``segmentation`` (same size) is given."""
        img = to_float_image(camera.check_image(image))
        cfg = self.config
        h, w = camera.shape
        segs = detect_line_segments(img, cfg.lines)
        vp = estimate_vanishing_directions(segs, camera, cfg.vanishing)
        label, pairs, pnormals = orientation_map(segs, vp, camera, cfg)
        rays = camera.rays()
        normals = np.broadcast_to(_FRONTO, (h, w, 3)).copy()
        known = label >= 0
        if known.any():
            normals[known] = _towards_camera(pnormals[label[known]], rays[known])
        est = ManhattanEstimate(normals, known, vp.directions, pairs, pnormals, label, segs, vp)
        if segmentation is not None:
            self._per_region(est, segmentation, rays)
        est.normals = est.normals.astype(np.float32)
        logger.debug("manhattan normals: %d segments, %d directions, %d orientations, "
                     "coverage %.3f", len(segs), len(vp), len(pairs), est.coverage)
        return est

    def _per_region(self, est: ManhattanEstimate, seg: Segmentation, rays: np.ndarray) -> None:
        cfg = self.config
        h, w = est.pixel_label.shape
        if (seg.height, seg.width) != (h, w):
            raise ValueError(f"segmentation is {seg.width}x{seg.height}, image is {w}x{h}")
        n_reg, n_pl = len(seg), len(est.plane_normals)
        sizes = np.array([r.size for r in seg.regions], np.int64)
        pix = np.concatenate(seg.regions) if n_reg else np.zeros(0, np.int64)
        rid = np.repeat(np.arange(n_reg), sizes)
        npl = max(n_pl, 1)
        # cue 1: segments of two classes lying inside a region span its plane
        region_of = np.full(h * w, -1, np.int64)
        region_of[pix] = rid
        line_score = _interior_line_votes(est, region_of.reshape(h, w), n_reg, npl,
                                          cfg.interior_offset)
        # cue 2: the sweep orientation map (fraction of the region's pixels)
        lab = est.pixel_label.reshape(-1)[pix]
        good = lab >= 0
        hist = np.bincount(rid[good] * npl + lab[good],
                           minlength=n_reg * npl).reshape(n_reg, npl)
        frac = hist / np.maximum(sizes, 1)[:, None]
        rows = np.arange(n_reg)
        mean_ray = np.stack([np.bincount(rid, weights=rays.reshape(-1, 3)[pix, c],
                                         minlength=n_reg) for c in range(3)], 1)
        if n_pl:
            # planes seen at grazing incidence from the region are implausible
            unit_ray = mean_ray / np.maximum(np.linalg.norm(mean_ray, axis=1, keepdims=True),
                                             1e-12)
            steep = np.abs(unit_ray @ est.plane_normals.T) < np.cos(
                np.radians(cfg.max_incidence_deg))
            line_score[:, :n_pl][steep] = 0.0
            frac[:, :n_pl][steep] = 0.0

        def decide(score: np.ndarray, min_score: float):
            order = np.argsort(-score, axis=1)
            top = score[rows, order[:, 0]] if n_reg else np.zeros(0)
            second = score[rows, order[:, 1]] if npl > 1 else np.zeros(n_reg)
            ok = (n_pl > 0) & (top >= min_score) & (top >= cfg.dominance * second)
            return order, top, ok

        l_order, l_top, l_ok = decide(line_score, 1e-9)
        s_order, s_top, s_ok = decide(frac, cfg.min_confidence)
        use_line = l_ok & cfg.use_interior_lines
        accept = use_line | s_ok
        best = np.where(use_line, l_order[:, 0] if n_reg else 0, s_order[:, 0] if n_reg else 0)
        conf = np.where(use_line, l_top / np.maximum(line_score.sum(axis=1), 1e-12), s_top)
        flat = np.broadcast_to(_FRONTO, (h * w, 3)).copy()
        known = np.zeros(h * w, bool)
        seg_n = np.broadcast_to(_FRONTO, (n_reg, 3)).copy()
        if n_pl and accept.any():
            # orient each region's normal at the region's mean ray
            chosen = _towards_camera(est.plane_normals[best], mean_ray)
            seg_n[accept] = chosen[accept]
            pix_acc = accept[rid]
            flat[pix[pix_acc]] = seg_n[rid[pix_acc]]
            known[pix[pix_acc]] = True
        est.segment_normals = seg_n
        est.segment_confidence = np.where(accept, conf, 0.0)
        # hypothesis list: line votes first (normalised), then sweep fractions
        comb = line_score / np.maximum(line_score.sum(axis=1, keepdims=True), 1e-12) + frac
        comb_order = np.argsort(-comb, axis=1)
        est.segment_hypotheses = [
            [(int(q), float(comb[r, q])) for q in comb_order[r] if comb[r, q] > 0]
            if n_pl else [] for r in range(n_reg)]
        est.normals = flat.reshape(h, w, 3)
        est.known = known.reshape(h, w)

    def estimate_for_segmentation(self, image: np.ndarray, camera: PinholeCamera,
                                  segmentation: Segmentation) -> ManhattanEstimate:
        """:meth:`analyse` with per-region normals of ``segmentation``."""
        return self.analyse(image, camera, segmentation)

    def estimate(self, image: np.ndarray, camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        """(H, W, 3) float32 unit normals towards the camera, (0, 0, -1) where
        unknown.  ``depth`` is ignored."""
        seg = None if self.segmenter is None else self.segmenter.segment(image, camera)
        return self.analyse(image, camera, seg).normals

    def __repr__(self) -> str:
        return f"ManhattanNormals({self.config!r})"
