"""Synthetic roads for driving at 10 Hz (issue 38 "On the road"): a long
straight street and a loop around a block, with exact ground truth.

Both are :class:`~spgeo.synthetic.scene.SyntheticScene` yards (world frame of
:mod:`spgeo.synthetic`: metres, z up) whose floor is a textured road, whose
ceiling, 60 m up, is a flat bright sky, and whose walls are the facades:

* :func:`straight_street`: a street canyon :data:`STRAIGHT_SIZE` (28 m between
  the facades, 760 m long) heading north (+y) with a gentle weave
  (:data:`WEAVE`).  A straight drive of 500 frames at 1.2 m per frame (43 km/h
  at 10 Hz) covers 600 m: the regime of a held-out KITTI drive (under 0.1
  degree of yaw per frame), where the points near the focus of expansion barely
  move while the near road moves tens of pixels.
* :func:`block_loop`: a 230 x 230 m yard around a 150 x 150 m block; the drive
  goes round the block anticlockwise (four straights of about 160 m, four
  90-degree corners of 14 m radius taken at 0.6 m per frame) with a stop of
  :data:`STOP_FRAMES` frames before the second corner, and ends where it
  started, so a loop can close.

Both have parked cars (boxes) along both kerbs and poles (cylinders) along the
pavements, deterministic in ``seed``.  :func:`road_drive` samples a drive along
a :class:`RoadPath` (``speeds`` metres per frame, 0 for a stop) with the camera
1.65 m above the road, looking along it, pitched 1 degree down, with a
pitch/roll bounce of 0.2 degree; the camera is :func:`street_camera`'s.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Tuple

import numpy as np

from .config import SceneConfig, TextureConfig
from .objects import BoxSpec, CylinderSpec
from .poses import camera_rotation
from .scene import SyntheticScene

__all__ = ["STRAIGHT_SIZE", "BLOCK_SIZE", "WEAVE", "STOP_FRAMES", "RoadPath", "RoadScene",
           "straight_street", "block_loop", "road_drive"]

#: ``(width, length, height)`` of the straight street's yard (metres).
STRAIGHT_SIZE: Tuple[float, float, float] = (28.0, 760.0, 60.0)
#: ``(width, length, height)`` of the block loop's yard and the block's side (metres).
BLOCK_SIZE: Tuple[float, float, float, float] = (230.0, 230.0, 60.0, 150.0)
#: ``(amplitude, wavelength)`` (metres) of the straight street's gentle weave: the
#: car keeps its lane within 0.5 m, turning at most 1.2 degrees from north (0.06
#: degree per frame at 1.2 m per frame), so the path is not one line (a Sim(3)
#: alignment of collinear positions is degenerate)
WEAVE: Tuple[float, float] = (0.5, 150.0)
#: frames the car stands still before the block loop's second corner
STOP_FRAMES = 12
_CAMERA_HEIGHT = 1.65
_TEXTURE = TextureConfig(max_wavelength=16.0, min_wavelength=0.5, pattern_period=(1.0, 5.0))


@dataclass(frozen=True)
class RoadPath:
    """A road's centre line sampled every few centimetres of arc: ``s`` (n,)
    metres of arc, ``xy`` (n, 2) world metres, ``yaw`` (n,) radians of the
    heading (0: +x, pi/2: +y)."""

    s: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray

    @classmethod
    def from_curvature(cls, start_xy, start_yaw: float, pieces: List[Tuple[float, float]],
                       ds: float = 0.05) -> "RoadPath":
        """Integrate ``pieces`` of ``(length m, curvature 1/m)`` (positive: left
        turns) from ``start_xy`` heading ``start_yaw``."""
        lengths = np.array([p[0] for p in pieces], float)
        s = np.r_[np.arange(0.0, lengths.sum() - ds / 2, ds), lengths.sum()]
        edges = np.r_[0.0, np.cumsum(lengths)]
        k = np.array([p[1] for p in pieces], float)[
            np.clip(np.searchsorted(edges, s, side="right") - 1, 0, len(pieces) - 1)]
        step = np.diff(s)
        yaw = start_yaw + np.r_[0.0, np.cumsum(0.5 * (k[1:] + k[:-1]) * step)]
        head = np.stack([np.cos(yaw), np.sin(yaw)], 1)
        moves = 0.5 * (head[1:] + head[:-1]) * step[:, None]
        xy = np.asarray(start_xy, float) + np.r_[np.zeros((1, 2)), np.cumsum(moves, 0)]
        return cls(s, xy, yaw)

    @classmethod
    def from_points(cls, xy: np.ndarray) -> "RoadPath":
        """The path through the dense points ``xy`` (n, 2) (arc by chords, yaw
        by central differences)."""
        xy = np.asarray(xy, float)
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
        d = np.gradient(xy, s, axis=0)
        return cls(s, xy, np.unwrap(np.arctan2(d[:, 1], d[:, 0])))

    def at(self, s: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """``(xy (m, 2), yaw (m,))`` at arcs ``s`` (linear interpolation)."""
        s = np.asarray(s, float)
        xy = np.stack([np.interp(s, self.s, self.xy[:, i]) for i in (0, 1)], 1)
        return xy, np.interp(s, self.s, self.yaw)


@dataclass
class RoadScene:
    """A synthetic road: the ray-castable ``scene``, its centre line ``path``
    and the drive's ``speeds`` (metres per frame for each frame step; 0: the car
    stands)."""

    scene: SyntheticScene
    path: RoadPath
    speeds: np.ndarray

    def drive(self, seed: int = 0) -> np.ndarray:
        """(n, 4, 4) camera-to-world poses of :func:`road_drive` along this road."""
        return road_drive(self.path, self.speeds, seed)


def _kerbside(path: RoadPath, rng: np.random.Generator) -> List:
    """Parked cars (boxes 4-5 m to each side of the centre line, one every
    12-35 m, aligned with the road) and poles (radius 0.12 m, 5-7 m high, 7 m
    to the side, one every 25-45 m) along ``path`` (metres)."""
    objects = []
    for side in (-1.0, 1.0):
        for offset, gap, make in ((4.5, (8.0, 30.0), "car"), (7.0, (25.0, 45.0), "pole")):
            s = rng.uniform(2.0, 12.0)
            while s < path.s[-1] - 5.0:
                (xy,), (yaw,) = path.at([s])
                right = np.array([np.sin(yaw), -np.cos(yaw)])
                if make == "car":
                    length, width, height = rng.uniform(3.8, 4.8), rng.uniform(1.7, 2.0), \
                        rng.uniform(1.4, 1.9)
                    c = xy + side * rng.uniform(offset - 0.5, offset + 0.5) * right
                    objects.append(BoxSpec((float(c[0]), float(c[1]), height / 2),
                                           (width, length, height), float(yaw) - np.pi / 2))
                    s += length
                else:
                    c = xy + side * offset * right
                    objects.append(CylinderSpec((float(c[0]), float(c[1]), 0.0), 0.12,
                                                float(rng.uniform(5.0, 7.0))))
                s += rng.uniform(*gap)
    return objects


def _yard(size, objects, seed: int, sky: float = 0.85) -> SyntheticScene:
    """A yard of ``size`` with ``objects``, the road textured, the sky flat."""
    config = SceneConfig(room_size=tuple(size[:3]), free_zone_radius=1.0, n_boxes=0,
                         n_cylinders=0, n_spheres=0, n_panels=0, texture=_TEXTURE)
    scene = SyntheticScene.build(objects, config, seed)
    scene.paint_flat((1,), sky)   # the ceiling: an open sky (no texture)
    return scene


def straight_street(n_frames: int = 500, step: float = 1.2, seed: int = 0) -> RoadScene:
    """The straight street (module docstring) with a drive of ``n_frames`` at
    ``step`` metres per frame from 20 m inside its south end.  Raises
    ``ValueError`` for a drive that does not fit (at most 700 m) or ``step <= 0``."""
    length = (int(n_frames) - 1) * float(step)
    if int(n_frames) < 2 or not step > 0 or length > 700.0:
        raise ValueError(f"straight_street: {n_frames} frames of {step} m (at most 700 m)")
    y = np.arange(-STRAIGHT_SIZE[1] / 2 + 20.0, STRAIGHT_SIZE[1] / 2 - 19.99, 0.05)
    weave = WEAVE[0] * np.sin(2 * np.pi * (y - y[0]) / WEAVE[1])
    path = RoadPath.from_points(np.stack([weave, y], 1))
    rng = np.random.default_rng([int(seed), 38])
    return RoadScene(_yard(STRAIGHT_SIZE, _kerbside(path, rng), seed), path,
                     np.full(int(n_frames) - 1, float(step)))


def block_loop(step: float = 1.2, corner_step: float = 0.6, seed: int = 0) -> RoadScene:
    """The loop around a block (module docstring): ``step`` metres per frame on
    the straights, ``corner_step`` in the corners (speed ramps over 10 m), a
    stop of :data:`STOP_FRAMES` frames 5 m before the second corner."""
    yard, block = BLOCK_SIZE[0], BLOCK_SIZE[3]
    centre = (yard + block) / 4          # the road's distance from the yard's centre
    radius = 14.0
    straight, quarter = 2 * (centre - radius), 0.5 * np.pi * radius
    pieces = [(straight / 2, 0.0)]       # from the middle of the east side, heading north
    for _ in range(4):
        pieces += [(quarter, 1.0 / radius), (straight, 0.0)]
    pieces[-1] = (straight / 2, 0.0)
    path = RoadPath.from_curvature((centre, 0.0), np.pi / 2, pieces)
    starts = straight / 2 + np.arange(4) * (quarter + straight)
    speeds, s, stopped = [], 0.0, False
    while s < path.s[-1] - step:
        near = np.min(np.abs(np.r_[starts, starts + quarter] - s))
        inside = np.any((s > starts) & (s < starts + quarter))
        v = corner_step if inside else float(np.interp(near, [0.0, 10.0], [corner_step, step]))
        if not stopped and s >= starts[1] - 5.0:
            speeds += [0.0] * STOP_FRAMES
            stopped = True
        speeds.append(v)
        s += v
    objects = [BoxSpec((0.0, 0.0, 12.0), (block, block, 24.0), 0.0)]
    rng = np.random.default_rng([int(seed), 39])
    return RoadScene(_yard(BLOCK_SIZE, objects + _kerbside(path, rng), seed), path,
                     np.asarray(speeds))


def road_drive(path: RoadPath, speeds: np.ndarray, seed: int = 0) -> np.ndarray:
    """(len(speeds) + 1, 4, 4) camera-to-world poses along ``path``: frame
    ``k + 1`` is ``speeds[k]`` metres of arc after frame ``k`` (0: the car
    stands; the camera then does not move), the camera :data:`_CAMERA_HEIGHT`
    up, looking along the road, pitched 1 degree down with a pitch/roll bounce
    of 0.2 degree (phases from ``seed``; frozen while the car stands)."""
    speeds = np.asarray(speeds, float)
    if speeds.ndim != 1 or np.any(speeds < 0) or speeds.sum() > path.s[-1]:
        raise ValueError("road_drive: speeds must be non-negative metres per frame within the road")
    arc = np.r_[0.0, np.cumsum(speeds)]
    xy, yaw = path.at(arc)
    moving = np.r_[0.0, np.cumsum(speeds > 0)]   # the bounce's clock stops with the car
    ph_p, ph_r = np.random.default_rng([int(seed), 8]).uniform(0, 2 * np.pi, 2)
    bounce = np.radians(0.2)
    poses = np.tile(np.eye(4), (len(arc), 1, 1))
    for i in range(len(arc)):
        poses[i, :3, :3] = camera_rotation(
            yaw[i], np.radians(-1.0) + bounce * np.sin(0.9 * moving[i] + ph_p),
            bounce * np.sin(1.3 * moving[i] + ph_r))
        poses[i, :3, 3] = (xy[i, 0], xy[i, 1], _CAMERA_HEIGHT)
    return poses
