"""Feature tracks of a few views (few-view SfM, docs/design.md §5, "Landmark bundle").

Every image (the reference is view 0) gets OpenCV SIFT features
(:func:`spgeo.twoview.backends.opencv_features`); every pair of views its ratio-test
matches (:func:`~spgeo.twoview.backends.ratio_matches`) verified by the two-view
geometry of :func:`spgeo.twoview.relative_pose_from_matches` (essential matrix,
RANSAC, parallax and conditioning checks).  The verified matches of all pairs are
joined into tracks (connected components of the match graph); a component holding
two features of one view is inconsistent and dropped.

A pair whose inliers a homography explains (a plane) may have two physically valid
relative poses; when the other one rotates differently by more than ``AMBIGUITY_DEG``
and explains the inliers as well, the pair is *ambiguous* (:func:`planar_alternatives`):
its matches still join tracks, but it cannot start the map, and it places a view only
where landmarks seen by both views choose among its poses.
"""
from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field
from typing import Dict, List, Sequence, Tuple

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..camera import PinholeCamera
from ..geometry import rotation_angle_deg
from ..twoview import TwoViewConfig, TwoViewResult, relative_pose_from_matches, to_gray_uint8
from ..twoview.backends import opencv_features, ratio_matches
from ..twoview.geometry import pose_from_tgt_ref, refine_sampson, sampson_px

__all__ = ["ViewTracks", "match_views", "planar_alternatives"]

log = logging.getLogger(__name__)

#: a homography explaining this fraction of a pair's inliers makes the pair planar
PLANAR_FRACTION = 0.9
#: a planar pair whose other homography solution's rotation differs by more is ambiguous
AMBIGUITY_DEG = 2.0


@dataclass
class ViewTracks:
    """Features, pairwise geometry and tracks of ``n`` views (view 0: the reference).

    Attributes:
        pixels: per view, (N_v, 2) feature pixels (spgeo convention: pixel centres
            at integers) at the camera's resolution.
        pairs: ``(a, b)`` with ``a < b`` -> :class:`~spgeo.twoview.TwoViewResult` of
            view ``b`` relative to view ``a`` (``T_ref_tgt`` = ``T_a_b``, unit
            translation); its ``inliers`` index ``pair_matches[(a, b)]``.
        pair_matches: ``(a, b)`` -> (M, 2) putative matches (feature of ``a``,
            feature of ``b``).
        tracks: (T, n) feature index of each track in each view, -1 where unseen;
            every track is seen by two views or more.
        alternatives: ``(a, b)`` -> the other poses ``T_a_b`` (unit translation) of
            the pairs (status ``"ok"``) that a plane leaves ambiguous
            (:func:`planar_alternatives`); unambiguous pairs are not keys.
    """

    pixels: List[np.ndarray]
    pairs: Dict[Tuple[int, int], TwoViewResult]
    pair_matches: Dict[Tuple[int, int], np.ndarray]
    tracks: np.ndarray
    alternatives: Dict[Tuple[int, int], List[np.ndarray]] = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        return len(self.pixels)

    def observed(self, views: Sequence[int]) -> np.ndarray:
        """(T,) True for the tracks seen in every view of ``views``."""
        return np.all(self.tracks[:, list(views)] >= 0, axis=1)

    def track_pixels(self, view: int, rows: np.ndarray) -> np.ndarray:
        """(len(rows), 2) pixels of tracks ``rows`` in ``view`` (NaN where unseen)."""
        idx = self.tracks[rows, view]
        out = np.full((len(idx), 2), np.nan)
        out[idx >= 0] = self.pixels[view][idx[idx >= 0]]
        return out

    def verified_matches(self, a: int, b: int) -> np.ndarray:
        """(K, 2) feature indices of the geometric inliers of pair ``(a, b)``
        (``a < b``): of its essential matrix (status ``"ok"``) or of its rotation
        (``"low_parallax"``); empty otherwise."""
        res = self.pairs[(a, b)]
        if res.status not in ("ok", "low_parallax"):
            return np.zeros((0, 2), np.int64)
        return self.pair_matches[(a, b)][res.inliers]


def planar_alternatives(res: TwoViewResult, camera: PinholeCamera,
                        threshold_px: float = 1.0) -> List[np.ndarray]:
    """The other relative poses ``T_ref_tgt`` (unit translation) of an ``"ok"`` pair
    ``res`` that explain its inliers as well: the poses of the homography of the
    inliers that keep them in front of both cameras, whose rotation differs from
    ``res``'s by more than ``AMBIGUITY_DEG``, and which, refined on the inliers'
    Sampson distances, keep ``PLANAR_FRACTION`` of them within ``threshold_px`` (an
    equally good RANSAC model).  Empty when no homography explains that fraction of
    the inliers (the scene is not a plane: the pose is unique)."""
    x1, x2 = res.points_ref.astype(np.float64), res.points_tgt.astype(np.float64)
    if len(x1) < 8:
        return []
    H, mask = cv2.findHomography(x1, x2, cv2.RANSAC, 2.0)
    if H is None or mask.sum() < PLANAR_FRACTION * len(x1):
        return []
    _, Rs, ts, normals = cv2.decomposeHomographyMat(H, camera.K)
    inl = mask.ravel() > 0
    n1, n2 = (((x[inl] - [camera.cx, camera.cy]) / [camera.fx, camera.fy])
              .astype(np.float32).reshape(-1, 1, 2) for x in (x1, x2))   # normalised
    kept = cv2.filterHomographyDecompByVisibleRefpoints(Rs, normals, n1, n2)
    R_tgt_ref = res.T_ref_tgt[:3, :3].T
    out = []
    for i in ([] if kept is None else kept.ravel()):
        if rotation_angle_deg(Rs[i].T @ R_tgt_ref) <= AMBIGUITY_DEG:
            continue
        R, t = refine_sampson(camera, Rs[i], ts[i].ravel(), x1, x2, threshold_px)
        fits = np.abs(sampson_px(camera, R, t, x1, x2)) <= threshold_px
        if rotation_angle_deg(R @ R_tgt_ref.T) > AMBIGUITY_DEG and fits.mean() >= PLANAR_FRACTION:
            out.append(pose_from_tgt_ref(R, t))
    return out


def _tracks_from_matches(sizes: Sequence[int], edges: Sequence[np.ndarray],
                         pair_ids: Sequence[Tuple[int, int]]) -> np.ndarray:
    """(T, n) tracks: connected components of the graph whose nodes are the features
    (``sizes[v]`` of view ``v``) and whose edges are the verified matches
    (``edges[k]`` (K, 2) between views ``pair_ids[k]``); components with two features
    of one view, or a single view, are dropped."""
    n = len(sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    rows = [offsets[a] + e[:, 0] for e, (a, _) in zip(edges, pair_ids)]
    cols = [offsets[b] + e[:, 1] for e, (_, b) in zip(edges, pair_ids)]
    total = int(offsets[-1])
    if total == 0 or not any(len(r) for r in rows):
        return np.zeros((0, n), np.int64)
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(total, total))
    _, label = connected_components(graph, directed=False)
    view = np.repeat(np.arange(n), sizes)
    feat = np.arange(total) - offsets[view]
    used = np.unique(np.concatenate([r, c]))
    comp, inv = np.unique(label[used], return_inverse=True)
    counts = np.zeros((len(comp), n), np.int64)
    np.add.at(counts, (inv, view[used]), 1)
    tracks = np.full((len(comp), n), -1, np.int64)
    tracks[inv, view[used]] = feat[used]
    good = np.all(counts <= 1, axis=1) & (np.sum(counts, axis=1) >= 2)
    return tracks[good]


def match_views(images: Sequence[np.ndarray], camera: PinholeCamera,
                config: TwoViewConfig) -> ViewTracks:
    """Features of ``images`` (view 0 first), the verified matches of every pair and
    their tracks (module docstring).

    Args:
        images: (H, W[, 3]) images of ``camera``'s size (uint8 / uint16 or float in
            [0, 1]), undistorted.
        camera: their intrinsics (no distortion).
        config: features (``features``, ``max_features``, ...) and the two-view
            geometry's thresholds (``min_inliers``, ``min_parallax_deg``, ...).
    Returns:
        :class:`ViewTracks`.
    """
    options = config.feature_options
    feats = [opencv_features(to_gray_uint8(im, f"view {v}"), options)
             for v, im in enumerate(images)]
    pixels = [f[0] for f in feats]
    pairs: Dict[Tuple[int, int], TwoViewResult] = {}
    pair_matches: Dict[Tuple[int, int], np.ndarray] = {}
    for a, b in itertools.combinations(range(len(images)), 2):
        m = ratio_matches(feats[a][1], feats[b][1], options)
        pair_matches[(a, b)] = m
        pairs[(a, b)] = relative_pose_from_matches(pixels[a][m[:, 0]], pixels[b][m[:, 1]],
                                                   camera, config)
        log.debug("pair %d-%d: %d matches, %s, %d inliers", a, b, len(m), pairs[(a, b)].status,
                  pairs[(a, b)].num_inliers)
    ids = [k for k, r in pairs.items() if r.status in ("ok", "low_parallax")]
    alternatives = {k: planar_alternatives(r, camera, config.ransac_threshold_px)
                    for k, r in pairs.items() if r.ok}
    vt = ViewTracks(pixels, pairs, pair_matches, np.zeros((0, len(images)), np.int64),
                    {k: alt for k, alt in alternatives.items() if alt})
    vt.tracks = _tracks_from_matches([len(p) for p in pixels],
                                     [vt.verified_matches(a, b) for a, b in ids], ids)
    return vt
