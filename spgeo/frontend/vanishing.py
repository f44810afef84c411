"""Vanishing directions from line segments with known intrinsics.

Each segment ``(p1, p2)`` defines its *interpretation plane* through the camera
centre, with unit normal ``l = normalize(K^-1 p1~ x K^-1 p2~)`` (a great circle
on the Gaussian sphere).  A 3-D direction ``d`` (camera frame) is the vanishing
direction of the segment when ``d`` lies in that plane; consistency is
measured in the image, as the angle between the segment and the line from its
midpoint to the vanishing point ``K d`` (which works for points at infinity).

:func:`estimate_vanishing_directions`:

1. free directions: RANSAC over pairs of segments (``d = l_i x l_j``, score =
   total length of the consistent segments), one after the other on the
   segments not yet explained;
2. a Manhattan frame: RANSAC over three segments (``d1 = l_a x l_b``,
   ``d2 = l_c x d1``, ``d3 = d1 x d2``) scored by the length consistent with
   any axis, each axis refined on its inliers, then the closest rotation.  It
   is kept when at least two axes have enough support and it explains nearly
   as much as the first three free directions (``manhattan_min_ratio``);
3. with a frame: further, non-orthogonal directions from free RANSAC on the
   segments the frame does not explain; without: the free directions of 1.

Fewer than 2 supported directions is a valid outcome (e.g. no lines: none).
Deterministic for a given ``seed``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from ..geometry import nearest_rotation
from .lines import LineSegments

__all__ = ["VanishingConfig", "VanishingResult", "estimate_vanishing_directions",
           "interpretation_normals", "segment_consistency"]

logger = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class VanishingConfig:
    """Options of :func:`estimate_vanishing_directions`.

    Attributes:
        inlier_angle_deg: a segment is consistent with a direction when the
            image angle between the segment and the line from its midpoint to
            the vanishing point is below this (degrees).
        n_hypotheses: RANSAC hypotheses per search.
        min_support_segments: a direction needs at least this many consistent
            segments.
        min_support_frac: ... and at least this fraction of the total segment
            length.
        max_directions: at most this many directions.
        manhattan: try to complete the dominant direction to an orthogonal
            frame.
        manhattan_min_ratio: the Manhattan frame is kept only when its axes
            explain at least this fraction of the segment length that the
            first three free directions explain.
        min_separation_deg: a new direction must be at least this far (degrees,
            either sign) from every earlier one.
        seed: seed of the random sampling.
    """

    inlier_angle_deg: float = 2.0
    n_hypotheses: int = 400
    min_support_segments: int = 4
    min_support_frac: float = 0.05
    max_directions: int = 4
    manhattan: bool = True
    manhattan_min_ratio: float = 0.9
    min_separation_deg: float = 15.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.inlier_angle_deg < 45.0:
            raise ValueError(f"VanishingConfig: inlier_angle_deg must be in (0, 45), "
                             f"got {self.inlier_angle_deg}")
        if self.n_hypotheses < 1 or self.min_support_segments < 2:
            raise ValueError("VanishingConfig: n_hypotheses must be >= 1 and "
                             "min_support_segments >= 2")
        if self.max_directions < 0:
            raise ValueError(f"VanishingConfig: max_directions must be >= 0, "
                             f"got {self.max_directions}")


@dataclass
class VanishingResult:
    """Vanishing directions of one image.

    Attributes:
        directions: (k, 3) unit directions in the camera frame (sign arbitrary),
            k >= 0.
        support: (k,) total length (pixels) of the segments assigned to each.
        assignment: (N,) int direction index of every segment, -1 for none.
        manhattan: True when ``directions[:3]`` is an orthonormal frame.
        line_normals: (N, 3) interpretation-plane normals of the segments.
    """

    directions: np.ndarray
    support: np.ndarray
    assignment: np.ndarray
    manhattan: bool
    line_normals: np.ndarray

    def __len__(self) -> int:
        return int(self.directions.shape[0])


def interpretation_normals(segments: LineSegments, camera: PinholeCamera) -> np.ndarray:
    """(N, 3) unit normals of the segments' interpretation planes (camera frame)."""
    e = segments.endpoints
    r1 = np.stack([(e[:, 0] - camera.cx) / camera.fx, (e[:, 1] - camera.cy) / camera.fy,
                   np.ones(len(e))], axis=1)
    r2 = np.stack([(e[:, 2] - camera.cx) / camera.fx, (e[:, 3] - camera.cy) / camera.fy,
                   np.ones(len(e))], axis=1)
    n = np.cross(r1, r2)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(norm > 0, norm, 1.0)


def segment_consistency(directions: np.ndarray, segments: LineSegments,
                        camera: PinholeCamera) -> np.ndarray:
    """(M, N) sine of the image angle between each segment and the line from its
    midpoint to the vanishing point of each direction ((M, 3), camera frame).
    1 where undefined (vanishing point on the midpoint)."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    # vanishing points in homogeneous pixels: K d
    vx = camera.fx * d[:, 0] + camera.cx * d[:, 2]
    vy = camera.fy * d[:, 1] + camera.cy * d[:, 2]
    vw = d[:, 2]
    e = segments.endpoints
    mu, mv = 0.5 * (e[:, 0] + e[:, 2]), 0.5 * (e[:, 1] + e[:, 3])
    su, sv = e[:, 2] - e[:, 0], e[:, 3] - e[:, 1]
    # direction midpoint -> vp (up to sign): v_xy - m * v_w
    tu = vx[:, None] - mu[None, :] * vw[:, None]
    tv = vy[:, None] - mv[None, :] * vw[:, None]
    cross = np.abs(tu * sv[None, :] - tv * su[None, :])
    denom = np.hypot(tu, tv) * np.hypot(su, sv)[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > 0, cross / np.where(denom > 0, denom, 1.0), 1.0)
    return s


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _refine(lines: np.ndarray, weights: np.ndarray, d0: np.ndarray) -> np.ndarray:
    """Direction minimising ``sum w (l . d)^2`` (smallest eigenvector), sign of ``d0``."""
    if lines.shape[0] < 2:
        return d0
    m = (lines * weights[:, None]).T @ lines
    _, vec = np.linalg.eigh(m)
    d = vec[:, 0]
    return d if d @ d0 >= 0 else -d


class _Search:
    """Shared state of one estimation: segments, their lengths, the inlier test."""

    def __init__(self, segments: LineSegments, camera: PinholeCamera, cfg: VanishingConfig):
        self.seg, self.cam, self.cfg = segments, camera, cfg
        self.lines = interpretation_normals(segments, camera)
        self.length = segments.lengths
        self.total = float(self.length.sum())
        self.thr = float(np.sin(np.radians(cfg.inlier_angle_deg)))
        self.rng = np.random.default_rng(cfg.seed)

    def inliers(self, dirs: np.ndarray, active: np.ndarray) -> np.ndarray:
        """(M, N) bool: segment consistent with each direction and still active."""
        return (segment_consistency(dirs, self.seg, self.cam) < self.thr) & active[None, :]

    def enough(self, inl: np.ndarray) -> bool:
        return (int(inl.sum()) >= self.cfg.min_support_segments
                and float(self.length[inl].sum()) >= self.cfg.min_support_frac * self.total)

    def pair_hypotheses(self, active: np.ndarray) -> np.ndarray:
        idx = np.flatnonzero(active)
        if idx.size < 2:
            return np.zeros((0, 3))
        p = self.length[idx] / self.length[idx].sum()
        m = self.cfg.n_hypotheses
        a = self.rng.choice(idx, size=m, p=p)
        b = self.rng.choice(idx, size=m, p=p)
        ok = a != b
        d = np.cross(self.lines[a[ok]], self.lines[b[ok]])
        good = np.linalg.norm(d, axis=1) > 1e-6
        return _unit(d[good])

    def best(self, dirs: np.ndarray, active: np.ndarray) -> Tuple[Optional[np.ndarray], float]:
        if dirs.shape[0] == 0:
            return None, 0.0
        score = self.inliers(dirs, active).astype(np.float64) @ self.length
        k = int(np.argmax(score))
        return dirs[k], float(score[k])

    def polish(self, d: np.ndarray, active: np.ndarray, rounds: int = 2) -> np.ndarray:
        for _ in range(rounds):
            inl = self.inliers(d[None], active)[0]
            d = _unit(_refine(self.lines[inl], self.length[inl], d))
        return d


def _separated(d: np.ndarray, existing: list, min_sep: float) -> bool:
    return all(abs(float(d @ e)) < np.cos(np.radians(min_sep)) for e in existing)


def _greedy(s: _Search, active: np.ndarray, existing: list, k: int) -> list:
    """Up to ``k`` directions found one after the other by pair RANSAC on the
    ``active`` segments, each removing its inliers; stops at the first one
    without enough support or too close to an earlier (or ``existing``) one."""
    active = active.copy()
    out: list = []
    while len(out) < k and active.sum() >= s.cfg.min_support_segments:
        d, _ = s.best(s.pair_hypotheses(active), active)
        if d is None or not s.enough(s.inliers(d[None], active)[0]):
            break
        d = s.polish(d, active)
        inl = s.inliers(d[None], active)[0]
        if not s.enough(inl) or not _separated(d, existing + out, s.cfg.min_separation_deg):
            break
        out.append(d)
        active &= ~inl
    return out


def _manhattan_ransac(s: _Search, active: np.ndarray) -> Optional[np.ndarray]:
    """Orthogonal frame (3, 3) from three-segment hypotheses: ``d1 = l_a x l_b``,
    ``d2 = l_c x d1``, ``d3 = d1 x d2``, scored by the total length of the
    segments consistent with any axis, then each axis refined on its inliers and the frame re-orthonormalised."""
    idx = np.flatnonzero(active)
    if idx.size < 3:
        return None
    p = s.length[idx] / s.length[idx].sum()
    m = s.cfg.n_hypotheses
    a, b, c = (s.rng.choice(idx, size=m, p=p) for _ in range(3))
    d1 = np.cross(s.lines[a], s.lines[b])
    d2 = np.cross(s.lines[c], d1)
    good = (a != b) & (np.linalg.norm(d1, axis=1) > 1e-6) & (np.linalg.norm(d2, axis=1) > 1e-6)
    if not good.any():
        return None
    d1, d2 = _unit(d1[good]), _unit(d2[good])
    d3 = _unit(np.cross(d1, d2))
    hit = np.zeros((d1.shape[0], active.size), dtype=bool)
    for d in (d1, d2, d3):
        hit |= s.inliers(d, active)
    k = int(np.argmax(hit.astype(np.float64) @ s.length))
    frame = np.stack([d1[k], d2[k], d3[k]])
    # refine each axis on its inliers, then back to the closest rotation
    for _ in range(2):
        rows = []
        for i in range(3):
            inl = s.inliers(frame[i][None], active)[0]
            rows.append(_refine(s.lines[inl], s.length[inl], frame[i]) if inl.sum() >= 2
                        else frame[i])
        frame = nearest_rotation(np.stack(rows).T).T
    return frame


def estimate_vanishing_directions(segments: LineSegments, camera: PinholeCamera,
                                  config: VanishingConfig = VanishingConfig()
                                  ) -> VanishingResult:
    """Vanishing directions of ``segments`` (found in an image matching ``camera``).

    See the module docstring for the method.  Never raises for lack of lines:
    the result then has ``k = 0`` directions.
    """
    if (segments.width, segments.height) != camera.size:
        raise ValueError(f"segments come from a {segments.width}x{segments.height} image, "
                         f"camera is {camera.width}x{camera.height}")
    cfg = config
    s = _Search(segments, camera, cfg)
    n = len(segments)
    manhattan = False
    everything = np.ones(n, dtype=bool)
    free = _greedy(s, everything, [], cfg.max_directions)
    dirs: list = []
    if cfg.manhattan and cfg.max_directions >= 3 and free:
        frame = _manhattan_ransac(s, everything)
        if frame is not None:
            inl = s.inliers(frame, everything)
            frame_sup = float(s.length[inl.any(axis=0)].sum())
            free_sup = float(s.length[s.inliers(np.array(free[:3]), everything).any(axis=0)].sum())
            if (sum(s.enough(i) for i in inl) >= 2
                    and frame_sup >= cfg.manhattan_min_ratio * free_sup):
                dirs = list(frame)
                manhattan = True
    active = everything & ~s.inliers(np.array(dirs).reshape(-1, 3), everything).any(axis=0)
    if not manhattan:
        dirs = free
    else:
        dirs += _greedy(s, active, dirs, cfg.max_directions - len(dirs))
    directions = np.array(dirs, dtype=np.float64).reshape(-1, 3)
    assignment = np.full(n, -1, dtype=np.int64)
    support = np.zeros(len(directions))
    if len(directions) and n:
        sines = segment_consistency(directions, segments, camera)
        best = np.argmin(sines, axis=0)
        ok = sines[best, np.arange(n)] < s.thr
        assignment[ok] = best[ok]
        support = np.bincount(assignment[ok], weights=s.length[ok], minlength=len(directions))
    logger.debug("vanishing directions: %d (manhattan=%s) from %d segments, %d assigned",
                 len(directions), manhattan, n, int((assignment >= 0).sum()))
    return VanishingResult(directions, support, assignment, manhattan, s.lines)
