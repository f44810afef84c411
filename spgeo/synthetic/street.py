"""A synthetic street for forward driving at a low frame rate (a KITTI-like
failure case of monocular initialisation, issue 30 "Driving").

A road runs through a :class:`~spgeo.synthetic.scene.SyntheticScene` yard
(:data:`STREET_SIZE`: 300 x 300 m, 60 m high) whose floor (the road) and ceiling
(the sky) are painted a flat, textureless grey: the only texture is on the
walls of the yard (far structure, 50-250 m away, up to 20 degrees above the
horizon) and on sparse boxes along both kerbs (parked cars, 4-5 m from the
centre line, one every 14-35 m).  So the near ground is textureless and the
median depth is tens of metres while the camera moves about 1 m per frame:
``|t| / median depth`` stays below 0.08 for several frames, and tracking
against keyframe 0's unscaled primitives loses those frames
(``tests/test_vo_drive.py``).

World frame as in :mod:`spgeo.synthetic` (metres, z up); the road starts 100 m
south of the yard's centre heading north (+y) and curves to the right
(:func:`street_drive`), the camera 1.65 m above it.  The camera
(:func:`street_camera`) has KITTI's proportions: fx / width = 0.58 (an
81-degree horizontal field of view) and width / height = 3.3.
"""
from __future__ import annotations

from typing import List, Tuple

import numpy as np

from ..camera import PinholeCamera
from .config import SceneConfig, TextureConfig
from .objects import BoxSpec
from .poses import camera_rotation
from .scene import SyntheticScene

__all__ = ["STREET_SIZE", "street_scene", "street_camera", "street_drive"]

#: ``(width, length, height)`` of the square yard the road runs through (metres).
STREET_SIZE: Tuple[float, float, float] = (300.0, 300.0, 60.0)
#: where the drive starts (world, metres): 100 m south of the centre, heading north (+y)
_START = (0.0, -100.0, 1.65)


def _road(turn_deg: float, length: float = 210.0, ds: float = 0.05
          ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The road's centre line from :data:`_START`: ``(s, xy, yaw)`` sampled every
    ``ds`` metres of arc ``s`` up to ``length``; a right-hand curve turning
    ``turn_deg`` degrees per metre for 20 m, the rate then falling linearly to
    an eighth of it by 45 m (``xy`` (n, 2) metres, ``yaw`` radians, 90 degrees:
    heading +y)."""
    s = np.arange(0.0, length + ds / 2, ds)
    rate = np.radians(turn_deg) * np.interp(s, [20.0, 45.0], [1.0, 0.125])
    yaw = np.pi / 2 - np.r_[0.0, np.cumsum(0.5 * (rate[1:] + rate[:-1]) * ds)]
    heading = np.stack([np.cos(yaw), np.sin(yaw)], 1)
    xy = np.asarray(_START[:2]) + np.r_[np.zeros((1, 2)),
                                        np.cumsum(0.5 * (heading[1:] + heading[:-1]) * ds, 0)]
    return s, xy, yaw


def _kerb_boxes(turn_deg: float, rng: np.random.Generator) -> List[BoxSpec]:
    """Parked cars along both kerbs of :func:`_road`: one box every 14-35 m on
    each side, 4-5 m to the side of the centre line, aligned with it (metres)."""
    arc, line, yaw = _road(turn_deg)
    boxes = []
    for side in (-1.0, 1.0):
        s = rng.uniform(2.0, 8.0)
        while s < arc[-1]:
            i = min(int(np.searchsorted(arc, s)), len(arc) - 1)
            normal = np.array([np.sin(yaw[i]), -np.cos(yaw[i])])  # right of the heading
            length, width, height = rng.uniform(3.8, 4.8), rng.uniform(1.7, 2.0), rng.uniform(1.4, 1.9)
            xy = line[i] + side * rng.uniform(4.0, 5.0) * normal
            boxes.append(BoxSpec((float(xy[0]), float(xy[1]), height / 2), (width, length, height),
                                 float(yaw[i]) - np.pi / 2))   # box length along the road
            s += length + rng.uniform(10.0, 30.0)
    return boxes


def street_scene(seed: int = 0, turn_deg: float = 2.5, grey: float = 0.45) -> SyntheticScene:
    """The street (module docstring) along the road of :func:`street_drive`
    with the same ``turn_deg``, deterministic in ``seed`` (kerb boxes,
    textures); the ground (road) and the sky have the constant albedo ``grey``
    (in [0, 1])."""
    texture = TextureConfig(max_wavelength=24.0, min_wavelength=1.5, pattern_period=(1.5, 6.0))
    config = SceneConfig(room_size=STREET_SIZE, free_zone_radius=4.0, n_boxes=0, n_cylinders=0,
                         n_spheres=0, n_panels=0, texture=texture)
    scene = SyntheticScene.build(_kerb_boxes(turn_deg, np.random.default_rng([int(seed), 7])),
                                 config, seed)
    scene.paint_flat((0, 1), grey)   # floor (road) and ceiling (sky)
    return scene


def street_camera(width: int = 504) -> PinholeCamera:
    """KITTI-like intrinsics at ``width`` pixels (height ``width / 3.3``, fx = fy
    = 0.58 ``width``, principal point at the centre); 504 is the VO's default
    processing width for KITTI's 1241x376 images."""
    height = int(round(width / 3.3))
    f = 0.58 * width
    return PinholeCamera(f, f, (width - 1) / 2, (height - 1) / 2, int(width), height)


def street_drive(n_frames: int, step: float = 1.0, turn_deg: float = 2.5,
                 seed: int = 0) -> np.ndarray:
    """(n, 4, 4) camera-to-world poses of a drive like the KITTI clip's along
    the road of :func:`street_scene`: ``step`` metres per frame (1.0: 36 km/h
    at 10 Hz) on a right-hand curve turning ``turn_deg`` degrees per metre for
    20 m, the rate then falling linearly to an eighth of it by 45 m; the camera
    1.65 m up, looking along the road, pitched 1 degree down, with a pitch/roll
    bounce of 0.3 degrees (phases drawn from ``seed``).  Raises ``ValueError``
    for ``n_frames < 1``, ``step <= 0`` or a drive longer than 150 m."""
    n = int(n_frames)
    if n < 1 or not step > 0 or (n - 1) * step > 150.0:
        raise ValueError(f"street_drive: {n_frames} frames of {step} m (at most 150 m)")
    arc, line, road_yaw = _road(turn_deg)
    sk = np.arange(n) * float(step)
    x, y, yaw = (np.interp(sk, arc, v) for v in (line[:, 0], line[:, 1], road_yaw))
    ph_p, ph_r = np.random.default_rng([int(seed), 8]).uniform(0, 2 * np.pi, 2)
    bounce = np.radians(0.3)
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        poses[i, :3, :3] = camera_rotation(yaw[i], np.radians(-1.0) + bounce * np.sin(0.9 * i + ph_p),
                                           bounce * np.sin(1.3 * i + ph_r))
        poses[i, :3, 3] = (x[i], y[i], _START[2])
    return poses
