"""Tessellation of the room and its objects into triangles tagged by surface id.

The mesh only tells the ray caster *which* surface a ray hits; distances and
normals are recomputed from the analytic surfaces (:mod:`.scene`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Sequence, Tuple

import numpy as np

from .config import SceneConfig
from .objects import BoxSpec, CylinderSpec, ObjectSpec, PanelSpec, SphereSpec, Surface, SurfaceKind

__all__ = ["SceneMesh", "tessellate"]


def _quad(c0, c1, c2, c3) -> Tuple[np.ndarray, np.ndarray]:
    return np.array([c0, c1, c2, c3], float), np.array([[0, 1, 2], [0, 2, 3]])


def _segments(radius: float, max_err: float, arc: float) -> int:
    """Segments for an arc so that a quad's diagonal sags less than ``max_err``."""
    step = math.sqrt(4.0 * max_err / max(radius, 1e-9))
    return max(8, int(math.ceil(arc / step)))


def _sphere_mesh(center, radius: float, max_err: float) -> Tuple[np.ndarray, np.ndarray]:
    n_lat = _segments(radius, max_err, np.pi)
    n_lon = 2 * n_lat
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.arange(n_lon) * 2 * np.pi / n_lon
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) * radius + np.asarray(center, float)
    j = np.arange(n_lon)
    jn = (j + 1) % n_lon
    tris = [np.stack([np.zeros(n_lon, int), 1 + j, 1 + jn], 1)]
    i = np.arange(n_lat - 2)[:, None]
    a = 1 + i * n_lon + j
    b = 1 + i * n_lon + jn
    c = 1 + (i + 1) * n_lon + j
    d = 1 + (i + 1) * n_lon + jn
    tris.append(np.stack([a, c, d], -1).reshape(-1, 3))
    tris.append(np.stack([a, d, b], -1).reshape(-1, 3))
    last = len(verts) - 1
    base = 1 + (n_lat - 2) * n_lon
    tris.append(np.stack([np.full(n_lon, last), base + jn, base + j], 1))
    return verts, np.concatenate(tris)


@dataclass
class SceneMesh:
    """Surfaces and their triangles.

    Attributes:
        surfaces: one :class:`Surface` per id.
        vertices: (V, 3) float32 world points.
        triangles: (T, 3) uint32 vertex indices.
        tri_surface: (T,) int32 surface id of each triangle.
    """

    surfaces: List[Surface]
    vertices: np.ndarray
    triangles: np.ndarray
    tri_surface: np.ndarray


class _MeshBuilder:
    """Surfaces and triangle soup collected while tessellating, in order."""

    def __init__(self) -> None:
        self.surfaces: List[Surface] = []
        self.verts: List[np.ndarray] = []
        self.tris: List[np.ndarray] = []
        self.tri_sid: List[np.ndarray] = []
        self.n_verts = 0

    def add(self, v: np.ndarray, t: np.ndarray, sid: int) -> None:
        self.verts.append(v)
        self.tris.append(t + self.n_verts)
        self.tri_sid.append(np.full(len(t), sid, np.int32))
        self.n_verts += len(v)

    def new_surface(self, kind, name, obj, point, axis, radius=0.0) -> int:
        sid = len(self.surfaces)
        self.surfaces.append(Surface(sid, SurfaceKind(kind), name, obj,
                                     tuple(float(x) for x in point),
                                     tuple(float(x) for x in axis), float(radius)))
        return sid

    def mesh(self) -> SceneMesh:
        return SceneMesh(self.surfaces, np.concatenate(self.verts).astype(np.float32),
                         np.concatenate(self.tris).astype(np.uint32), np.concatenate(self.tri_sid))


def _add_room(mesh: _MeshBuilder, config: SceneConfig) -> None:
    """Floor, ceiling and 4 walls (surface ids 0..5), overlapping by ``room_overlap``."""
    X, Y, Z = (float(s) for s in config.room_size)
    hx, hy, m = X / 2, Y / 2, float(config.room_overlap)
    room = [  # name, point, inward normal, 4 corners
        ("floor", (0, 0, 0), (0, 0, 1),
         [(-hx - m, -hy - m, 0), (hx + m, -hy - m, 0), (hx + m, hy + m, 0), (-hx - m, hy + m, 0)]),
        ("ceiling", (0, 0, Z), (0, 0, -1),
         [(-hx - m, -hy - m, Z), (hx + m, -hy - m, Z), (hx + m, hy + m, Z), (-hx - m, hy + m, Z)]),
        ("wall-x", (-hx, 0, 0), (1, 0, 0),
         [(-hx, -hy - m, -m), (-hx, hy + m, -m), (-hx, hy + m, Z + m), (-hx, -hy - m, Z + m)]),
        ("wall+x", (hx, 0, 0), (-1, 0, 0),
         [(hx, -hy - m, -m), (hx, hy + m, -m), (hx, hy + m, Z + m), (hx, -hy - m, Z + m)]),
        ("wall-y", (0, -hy, 0), (0, 1, 0),
         [(-hx - m, -hy, -m), (hx + m, -hy, -m), (hx + m, -hy, Z + m), (-hx - m, -hy, Z + m)]),
        ("wall+y", (0, hy, 0), (0, -1, 0),
         [(-hx - m, hy, -m), (hx + m, hy, -m), (hx + m, hy, Z + m), (-hx - m, hy, Z + m)]),
    ]
    for name, point, normal, corners in room:
        sid = mesh.new_surface(SurfaceKind.PLANE, name, -1, point, normal)
        mesh.add(*_quad(*corners), sid)


def _add_box(mesh: _MeshBuilder, obj: BoxSpec, name: str, oi: int) -> None:
    c = np.asarray(obj.center, float)
    half = np.asarray(obj.size, float) / 2
    cy, sy = math.cos(obj.yaw), math.sin(obj.yaw)
    R = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = R[:, axis] * sign
            a1, a2 = [k for k in range(3) if k != axis]
            e1, e2 = R[:, a1] * half[a1], R[:, a2] * half[a2]
            fc = c + n * half[axis]
            sid = mesh.new_surface(SurfaceKind.PLANE, f"{name}/{'+' if sign > 0 else '-'}"
                                   f"{'xyz'[axis]}", oi, fc, n)
            mesh.add(*_quad(fc - e1 - e2, fc + e1 - e2, fc + e1 + e2, fc - e1 + e2), sid)


def _add_cylinder(mesh: _MeshBuilder, obj: CylinderSpec, name: str, oi: int, err: float) -> None:
    b = np.asarray(obj.base_center, float)
    r, h = float(obj.radius), float(obj.height)
    top = b + np.array([0, 0, h])
    nseg = _segments(r, err, 2 * np.pi)
    ang = np.arange(nseg) * 2 * np.pi / nseg
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(nseg)], 1) * r
    j = np.arange(nseg)
    jn = (j + 1) % nseg
    sid = mesh.new_surface(SurfaceKind.CYLINDER, f"{name}/side", oi, b, (0, 0, 1), r)
    v = np.concatenate([b + ring, top + ring])
    t = np.concatenate([np.stack([j, jn, nseg + jn], 1),
                        np.stack([j, nseg + jn, nseg + j], 1)])
    mesh.add(v, t, sid)
    for cap, centre, normal in (("top", top, (0, 0, 1)), ("bottom", b, (0, 0, -1))):
        sid = mesh.new_surface(SurfaceKind.PLANE, f"{name}/{cap}", oi, centre, normal)
        v = np.concatenate([centre[None], centre + ring])
        mesh.add(v, np.stack([np.zeros(nseg, int), 1 + j, 1 + jn], 1), sid)


def _add_panel(mesh: _MeshBuilder, obj: PanelSpec, name: str, oi: int) -> None:
    c = np.asarray(obj.center, float)
    n = np.asarray(obj.normal, float)
    n = n / np.linalg.norm(n)
    u = np.cross([0.0, 0.0, 1.0], n)
    u = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(u) < 1e-9 else u / np.linalg.norm(u)
    v = np.cross(n, u)
    cs, ss = math.cos(obj.spin), math.sin(obj.spin)
    u, v = cs * u + ss * v, -ss * u + cs * v
    e1, e2 = u * obj.size[0] / 2, v * obj.size[1] / 2
    sid = mesh.new_surface(SurfaceKind.PLANE, name, oi, c, n)
    mesh.add(*_quad(c - e1 - e2, c + e1 - e2, c + e1 + e2, c - e1 + e2), sid)


def tessellate(config: SceneConfig, objects: Sequence[ObjectSpec]) -> SceneMesh:
    """Room (floor, ceiling, 4 walls: ids 0..5) then every object's surfaces, in order.

    Raises ``TypeError`` for an unsupported object.
    """
    mesh = _MeshBuilder()
    _add_room(mesh, config)
    err = float(config.max_chord_error)
    counters: Dict[str, int] = {}
    for oi, obj in enumerate(objects):
        label = type(obj).__name__.replace("Spec", "").lower()
        name = f"{label}{counters.get(label, 0)}"
        counters[label] = counters.get(label, 0) + 1
        if isinstance(obj, BoxSpec):
            _add_box(mesh, obj, name, oi)
        elif isinstance(obj, CylinderSpec):
            _add_cylinder(mesh, obj, name, oi, err)
        elif isinstance(obj, SphereSpec):
            sid = mesh.new_surface(SurfaceKind.SPHERE, name, oi, obj.center, (0, 0, 0), obj.radius)
            mesh.add(*_sphere_mesh(obj.center, float(obj.radius), err), sid)
        elif isinstance(obj, PanelSpec):
            _add_panel(mesh, obj, name, oi)
        else:
            raise TypeError(f"unsupported scene object {obj!r}")
    return mesh.mesh()
