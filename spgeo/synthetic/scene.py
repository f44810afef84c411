"""The ray-castable procedural room: exact depth, normals, surface ids and shaded colour.

Rendering uses open3d's Embree-backed :class:`open3d.t.geometry.RaycastingScene`
only to find *which* surface a ray hits; the hit distance and the normal are
then recomputed in float64 from the analytic surface (plane, sphere or
cylinder), so depth and normals are exact (up to float32 storage), not those of
the tessellation.  Shading is Lambertian with a fixed directional light and an
ambient term (view-independent).
"""
from __future__ import annotations

import logging
from typing import Dict, List, Sequence, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..geometry import check_pose
from .config import SceneConfig
from .mesh import tessellate
from .objects import ObjectSpec, RenderedView, Surface, SurfaceKind, sample_objects
from .texture import FlatTexture, make_texture

__all__ = ["SyntheticScene"]

logger = logging.getLogger(__name__)


class SyntheticScene:
    """A ray-castable procedural room.  Build with :meth:`generate` (random,
    deterministic by seed) or :meth:`build` (explicit objects)."""

    def __init__(self, config: SceneConfig, seed: int, objects: Sequence[ObjectSpec]) -> None:
        import open3d as o3d

        X, Y, Z = (float(s) for s in config.room_size)
        if min(X, Y, Z) <= 0 or 2 * config.free_zone_radius >= min(X, Y):
            raise ValueError(f"SceneConfig: room_size {config.room_size} must be positive and "
                             f"wider than the free zone (radius {config.free_zone_radius})")
        self.config = config
        self.seed = int(seed)
        self.objects: List[ObjectSpec] = list(objects)
        mesh = tessellate(config, self.objects)
        self.surfaces: List[Surface] = mesh.surfaces
        self._vertices = mesh.vertices
        self._triangles = mesh.triangles
        self._tri_surface = mesh.tri_surface
        self._kind = np.array([s.kind for s in self.surfaces], np.int8)
        self._point = np.array([s.point for s in self.surfaces], float)
        self._axis = np.array([s.axis for s in self.surfaces], float)
        self._radius = np.array([s.radius for s in self.surfaces], float)
        self._textures = [
            make_texture(np.random.default_rng([self.seed, 1, s.id]), config.texture,
                         np.asarray(s.axis) if s.kind == SurfaceKind.PLANE else None)
            for s in self.surfaces]
        light = np.asarray(config.light_direction, float)
        self._light = light / np.linalg.norm(light)
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(o3d.core.Tensor(self._vertices), o3d.core.Tensor(self._triangles))
        logger.debug("synthetic scene seed %d: %d objects, %d surfaces, %d triangles", self.seed,
                     len(self.objects), len(self.surfaces), len(self._triangles))

    # ------------------------------------------------------------ constructors
    @classmethod
    def build(cls, objects: Sequence[ObjectSpec] = (), config: SceneConfig = SceneConfig(),
              seed: int = 0) -> "SyntheticScene":
        """Room of ``config.room_size`` with exactly ``objects`` (``seed`` draws the textures)."""
        return cls(config, seed, objects)

    @classmethod
    def generate(cls, seed: int, config: SceneConfig = SceneConfig()) -> "SyntheticScene":
        """Random furnished room, deterministic in ``seed``.

        Objects are spread in azimuth around the room centre (stratified), at
        least ``free_zone_radius`` away from it (in plan), inside the walls and
        without overlapping each other (bounding circles in plan).
        """
        return cls(config, seed, sample_objects(np.random.default_rng([int(seed), 0]), config))

    def paint_flat(self, surface_ids, grey: float) -> None:
        """Give the surfaces ``surface_ids`` (ints) the constant albedo ``grey``
        (in [0, 1], all channels): textureless surfaces such as a road or a
        sky.  Shading still applies."""
        for s in surface_ids:
            self._textures[int(s)] = FlatTexture(grey)

    # ---------------------------------------------------------------- queries
    def surface_object(self, surface_ids: np.ndarray) -> np.ndarray:
        """Object index (-1 for the room or no hit) of every surface id."""
        lut = np.array([s.object_index for s in self.surfaces] + [-1], np.int32)
        ids = np.asarray(surface_ids)
        return lut[np.where(ids >= 0, ids, len(self.surfaces))]

    def albedo(self, points: np.ndarray, surface_ids: np.ndarray) -> np.ndarray:
        """(N, 3) float32 texture colour of world points (N, 3) on surfaces
        ``surface_ids`` (N,) (0 where the id is -1)."""
        points = np.asarray(points, float).reshape(-1, 3)
        sid = np.asarray(surface_ids).reshape(-1)
        out = np.zeros((len(sid), 3), np.float32)
        for s, idx in _group_by_surface(sid):
            out[idx] = self._textures[s].evaluate(points[idx])
        return out

    def cast_rays(self, origin: np.ndarray, directions: np.ndarray) -> Dict[str, np.ndarray]:
        """Trace rays from one ``origin`` (3,) along ``directions`` (N, 3) (world frame).

        Returns ``t`` (N,) with hit point ``origin + t * direction`` (analytic,
        float64; inf on a miss), ``surface_ids`` (N,) int32 (-1 on a miss),
        ``points`` (N, 3) (NaN on a miss) and ``normals`` (N, 3) exact unit world
        normals facing the ray origin (NaN on a miss).
        """
        d = np.asarray(directions, float).reshape(-1, 3)
        hit = self._trace(origin, d[:, 0], d[:, 1], d[:, 2], with_rgb=False)
        return {"t": hit["t"], "surface_ids": hit["surface_ids"],
                "points": np.stack(hit["points"], 1), "normals": np.stack(hit["normals"], 1)}

    def _trace(self, origin: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
               with_rgb: bool) -> Dict[str, object]:
        """Embree finds the surface; distance, normal (and colour) are analytic.

        Works on ray-direction components (structure of arrays), vectorised with
        per-surface lookup tables; only the texture loops over the surfaces
        present (contiguous slices after a sort by id).  Returns ``t``,
        ``surface_ids``, ``points`` and ``normals`` (tuples of 3 arrays) and,
        with ``with_rgb``, ``rgb`` (N, 3) float32.
        """
        import open3d as o3d

        o = np.asarray(origin, float).reshape(3)
        n = len(dx)
        n_surf = len(self.surfaces)
        rays = np.empty((n, 6), np.float32)
        rays[:, :3] = o
        rays[:, 3], rays[:, 4], rays[:, 5] = dx, dy, dz
        ans = self._rc.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t_mesh = ans["t_hit"].numpy().astype(float)
        prim = ans["primitive_ids"].numpy()
        hit = np.isfinite(t_mesh)
        all_hit = bool(hit.all())
        if all_hit:
            sid = self._tri_surface[prim]
        else:
            sid = np.where(hit, self._tri_surface[np.where(hit, prim, 0)], -1).astype(np.int32)
        safe = sid if all_hit else np.where(hit, sid, n_surf)  # row n_surf: 'no surface'

        # per-surface tables for this origin (last row: no surface)
        w = o - self._point
        side = np.einsum("ij,ij->i", w, self._axis)
        on = self._axis * np.where(side >= 0, 1.0, -1.0)[:, None]  # plane normals facing o
        planar = self._kind == SurfaceKind.PLANE
        on[~planar] = 0.0
        on = np.vstack([on, np.full((1, 3), np.nan)])
        num = np.append(np.where(planar, -np.abs(side), 0.0), np.nan)  # t = num / (d . on)

        nx, ny, nz = on[:, 0][safe], on[:, 1][safe], on[:, 2][safe]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num[safe] / (dx * nx + dy * ny + dz * nz)
            curved = np.flatnonzero(np.append(~planar, False)[safe])
            if curved.size:
                tc, radial = self._curved_hits(o, w, sid[curved], dx[curved], dy[curved],
                                               dz[curved], t_mesh[curved])
                t[curved] = tc
                nx[curved], ny[curved], nz[curved] = radial.T
            # trust the analytic distance unless it is far from the mesh hit
            ok = np.isfinite(t) & (t > 0) & (np.abs(t - t_mesh) <= 0.05 + 0.02 * t_mesh)
        if not all_hit or not ok.all():
            t = np.where(ok, t, t_mesh)
        t_pts = t if all_hit else np.where(hit, t, np.nan)
        points = (o[0] + t_pts * dx, o[1] + t_pts * dy, o[2] + t_pts * dz)
        out: Dict[str, object] = {"t": t, "surface_ids": sid, "points": points,
                                  "normals": (nx, ny, nz)}
        if with_rgb:
            out["rgb"] = self._colour(safe, points, (nx, ny, nz))
        return out

    def _curved_hits(self, o: np.ndarray, w: np.ndarray, sc: np.ndarray, dxc: np.ndarray,
                     dyc: np.ndarray, dzc: np.ndarray, tm: np.ndarray):
        """Analytic ``(t, unit normals facing the rays)`` of rays hitting cylinders and
        spheres (surface ids ``sc``, mesh distances ``tm``, kept where the analytic one is
        far from them); ``w``: the origin ``o`` minus each surface's point."""
        dc = np.stack([dxc, dyc, dzc], 1)
        ax = self._axis[sc]  # zeros for spheres: the projection below is a no-op
        wc = w[sc]
        dp = dc - np.einsum("ij,ij->i", dc, ax)[:, None] * ax
        wp = wc - np.einsum("ij,ij->i", wc, ax)[:, None] * ax
        qa = np.einsum("ij,ij->i", dp, dp)
        qb = 2.0 * np.einsum("ij,ij->i", dp, wp)
        qc = np.einsum("ij,ij->i", wp, wp) - self._radius[sc] ** 2
        sq = np.sqrt(np.maximum(qb * qb - 4.0 * qa * qc, 0.0))
        t1 = (-qb - sq) / (2.0 * qa)
        tc = np.where(t1 > 1e-9, t1, (-qb + sq) / (2.0 * qa))
        ok = np.isfinite(tc) & (tc > 0) & (np.abs(tc - tm) <= 0.05 + 0.02 * tm)
        tc = np.where(ok, tc, tm)
        radial = o + tc[:, None] * dc - self._point[sc]
        radial -= np.einsum("ij,ij->i", radial, ax)[:, None] * ax
        radial /= np.linalg.norm(radial, axis=1, keepdims=True)
        radial[np.einsum("ij,ij->i", radial, dc) > 0] *= -1.0
        return tc, radial

    def _colour(self, safe: np.ndarray, points: Tuple[np.ndarray, ...],
                normals: Tuple[np.ndarray, ...]) -> np.ndarray:
        """(N, 3) float32 shaded texture; ``safe`` = surface ids with misses as ``n_surf``."""
        n = len(safe)
        key = safe.astype(np.int16) if len(self.surfaces) < 32767 else safe
        order, sorted_ids, starts, ends = _runs(key)
        P = np.empty((3, n), np.float32)
        for c in range(3):
            P[c] = points[c][order]
        rgb_sorted = np.zeros((3, n), np.float32)
        for a, b in zip(starts, ends):
            s = int(sorted_ids[a])
            if s < len(self.surfaces):
                rgb_sorted[:, a:b] = self._textures[s].evaluate_rows(P[:, a:b])
        inverse = np.empty(n, np.intp)
        inverse[order] = np.arange(n)
        rgb = np.empty((n, 3), np.float32)
        if self.config.shading:
            L = self._light
            nx, ny, nz = normals
            with np.errstate(invalid="ignore"):
                lam = np.maximum(nx * L[0] + ny * L[1] + nz * L[2], 0.0)
            lam = np.nan_to_num(self.config.ambient + self.config.diffuse * lam).astype(np.float32)
            for c in range(3):
                rgb[:, c] = rgb_sorted[c][inverse] * lam
        else:
            for c in range(3):
                rgb[:, c] = rgb_sorted[c][inverse]
        return np.clip(rgb, 0.0, 1.0, out=rgb)

    # -------------------------------------------------------------- rendering
    @staticmethod
    def _world_rays(camera: PinholeCamera, R: np.ndarray,
                    shift: Tuple[float, float] = (0.0, 0.0)) -> Tuple[np.ndarray, ...]:
        """World components of the rays ``R K^-1 [u + du, v + dv, 1]`` (from ``camera.rays()``)."""
        r = camera.rays().reshape(-1, 3)
        rx = r[:, 0] + shift[0] / camera.fx
        ry = r[:, 1] + shift[1] / camera.fy
        rz = r[:, 2]
        return tuple(R[i, 0] * rx + R[i, 1] * ry + R[i, 2] * rz for i in range(3))

    def render(self, camera: PinholeCamera, T_world_cam: np.ndarray,
               supersample: int = 1) -> RenderedView:
        """Render rgb, depth, camera-frame normals and surface ids.

        Rays are ``R K^-1 [u, v, 1]`` (``camera.rays()``, z = 1 in the camera, so
        the ray parameter of a hit is its depth), pixel centres at integers.
        ``supersample = k > 1`` averages ``k x k`` sub-pixel rays for ``rgb`` only
        (depth, normals and ids always come from the pixel-centre ray).
        Distortion in ``camera`` is ignored (an undistorted image is rendered).
        """
        T = check_pose(T_world_cam, "T_world_cam")
        k = int(supersample)
        if k < 1:
            raise ValueError(f"render: supersample must be >= 1, got {supersample}")
        R, o = T[:3, :3], T[:3, 3]
        h, w = camera.shape
        hit = self._trace(o, *self._world_rays(camera, R), with_rgb=k == 1)
        valid = hit["surface_ids"] >= 0
        depth = np.where(valid, hit["t"], np.nan)
        nx, ny, nz = hit["normals"]
        normals = np.empty((h * w, 3), np.float32)
        for i in range(3):  # camera frame: R^T n
            normals[:, i] = R[0, i] * nx + R[1, i] * ny + R[2, i] * nz
        if k == 1:
            rgb = hit["rgb"]
        else:
            off = (np.arange(k) + 0.5) / k - 0.5
            rgb = np.zeros((h * w, 3), np.float32)
            for du in off:
                for dv in off:
                    rgb += self._trace(o, *self._world_rays(camera, R, (du, dv)),
                                       with_rgb=True)["rgb"]
            rgb /= k * k
        return RenderedView(
            rgb=rgb.reshape(h, w, 3),
            depth=depth.reshape(h, w).astype(np.float32),
            normals=normals.reshape(h, w, 3),
            surface_ids=hit["surface_ids"].reshape(h, w).astype(np.int32, copy=False),
            camera=camera, T_world_cam=T.copy())

    def render_depth(self, camera: PinholeCamera, T_world_cam: np.ndarray) -> np.ndarray:
        """float32 (H, W) depth only (no texturing), NaN where nothing was hit."""
        T = check_pose(T_world_cam, "T_world_cam")
        hit = self._trace(T[:3, 3], *self._world_rays(camera, T[:3, :3]), with_rgb=False)
        depth = np.where(hit["surface_ids"] >= 0, hit["t"], np.nan)
        return depth.reshape(camera.shape).astype(np.float32)


def _group_by_surface(sid: np.ndarray):
    """Yield ``(surface_id, indices)`` for every id >= 0 present in ``sid`` (no per-pixel loop)."""
    if sid.size == 0:
        return
    key = sid.astype(np.int16) if sid.max(initial=-1) < 32767 else sid
    order, sorted_ids, starts, ends = _runs(key)
    for a, b in zip(starts, ends):
        s = int(sorted_ids[a])
        if s >= 0:
            yield s, order[a:b]

def _runs(key: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stable sort of ``key`` into runs of equal values: ``(order, sorted keys, starts, ends)``."""
    order = np.argsort(key, kind="stable")
    sorted_ids = key[order]
    starts = np.concatenate([[0], np.flatnonzero(np.diff(sorted_ids)) + 1])
    ends = np.append(starts[1:], len(sorted_ids))
    return order, sorted_ids, starts, ends
