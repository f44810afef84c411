"""Where the sparse depth points of a completion input lie, sampled from a dense
reference depth (the inputs of the demo and of the completion benchmarks).

Each function takes a dense reference depth (H, W) metres (0 / NaN / inf =
none) and returns an (H, W) float64 sparse map, metres with 0 = missing, at
pixels chosen the way a depth-completion input gets them:

* :func:`keypoint_sparse_depth`: FAST corners, spread by a grid (VOID's
  tracked corners) or the strongest ones, clustered on texture;
* :func:`uniform_sparse_depth`: uniform random pixels with depth;
* :func:`track_sparse_depth`: corners that a KLT tracker keeps over the next
  few frames, as a SLAM / VIO front-end hands them over (issue 39).

All are deterministic in their ``seed``.
"""
from __future__ import annotations

import logging
from typing import Sequence

import cv2
import numpy as np

from ..images import to_float_image, to_gray

__all__ = ["keypoint_sparse_depth", "uniform_sparse_depth", "track_sparse_depth"]

log = logging.getLogger(__name__)


def _grey8(image: np.ndarray) -> np.ndarray:
    """uint8 grey of an RGB / grey image (any dtype :func:`to_float_image` takes)."""
    img = to_float_image(image)
    return np.rint(255 * (to_gray(img) if img.ndim == 3 else img)).astype(np.uint8)


def keypoint_sparse_depth(image: np.ndarray, depth: np.ndarray, n_points: int = 150,
                          rel_noise: float = 0.01, seed: int = 0, fast_threshold: int = 10,
                          spread: bool = True) -> np.ndarray:
    """Sparse depth at image keypoints, the way VIO gives it (VOID's points are
    tracked corners).

    FAST corners (OpenCV, non-maximum suppression) with valid depth are
    spread over the image by keeping the strongest corner per grid cell
    (cells sized for about ``2 * n_points`` cells), then the ``n_points``
    strongest of those (more from the remaining corners if too few cells are
    occupied); with ``spread=False`` simply the ``n_points`` strongest corners,
    which cluster on texture (the held-out regime of issue 39).  Depths get
    multiplicative Gaussian noise ``d * (1 + rel_noise * N(0, 1))``.  The FAST
    threshold is lowered (to 5, then 1) when too few corners are found.
    Deterministic in ``seed``.

    Returns (H, W) float64 metres, 0 = missing.
    """
    grey = _grey8(image)
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != grey.shape:
        raise ValueError(f"depth shape {depth.shape} != image shape {grey.shape}")
    if int(n_points) < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    if rel_noise < 0 or not np.isfinite(rel_noise):
        raise ValueError(f"rel_noise must be finite and >= 0, got {rel_noise}")
    h, w = grey.shape
    ok = np.isfinite(depth) & (depth > 0)
    u = v = resp = np.zeros(0)
    for thr in sorted({int(fast_threshold), 5, 1}, reverse=True):
        det = cv2.FastFeatureDetector_create(threshold=thr, nonmaxSuppression=True)
        kps = det.detect(grey, None)
        if kps:
            pts = np.array([kp.pt for kp in kps])
            resp = np.array([kp.response for kp in kps])
            u = np.clip(np.rint(pts[:, 0]), 0, w - 1).astype(np.int64)
            v = np.clip(np.rint(pts[:, 1]), 0, h - 1).astype(np.int64)
            keep = ok[v, u]
            u, v, resp = u[keep], v[keep], resp[keep]
        if u.size >= n_points:
            break
    if u.size == 0:
        raise ValueError("keypoint_sparse_depth: no keypoint with valid depth")
    # unique pixels, strongest first (stable on ties: raster order)
    flat = v * w + u
    order = np.lexsort((flat, -resp))
    flat, resp = flat[order], resp[order]
    _, first = np.unique(flat, return_index=True)
    first = np.sort(first)
    flat, resp = flat[first], resp[first]
    if not spread:
        return _with_noise(flat[:n_points], depth, rel_noise, seed)
    cell = max(1.0, np.sqrt(h * w / (2.0 * n_points)))
    cu = ((flat % w) / cell).astype(np.int64)
    cv_ = ((flat // w) / cell).astype(np.int64)
    cid = cv_ * (int(w / cell) + 1) + cu
    _, best = np.unique(cid, return_index=True)  # first = strongest per cell
    best = np.sort(best)
    chosen = best[:n_points]
    if chosen.size < n_points:
        rest = np.setdiff1d(np.arange(flat.size), chosen, assume_unique=True)
        chosen = np.concatenate([chosen, rest[:n_points - chosen.size]])
    if chosen.size < n_points:
        log.debug("keypoint_sparse_depth: only %d keypoints with depth (asked %d)", chosen.size,
                  n_points)
    return _with_noise(flat[chosen], depth, rel_noise, seed)


def _with_noise(sel: np.ndarray, depth: np.ndarray, rel_noise: float, seed: int) -> np.ndarray:
    """(H, W) sparse map: ``depth`` at the flat pixel indices ``sel`` times
    ``1 + rel_noise * N(0, 1)`` (at least 1 mm), 0 elsewhere."""
    rng = np.random.default_rng(seed)
    out = np.zeros(depth.size)
    d = depth.reshape(-1)[sel]
    out[sel] = np.maximum(d * (1.0 + rel_noise * rng.standard_normal(sel.size)), 1e-3)
    return out.reshape(depth.shape)


def uniform_sparse_depth(depth: np.ndarray, n_points: int = 150, rel_noise: float = 0.0,
                         seed: int = 0) -> np.ndarray:
    """Sparse depth at ``n_points`` pixels drawn uniformly among those with
    valid depth (finite, > 0), deterministic in ``seed``; noise as
    :func:`keypoint_sparse_depth`.  Returns (H, W) metres, 0 = missing; raises
    ``ValueError`` when no pixel has depth or ``n_points < 1``."""
    depth = np.asarray(depth, dtype=np.float64)
    valid = np.flatnonzero(np.isfinite(depth.reshape(-1)) & (depth.reshape(-1) > 0))
    if valid.size == 0 or int(n_points) < 1:
        raise ValueError(f"uniform_sparse_depth: {valid.size} valid pixels, n_points {n_points}")
    rng = np.random.default_rng([int(seed), 39])
    sel = rng.choice(valid, size=min(int(n_points), valid.size), replace=False)
    return _with_noise(np.sort(sel), depth, rel_noise, seed)


def track_sparse_depth(images: Sequence[np.ndarray], depth: np.ndarray, n_points: int = 150,
                       rel_noise: float = 0.0, seed: int = 0, min_distance: float = 10.0,
                       fb_tolerance: float = 1.0) -> np.ndarray:
    """Sparse depth at the corners of ``images[0]`` that a KLT tracker keeps
    through ``images[1:]``, the points a SLAM / VIO front-end hands over.

    Shi-Tomasi corners (``cv2.goodFeaturesToTrack``: up to ``4 * n_points``,
    quality 0.01, ``min_distance`` pixels apart) with valid depth are tracked
    frame to frame by pyramidal Lucas-Kanade (21x21 window, 3 levels); a
    track ends when LK fails, leaves the image, or its backward track misses
    its start by more than ``fb_tolerance`` pixels.  The strongest
    ``n_points`` survivors are kept; when fewer survive, the strongest lost
    ones (longest-lived first) complete the set.  The survivors cluster
    where texture is trackable, as a front-end's points do.

    Args:
        images: the frame and the frames after it (or before it) in time
            order away from it, RGB or grey, all of one size; at least one.
        depth: (H, W) reference depth of ``images[0]``, metres.
        n_points: points to keep (>= 1).
        rel_noise, seed: noise as :func:`keypoint_sparse_depth`.
        min_distance: least corner spacing, pixels.
        fb_tolerance: forward-backward tolerance, pixels (> 0).
    Returns:
        (H, W) float64 metres, 0 = missing.
    Raises:
        ValueError: no image, images of other sizes than ``depth``, no
            corner with depth, ``n_points < 1``.
    """
    if len(images) < 1 or int(n_points) < 1:
        raise ValueError(f"track_sparse_depth: need an image and n_points >= 1, got "
                         f"{len(images)} images, n_points {n_points}")
    greys = [_grey8(im) for im in images]
    depth = np.asarray(depth, dtype=np.float64)
    if any(g.shape != depth.shape for g in greys):
        raise ValueError(f"track_sparse_depth: image sizes {[g.shape for g in greys]} differ "
                         f"from the depth's {depth.shape}")
    h, w = depth.shape
    ok = np.isfinite(depth) & (depth > 0)
    pts = cv2.goodFeaturesToTrack(greys[0], 4 * int(n_points), 0.01, float(min_distance))
    pts = np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2)
    px = np.rint(pts).astype(np.int64).clip(0, [w - 1, h - 1])
    keep = ok[px[:, 1], px[:, 0]]
    pts, px = pts[keep], px[keep]
    if pts.shape[0] == 0:
        raise ValueError("track_sparse_depth: no corner with valid depth")
    life = _track_lifetimes(greys, pts, fb_tolerance)
    order = np.lexsort((np.arange(life.size), -life))   # longest-lived, then strongest
    sel = px[order[:int(n_points)]]
    return _with_noise(np.unique(sel[:, 1] * w + sel[:, 0]), depth, rel_noise, seed)


def _track_lifetimes(greys: Sequence[np.ndarray], pts: np.ndarray, fb_tolerance: float
                     ) -> np.ndarray:
    """(N,) number of frames of ``greys[1:]`` each point of ``pts`` (N, 2) of
    ``greys[0]`` is tracked through (forward-backward checked LK)."""
    lk = dict(winSize=(21, 21), maxLevel=3,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    h, w = greys[0].shape
    life = np.zeros(pts.shape[0], np.int64)
    alive = np.ones(pts.shape[0], bool)
    cur = pts.astype(np.float32).reshape(-1, 1, 2)
    for prev, nxt in zip(greys[:-1], greys[1:]):
        fwd, st, _ = cv2.calcOpticalFlowPyrLK(prev, nxt, cur, None, **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(nxt, prev, fwd, None, **lk)
        p = fwd.reshape(-1, 2)
        good = (st.ravel() == 1) & (st2.ravel() == 1) & \
            (np.linalg.norm((back - cur).reshape(-1, 2), axis=1) <= fb_tolerance) & \
            (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
        alive &= good
        life += alive
        cur = fwd
    return life
