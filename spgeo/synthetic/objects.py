"""Scene description types (surfaces, object specs, rendered views) and random object placement.

World frame: metres, z up; the room is ``[-X/2, X/2] x [-Y/2, Y/2] x [0, Z]``.
"""
from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass
from typing import List, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from .config import SceneConfig

__all__ = ["SurfaceKind", "Surface", "BoxSpec", "CylinderSpec", "SphereSpec", "PanelSpec",
           "ObjectSpec", "RenderedView", "sample_objects"]

logger = logging.getLogger(__name__)

ObjectSpec = Union["BoxSpec", "CylinderSpec", "SphereSpec", "PanelSpec"]


class SurfaceKind(enum.IntEnum):
    PLANE = 0
    SPHERE = 1
    CYLINDER = 2


@dataclass(frozen=True)
class Surface:
    """One smooth surface of the scene.

    Attributes:
        id: surface id (index into :attr:`SyntheticScene.surfaces`).
        kind: plane, sphere or cylinder.
        name: e.g. ``"wall+x"``, ``"box2/+z"``, ``"cylinder0/side"``.
        object_index: index into :attr:`SyntheticScene.objects`, -1 for the room.
        point: a point of the plane / the sphere centre / a point of the cylinder axis.
        axis: the plane normal (pointing out of the object, into the room for the
            room's walls) / unused (zeros) / the unit cylinder axis.
        radius: sphere or cylinder radius (0 for planes).
    """

    id: int
    kind: SurfaceKind
    name: str
    object_index: int
    point: Tuple[float, float, float]
    axis: Tuple[float, float, float]
    radius: float = 0.0


@dataclass(frozen=True)
class BoxSpec:
    """Box of full extents ``size`` (local x, y, z) centred at ``center``,
    rotated by ``yaw`` radians about the world z axis."""

    center: Tuple[float, float, float]
    size: Tuple[float, float, float]
    yaw: float = 0.0


@dataclass(frozen=True)
class CylinderSpec:
    """Vertical (world z) cylinder with the centre of its bottom cap at ``base_center``."""

    base_center: Tuple[float, float, float]
    radius: float
    height: float


@dataclass(frozen=True)
class SphereSpec:
    center: Tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class PanelSpec:
    """Thin two-sided rectangle (zero thickness) of ``size = (width, height)``.

    Its width axis is horizontal (``normalize(z x normal)``; world x for a
    horizontal panel), rotated in-plane by ``spin`` radians.
    """

    center: Tuple[float, float, float]
    normal: Tuple[float, float, float]
    size: Tuple[float, float]
    spin: float = 0.0


@dataclass
class RenderedView:
    """Output of :meth:`SyntheticScene.render`.

    Attributes:
        rgb: float32 (H, W, 3) in [0, 1] (0 where nothing was hit).
        depth: float32 (H, W) metres along the optical axis, NaN where nothing was hit.
        normals: float32 (H, W, 3) unit normals in the camera frame, oriented
            towards the camera (``n . ray < 0``); NaN where nothing was hit.
        surface_ids: int32 (H, W), -1 where nothing was hit.
        camera: the intrinsics rendered.
        T_world_cam: 4x4 camera-to-world pose rendered.
    """

    rgb: np.ndarray
    depth: np.ndarray
    normals: np.ndarray
    surface_ids: np.ndarray
    camera: PinholeCamera
    T_world_cam: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: a surface was hit."""
        return self.surface_ids >= 0


def sample_objects(rng: np.random.Generator, cfg: SceneConfig) -> List[ObjectSpec]:
    """Random, non-overlapping (in plan) objects around the free zone."""
    X, Y, Z = (float(s) for s in cfg.room_size)
    kinds = (["box"] * cfg.n_boxes + ["cylinder"] * cfg.n_cylinders + ["sphere"] * cfg.n_spheres
             + ["panel"] * cfg.n_panels)
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    n = len(kinds)
    sector = 2 * np.pi / max(n, 1)
    az0 = rng.uniform(0, 2 * np.pi)
    placed: List[Tuple[float, float, float]] = []  # (x, y, bounding radius)
    objects: List[ObjectSpec] = []
    r_room = min(X, Y) / 2 * math.sqrt(2)
    for i, kind in enumerate(kinds):
        for _ in range(max(1, cfg.placement_tries)):
            az = az0 + (i + rng.uniform(0.1, 0.9)) * sector
            direction = np.array([math.cos(az), math.sin(az)])
            br, make = _draw_object(rng, kind, cfg, Z)
            r_min = cfg.free_zone_radius + br
            dist = rng.uniform(r_min, r_room)
            xy = direction * dist
            inside = (abs(xy[0]) + br <= X / 2 - cfg.wall_margin
                      and abs(xy[1]) + br <= Y / 2 - cfg.wall_margin)
            free = all(math.hypot(xy[0] - px, xy[1] - py) >= br + pr + 0.05 for px, py, pr in placed)
            if inside and free:
                placed.append((float(xy[0]), float(xy[1]), br))
                objects.append(make((float(xy[0]), float(xy[1]))))
                break
        else:
            logger.debug("synthetic scene: could not place a %s, skipped", kind)
    return objects


def _draw_object(rng: np.random.Generator, kind: str, cfg: SceneConfig, Z: float):
    """Draw the size (and height, tilt...) of one object of ``kind``: ``(bounding radius
    in plan, make)`` where ``make((x, y))`` builds the object at that place."""
    if kind == "box":
        sx, sy = (float(v) for v in rng.uniform(*cfg.box_size, 2))
        floating = rng.uniform() < cfg.floating_box_prob
        if floating:
            sz = float(rng.uniform(0.2, 0.6))
            z0 = float(rng.uniform(0.6, max(0.6, min(1.8, Z - 0.1 - sz))))
        else:
            sz, z0 = float(rng.uniform(*cfg.box_height)), 0.0
        sz = min(sz, Z - z0 - 0.05)
        yaw = float(rng.uniform(0, np.pi))
        br = 0.5 * math.hypot(sx, sy)
        make = lambda xy, sx=sx, sy=sy, sz=sz, z0=z0, yaw=yaw: BoxSpec(  # noqa: E731
            (xy[0], xy[1], z0 + sz / 2), (sx, sy, sz), yaw)
        return br, make
    if kind == "cylinder":
        r = float(rng.uniform(*cfg.cylinder_radius))
        hgt = min(float(rng.uniform(*cfg.cylinder_height)), Z - 0.05)
        br = r
        make = lambda xy, r=r, hgt=hgt: CylinderSpec((xy[0], xy[1], 0.0), r, hgt)  # noqa: E731
        return br, make
    if kind == "sphere":
        r = float(rng.uniform(*cfg.sphere_radius))
        zc = (r if rng.uniform() < 0.5
              else float(rng.uniform(max(0.6, r + 0.05), min(2.2, Z - r - 0.05))))
        br = r
        make = lambda xy, r=r, zc=zc: SphereSpec((xy[0], xy[1], zc), r)  # noqa: E731
        return br, make
    # kind == "panel"
    pw, ph = (float(v) for v in rng.uniform(*cfg.panel_size, 2))
    tilt = np.radians(rng.uniform(*cfg.panel_tilt_deg)) * rng.choice([-1.0, 1.0])
    turn = np.radians(rng.uniform(-35, 35))
    zc = float(rng.uniform(0.7, 2.0))
    zc = float(np.clip(zc, ph / 2 + 0.05, Z - ph / 2 - 0.05))
    br = 0.5 * max(pw, ph)
    make = lambda xy, pw=pw, ph=ph, tilt=tilt, turn=turn, zc=zc: PanelSpec(  # noqa: E731
        (xy[0], xy[1], zc), _panel_normal(xy, turn, tilt), (pw, ph), 0.0)
    return br, make


def _panel_normal(xy, turn: float, tilt: float) -> Tuple[float, float, float]:
    """Normal facing the room centre (in plan), turned by ``turn`` and tilted by ``tilt``."""
    inward = -np.asarray(xy, float) / max(np.linalg.norm(xy), 1e-9)
    c, s = math.cos(turn), math.sin(turn)
    h = np.array([c * inward[0] - s * inward[1], s * inward[0] + c * inward[1], 0.0])
    n = math.cos(tilt) * h + np.array([0.0, 0.0, math.sin(tilt)])
    return tuple(float(x) for x in n / np.linalg.norm(n))

