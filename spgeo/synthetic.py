"""Procedural indoor scenes with exact ground truth, ray-cast on the CPU.

A scene is a closed room (floor, ceiling, four walls) furnished with boxes,
vertical cylinders, spheres and tilted panels.  Rendering uses open3d's
Embree-backed :class:`open3d.t.geometry.RaycastingScene` only to find *which*
surface a ray hits; the hit distance and the normal are then recomputed in
float64 from the analytic surface (plane, sphere or cylinder), so depth and
normals are exact (up to float32 storage), not those of the tessellation.

World frame: metres, **z up**; the room is the box
``[-X/2, X/2] x [-Y/2, Y/2] x [0, Z]`` with ``(X, Y, Z) = SceneConfig.room_size``,
so the room centre (in plan) is the world origin.  Cameras are OpenCV
(x right, y down, z forward) and poses are camera-to-world ``T_world_cam``
(DESIGN.md §1).  A horizontal camera with yaw ``psi`` looks along
``(cos psi, sin psi, 0)``.

Surfaces and ids (``RenderedView.surface_ids``): every smooth surface piece has
its own id and its own solid texture: ids 0..5 are floor, ceiling, walls -x, +x,
-y, +y; then, object by object, **each face of a box is a distinct surface**
(6 ids, so every id is planar), a cylinder has 3 (side, top cap, bottom cap), a
sphere 1 and a panel 1 (both sides share it).  :attr:`SyntheticScene.surfaces`
describes them.

Textures are *solid*: colour is a function of the 3-D world hit point only, so
a surface point has the same albedo in every view; shading is Lambertian with a
fixed directional light and an ambient term (view-independent), so brightness
constancy holds exactly apart from sampling/aliasing.
"""
from __future__ import annotations

import colorsys
import enum
import json
import logging
import math
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from .camera import PinholeCamera
from .frame import Frame
from .geometry import check_pose, pose_to_tum, rotation_angle_deg, so3_exp

__all__ = [
    "TextureConfig", "SceneConfig", "TrajectoryConfig", "SurfaceKind", "Surface",
    "BoxSpec", "CylinderSpec", "SphereSpec", "PanelSpec", "RenderedView", "SyntheticScene",
    "default_camera", "look_at", "camera_rotation", "make_trajectory", "orbit_views",
    "make_view_set", "render_frames", "write_tum_sequence",
]

logger = logging.getLogger(__name__)

ObjectSpec = Union["BoxSpec", "CylinderSpec", "SphereSpec", "PanelSpec"]


# =============================================================== configuration
@dataclass(frozen=True)
class TextureConfig:
    """Parameters of the per-surface solid textures.

    Attributes:
        max_wavelength: longest wavelength of the multi-octave noise (m), default 1.2.
        min_wavelength: shortest noise wavelength (m), default 0.08 (about 2.5 px at
            5 m for a 160x120 image with fx = 131).  Octaves halve from the longest.
        waves_per_octave: random-direction sinusoids per octave, default 3.
        noise_contrast: range of the relative albedo modulation by the
            (unit-std) noise, drawn per surface, default (0.12, 0.22).
        tint_strength: amplitude of the low-frequency colour (hue) variation, default 0.06.
        pattern_period: range of the period (m) of the sharp-edged pattern
            (stripes, checker or blobs, one drawn per surface), default (0.15, 0.6).
        patterns: which sharp patterns may be drawn, default all three.
    """

    max_wavelength: float = 1.2
    min_wavelength: float = 0.08
    waves_per_octave: int = 3
    noise_contrast: Tuple[float, float] = (0.12, 0.22)
    tint_strength: float = 0.06
    pattern_period: Tuple[float, float] = (0.15, 0.6)
    patterns: Tuple[str, ...] = ("stripes", "checker", "blobs")


@dataclass(frozen=True)
class SceneConfig:
    """Parameters of :meth:`SyntheticScene.generate` (all lengths in metres).

    Attributes:
        room_size: room extent ``(X, Y, Z)``: width along x, depth along y and
            height (z up), default (6, 6, 3).
        free_zone_radius: no object comes closer (in plan) than this to the room
            centre, so cameras near the centre never sit inside one, default 1.0.
        n_boxes, n_cylinders, n_spheres, n_panels: object counts, default 6, 3, 3, 3.
            Objects that cannot be placed without overlap after
            ``placement_tries`` attempts are skipped (logged).
        box_size: range of box width/depth, default (0.3, 0.9).
        box_height: range of floor-standing box heights, default (0.3, 1.6).
        floating_box_prob: probability a box is a wall cabinet hanging at
            0.6-1.8 m instead of standing on the floor, default 0.25.
        cylinder_radius, cylinder_height: ranges, default (0.08, 0.35), (0.4, 2.2).
        sphere_radius: range, default (0.15, 0.45); half the spheres rest on the
            floor, the others float at 0.6-2.2 m.
        panel_size: range of panel width/height, default (0.6, 1.4).
        panel_tilt_deg: range of panel tilt from vertical, default (15, 55).
        wall_margin: minimum gap between an object and the walls, default 0.02.
        placement_tries: random attempts per object, default 60.
        max_chord_error: maximum distance between the tessellated mesh and the
            analytic sphere/cylinder (only visible at silhouettes, since depth is
            recomputed analytically), default 5e-4.
        room_overlap: floor, ceiling and walls extend this far past the room
            corners so that rays never slip through the seams, default 0.05.
        texture: :class:`TextureConfig`.
        shading: Lambertian shading (True, default) or pure albedo (False).
        light_direction: direction *towards* the light (world, normalised
            internally), default (0.35, 0.25, 1.0) (from above, oblique).
        ambient, diffuse: ``rgb = albedo * (ambient + diffuse * max(0, n.l))``,
            default 0.5 and 0.5.
    """

    room_size: Tuple[float, float, float] = (6.0, 6.0, 3.0)
    free_zone_radius: float = 1.0
    n_boxes: int = 6
    n_cylinders: int = 3
    n_spheres: int = 3
    n_panels: int = 3
    box_size: Tuple[float, float] = (0.3, 0.9)
    box_height: Tuple[float, float] = (0.3, 1.6)
    floating_box_prob: float = 0.25
    cylinder_radius: Tuple[float, float] = (0.08, 0.35)
    cylinder_height: Tuple[float, float] = (0.4, 2.2)
    sphere_radius: Tuple[float, float] = (0.15, 0.45)
    panel_size: Tuple[float, float] = (0.6, 1.4)
    panel_tilt_deg: Tuple[float, float] = (15.0, 55.0)
    wall_margin: float = 0.02
    placement_tries: int = 60
    max_chord_error: float = 5e-4
    room_overlap: float = 0.05
    texture: TextureConfig = field(default_factory=TextureConfig)
    shading: bool = True
    light_direction: Tuple[float, float, float] = (0.35, 0.25, 1.0)
    ambient: float = 0.5
    diffuse: float = 0.5


@dataclass(frozen=True)
class TrajectoryConfig:
    """Parameters of :func:`make_trajectory` (hand-held-like camera motion).

    Attributes:
        fps: frame rate, default 30.
        center: world point the camera moves around, default (0, 0, 1.4).
        max_radius: hard bound on the horizontal distance from ``center``
            (enforced by a smooth radial squashing ``r -> R tanh(r / R)``); keep it
            below ``SceneConfig.free_zone_radius``, default 0.6.
        speed: RMS horizontal speed of the smooth path before squashing (m/s),
            default 0.3.
        height_amplitude: amplitude of the vertical motion (m), default 0.1.
        translation_period: range of the periods (s) of the translation
            sinusoids, default (4, 12).
        n_components: sinusoids per degree of freedom, default 3.
        yaw_amplitude_deg: amplitude of the yaw sweep, default 35.
        yaw_drift_deg_s: range of a constant yaw rate (random sign), default (3, 12).
        rotation_period: range of the periods (s) of the rotation sinusoids,
            default (3, 10).
        pitch_offset_deg: mean pitch (positive looks up), default -5.
        pitch_amplitude_deg, roll_amplitude_deg: default 8 and 4.
        jitter_translation: std of the smoothed translation jitter (m), default 0.0015.
        jitter_rotation_deg: std of the smoothed rotation jitter, default 0.1.
        jitter_sigma_frames: Gaussian smoothing of the jitter (frames), default 1.5.
        pure_rotation: optional ``(start, end)`` frame range (end exclusive) in
            which the translation is frozen (the translation clock stops, so the
            path stays continuous); rotation continues.  Default None.
        start_yaw_deg: initial yaw; None (default) draws it from the seed.
    """

    fps: float = 30.0
    center: Tuple[float, float, float] = (0.0, 0.0, 1.4)
    max_radius: float = 0.6
    speed: float = 0.3
    height_amplitude: float = 0.1
    translation_period: Tuple[float, float] = (4.0, 12.0)
    n_components: int = 3
    yaw_amplitude_deg: float = 35.0
    yaw_drift_deg_s: Tuple[float, float] = (3.0, 12.0)
    rotation_period: Tuple[float, float] = (3.0, 10.0)
    pitch_offset_deg: float = -5.0
    pitch_amplitude_deg: float = 8.0
    roll_amplitude_deg: float = 4.0
    jitter_translation: float = 0.0015
    jitter_rotation_deg: float = 0.1
    jitter_sigma_frames: float = 1.5
    pure_rotation: Optional[Tuple[int, int]] = None
    start_yaw_deg: Optional[float] = None


# ================================================================ scene types
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


# ============================================================ solid textures
_PATTERN_STRIPES, _PATTERN_CHECKER, _PATTERN_BLOBS = "stripes", "checker", "blobs"


class _SolidTexture:
    """Albedo as a function of the world point (vectorised, float32).

    ``albedo = where(pattern > threshold, c2, c1) * (1 + contrast * noise) + tint``
    with ``noise`` a unit-std multi-octave sum of sinusoids, ``pattern`` a
    product (stripes, checker) or sum (blobs) of sinusoids, ``tint`` a
    low-frequency colour variation.
    """

    def __init__(self, k_noise: np.ndarray, ph_noise: np.ndarray, amp_noise: np.ndarray,
                 k_tint: np.ndarray, ph_tint: np.ndarray, amp_tint: np.ndarray,
                 tint: np.ndarray, pattern: str, k_pat: np.ndarray, ph_pat: np.ndarray,
                 threshold: float, c1: np.ndarray, c2: np.ndarray, contrast: float) -> None:
        f32 = np.float32
        # column layout (K, 1) so that evaluation broadcasts over rows of points
        self.k_noise = np.asarray(k_noise, f32).T[:, :, None]  # (3, Kn, 1)
        self.ph_noise = np.asarray(ph_noise, f32)[:, None]
        self.amp_noise = (contrast * np.asarray(amp_noise)).astype(f32)[:, None]
        self.k_tint = np.asarray(k_tint, f32).T[:, :, None]
        self.ph_tint = np.asarray(ph_tint, f32)[:, None]
        self.amp_tint = np.asarray(amp_tint, f32)[:, None]
        self.tint = np.asarray(tint, f32)[:, None]
        self.pattern = pattern
        self.k_pat = np.asarray(k_pat, f32).T[:, :, None]
        self.ph_pat = np.asarray(ph_pat, f32)[:, None]
        self.threshold = f32(threshold)
        self.c1 = np.asarray(c1, f32)[:, None]
        self.c2 = np.asarray(c2, f32)[:, None]

    @staticmethod
    def _waves(p: np.ndarray, k: np.ndarray, ph: np.ndarray) -> np.ndarray:
        """sin(k . p + ph) as (K, N) (elementwise: no BLAS call for 3-long dot products)."""
        s = k[0] * p[0]
        s += k[1] * p[1]
        s += k[2] * p[2]
        s += ph
        return np.sin(s, out=s)

    def evaluate_rows(self, p: np.ndarray) -> np.ndarray:
        """(3, N) float32 albedo in [0, 1] of float32 world points given as rows (3, N)."""
        mod = (self._waves(p, self.k_noise, self.ph_noise) * self.amp_noise).sum(axis=0)
        mod += 1.0
        tint = (self._waves(p, self.k_tint, self.ph_tint) * self.amp_tint).sum(axis=0)
        pat = self._waves(p, self.k_pat, self.ph_pat)
        value = pat.sum(axis=0) if self.pattern == _PATTERN_BLOBS else pat[0] * pat[1] * pat[2]
        rgb = np.where(value > self.threshold, self.c2, self.c1)
        rgb *= mod
        rgb += tint * self.tint
        return np.clip(rgb, 0.0, 1.0, out=rgb)

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float32 albedo in [0, 1] at world points (N, 3)."""
        p = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3).T)
        return self.evaluate_rows(p).T


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _in_plane(k: np.ndarray, normal: Optional[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """Project wave vectors onto a plane keeping their length (planes only)."""
    if normal is None:
        return k
    length = np.linalg.norm(k, axis=1, keepdims=True)
    kp = k - (k @ normal)[:, None] * normal
    norm = np.linalg.norm(kp, axis=1, keepdims=True)
    bad = norm[:, 0] < 1e-6 * np.maximum(length[:, 0], 1e-12)
    if np.any(bad):  # wave vector along the normal: any in-plane direction
        u, _ = _plane_basis(normal)
        kp[bad] = u
        norm[bad] = 1.0
    return kp / norm * length


def _plane_basis(normal: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    n = normal / np.linalg.norm(normal)
    ref = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(ref, n)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


_LUMA = np.array([0.299, 0.587, 0.114])


def _colour_with_luma(hue: float, sat: float, luma: float) -> np.ndarray:
    """RGB of a hue/saturation with BT.601 luminance ``luma`` (darken, or blend with white)."""
    rgb = np.array(colorsys.hsv_to_rgb(hue, sat, 1.0))
    y = float(rgb @ _LUMA)
    if y >= luma:
        return rgb * (luma / y)
    return rgb + (luma - y) / (1.0 - y) * (1.0 - rgb)


def _contrasting_colours(rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    """Base and pattern colours whose luminances differ by 0.2-0.35 (texture in grey too)."""
    h1, s1, y1 = rng.uniform(), rng.uniform(0.15, 0.8), rng.uniform(0.3, 0.75)
    h2, s2 = (h1 + rng.uniform(-0.3, 0.3)) % 1.0, rng.uniform(0.1, 0.8)
    dy = rng.uniform(0.2, 0.35)
    y2 = y1 - dy if y1 > 0.5 else y1 + dy
    return _colour_with_luma(h1, s1, y1), _colour_with_luma(h2, s2, float(np.clip(y2, 0.08, 0.95)))


def _make_texture(rng: np.random.Generator, cfg: TextureConfig,
                  normal: Optional[np.ndarray]) -> _SolidTexture:
    """Random solid texture; ``normal`` (planes) keeps all waves in-plane."""
    n_oct = max(1, int(math.floor(math.log2(cfg.max_wavelength / cfg.min_wavelength))) + 1)
    wavelengths = cfg.max_wavelength * 0.5 ** np.arange(n_oct)
    wpo = max(1, int(cfg.waves_per_octave))
    lam = np.repeat(wavelengths, wpo) * rng.uniform(0.8, 1.25, n_oct * wpo)
    k_noise = _random_unit(rng, lam.size) * (2 * np.pi / lam)[:, None]
    k_noise = _in_plane(k_noise, normal, rng)
    amp = (lam / cfg.max_wavelength) ** 0.4
    amp = amp / np.sqrt(0.5 * np.sum(amp ** 2))  # unit std of the sum
    ph_noise = rng.uniform(0, 2 * np.pi, lam.size)

    lam_t = rng.uniform(0.6, 2.0, 3)
    k_tint = _in_plane(_random_unit(rng, 3) * (2 * np.pi / lam_t)[:, None], normal, rng)
    amp_tint = np.full(3, cfg.tint_strength / np.sqrt(1.5))
    tint = rng.normal(size=3)
    tint = tint / np.linalg.norm(tint)

    pattern = str(cfg.patterns[rng.integers(len(cfg.patterns))]) if cfg.patterns else _PATTERN_STRIPES
    period = rng.uniform(*cfg.pattern_period)
    ph_pat = rng.uniform(0, 2 * np.pi, 3)
    if pattern == _PATTERN_CHECKER:
        if normal is not None:  # a 2-D checker in the plane
            u, v = _plane_basis(normal)
            a = rng.uniform(0, np.pi)
            k_pat = np.stack([np.cos(a) * u + np.sin(a) * v, -np.sin(a) * u + np.cos(a) * v,
                              np.zeros(3)]) * (2 * np.pi / period)
            k_pat[2] = 0.0
            ph_pat[2] = np.pi / 2
        else:  # 3-D checker (random orientation)
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            k_pat = q * (2 * np.pi / period)
        threshold = 0.0
    elif pattern == _PATTERN_STRIPES:
        k_pat = np.zeros((3, 3))
        k_pat[0] = _in_plane(_random_unit(rng, 1), normal, rng)[0] * (2 * np.pi / period)
        ph_pat[1:] = np.pi / 2
        threshold = float(rng.uniform(-0.4, 0.4))
    elif pattern == _PATTERN_BLOBS:
        k_pat = _in_plane(_random_unit(rng, 3) * (2 * np.pi / (1.5 * period)), normal, rng)
        threshold = float(rng.uniform(0.2, 0.9))
    else:
        raise ValueError(f"unknown texture pattern {pattern!r}")
    c1, c2 = _contrasting_colours(rng)
    return _SolidTexture(k_noise, ph_noise, amp, k_tint, rng.uniform(0, 2 * np.pi, 3), amp_tint,
                         tint, pattern, k_pat, ph_pat, threshold, c1, c2,
                         float(rng.uniform(*cfg.noise_contrast)))


# ============================================================== tessellation
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


# ================================================================== the scene
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
        self.surfaces: List[Surface] = []
        verts: List[np.ndarray] = []
        tris: List[np.ndarray] = []
        tri_sid: List[np.ndarray] = []
        n_verts = 0

        def add(v: np.ndarray, t: np.ndarray, sid: int) -> None:
            nonlocal n_verts
            verts.append(v)
            tris.append(t + n_verts)
            tri_sid.append(np.full(len(t), sid, np.int32))
            n_verts += len(v)

        def new_surface(kind, name, obj, point, axis, radius=0.0) -> int:
            sid = len(self.surfaces)
            self.surfaces.append(Surface(sid, SurfaceKind(kind), name, obj,
                                         tuple(float(x) for x in point),
                                         tuple(float(x) for x in axis), float(radius)))
            return sid

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
            sid = new_surface(SurfaceKind.PLANE, name, -1, point, normal)
            add(*_quad(*corners), sid)

        err = float(config.max_chord_error)
        counters: Dict[str, int] = {}
        for oi, obj in enumerate(self.objects):
            label = type(obj).__name__.replace("Spec", "").lower()
            name = f"{label}{counters.get(label, 0)}"
            counters[label] = counters.get(label, 0) + 1
            if isinstance(obj, BoxSpec):
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
                        sid = new_surface(SurfaceKind.PLANE, f"{name}/{'+' if sign > 0 else '-'}"
                                          f"{'xyz'[axis]}", oi, fc, n)
                        add(*_quad(fc - e1 - e2, fc + e1 - e2, fc + e1 + e2, fc - e1 + e2), sid)
            elif isinstance(obj, CylinderSpec):
                b = np.asarray(obj.base_center, float)
                r, h = float(obj.radius), float(obj.height)
                top = b + np.array([0, 0, h])
                nseg = _segments(r, err, 2 * np.pi)
                ang = np.arange(nseg) * 2 * np.pi / nseg
                ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(nseg)], 1) * r
                j = np.arange(nseg)
                jn = (j + 1) % nseg
                sid = new_surface(SurfaceKind.CYLINDER, f"{name}/side", oi, b, (0, 0, 1), r)
                v = np.concatenate([b + ring, top + ring])
                t = np.concatenate([np.stack([j, jn, nseg + jn], 1),
                                    np.stack([j, nseg + jn, nseg + j], 1)])
                add(v, t, sid)
                for cap, centre, normal in (("top", top, (0, 0, 1)), ("bottom", b, (0, 0, -1))):
                    sid = new_surface(SurfaceKind.PLANE, f"{name}/{cap}", oi, centre, normal)
                    v = np.concatenate([centre[None], centre + ring])
                    add(v, np.stack([np.zeros(nseg, int), 1 + j, 1 + jn], 1), sid)
            elif isinstance(obj, SphereSpec):
                sid = new_surface(SurfaceKind.SPHERE, name, oi, obj.center, (0, 0, 0), obj.radius)
                add(*_sphere_mesh(obj.center, float(obj.radius), err), sid)
            elif isinstance(obj, PanelSpec):
                c = np.asarray(obj.center, float)
                n = np.asarray(obj.normal, float)
                n = n / np.linalg.norm(n)
                u = np.cross([0.0, 0.0, 1.0], n)
                u = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(u) < 1e-9 else u / np.linalg.norm(u)
                v = np.cross(n, u)
                cs, ss = math.cos(obj.spin), math.sin(obj.spin)
                u, v = cs * u + ss * v, -ss * u + cs * v
                e1, e2 = u * obj.size[0] / 2, v * obj.size[1] / 2
                sid = new_surface(SurfaceKind.PLANE, name, oi, c, n)
                add(*_quad(c - e1 - e2, c + e1 - e2, c + e1 + e2, c - e1 + e2), sid)
            else:
                raise TypeError(f"unsupported scene object {obj!r}")

        self._vertices = np.concatenate(verts).astype(np.float32)
        self._triangles = np.concatenate(tris).astype(np.uint32)
        self._tri_surface = np.concatenate(tri_sid)
        self._kind = np.array([s.kind for s in self.surfaces], np.int8)
        self._point = np.array([s.point for s in self.surfaces], float)
        self._axis = np.array([s.axis for s in self.surfaces], float)
        self._radius = np.array([s.radius for s in self.surfaces], float)
        self._textures = [
            _make_texture(np.random.default_rng([self.seed, 1, s.id]), config.texture,
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
        return cls(config, seed, _sample_objects(np.random.default_rng([int(seed), 0]), config))

    # ---------------------------------------------------------------- queries
    @property
    def room_center(self) -> np.ndarray:
        """Centre of the room volume (world)."""
        return np.array([0.0, 0.0, self.config.room_size[2] / 2])

    @property
    def n_triangles(self) -> int:
        return len(self._triangles)

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

    def shade(self, points: np.ndarray, surface_ids: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(N, 3) float32 rgb in [0, 1]: albedo times Lambertian shading (if enabled)."""
        rgb = self.albedo(points, surface_ids)
        if self.config.shading:
            nrm = np.asarray(normals, float).reshape(-1, 3)
            L = self._light
            ndotl = np.nan_to_num(nrm[:, 0] * L[0] + nrm[:, 1] * L[1] + nrm[:, 2] * L[2])
            rgb *= (self.config.ambient
                    + self.config.diffuse * np.maximum(ndotl, 0.0)).astype(np.float32)[:, None]
        return np.clip(rgb, 0.0, 1.0, out=rgb)

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
                sc = sid[curved]
                dc = np.stack([dx[curved], dy[curved], dz[curved]], 1)
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
                tm = t_mesh[curved]
                ok = np.isfinite(tc) & (tc > 0) & (np.abs(tc - tm) <= 0.05 + 0.02 * tm)
                tc = np.where(ok, tc, tm)
                radial = o + tc[:, None] * dc - self._point[sc]
                radial -= np.einsum("ij,ij->i", radial, ax)[:, None] * ax
                radial /= np.linalg.norm(radial, axis=1, keepdims=True)
                radial[np.einsum("ij,ij->i", radial, dc) > 0] *= -1.0
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

    def _colour(self, safe: np.ndarray, points: Tuple[np.ndarray, ...],
                normals: Tuple[np.ndarray, ...]) -> np.ndarray:
        """(N, 3) float32 shaded texture; ``safe`` = surface ids with misses as ``n_surf``."""
        n = len(safe)
        key = safe.astype(np.int16) if len(self.surfaces) < 32767 else safe
        order = np.argsort(key, kind="stable")
        sorted_ids = key[order]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(sorted_ids)) + 1])
        ends = np.append(starts[1:], n)
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
    order = np.argsort(key, kind="stable")
    sorted_ids = key[order]
    starts = np.concatenate([[0], np.flatnonzero(np.diff(sorted_ids)) + 1])
    ends = np.append(starts[1:], len(sorted_ids))
    for a, b in zip(starts, ends):
        s = int(sorted_ids[a])
        if s >= 0:
            yield s, order[a:b]


def _sample_objects(rng: np.random.Generator, cfg: SceneConfig) -> List[ObjectSpec]:
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
            elif kind == "cylinder":
                r = float(rng.uniform(*cfg.cylinder_radius))
                hgt = min(float(rng.uniform(*cfg.cylinder_height)), Z - 0.05)
                br = r
                make = lambda xy, r=r, hgt=hgt: CylinderSpec((xy[0], xy[1], 0.0), r, hgt)  # noqa: E731
            elif kind == "sphere":
                r = float(rng.uniform(*cfg.sphere_radius))
                zc = (r if rng.uniform() < 0.5
                      else float(rng.uniform(max(0.6, r + 0.05), min(2.2, Z - r - 0.05))))
                br = r
                make = lambda xy, r=r, zc=zc: SphereSpec((xy[0], xy[1], zc), r)  # noqa: E731
            else:
                pw, ph = (float(v) for v in rng.uniform(*cfg.panel_size, 2))
                tilt = np.radians(rng.uniform(*cfg.panel_tilt_deg)) * rng.choice([-1.0, 1.0])
                turn = np.radians(rng.uniform(-35, 35))
                zc = float(rng.uniform(0.7, 2.0))
                zc = float(np.clip(zc, ph / 2 + 0.05, Z - ph / 2 - 0.05))
                br = 0.5 * max(pw, ph)
                make = lambda xy, pw=pw, ph=ph, tilt=tilt, turn=turn, zc=zc: PanelSpec(  # noqa: E731
                    (xy[0], xy[1], zc), _panel_normal(xy, turn, tilt), (pw, ph), 0.0)
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


def _panel_normal(xy, turn: float, tilt: float) -> Tuple[float, float, float]:
    """Normal facing the room centre (in plan), turned by ``turn`` and tilted by ``tilt``."""
    inward = -np.asarray(xy, float) / max(np.linalg.norm(xy), 1e-9)
    c, s = math.cos(turn), math.sin(turn)
    h = np.array([c * inward[0] - s * inward[1], s * inward[0] + c * inward[1], 0.0])
    n = math.cos(tilt) * h + np.array([0.0, 0.0, math.sin(tilt)])
    return tuple(float(x) for x in n / np.linalg.norm(n))


# ================================================================== cameras
def default_camera(width: int = 640, height: int = 480) -> PinholeCamera:
    """TUM-like intrinsics (fx = fy = 525 at 640x480, principal point at the centre)
    resampled to ``width`` x ``height`` (``PinholeCamera.resized`` convention)."""
    return PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480).resized(width, height)


def camera_rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation (OpenCV camera, world z up) from angles in radians.

    ``yaw`` turns the viewing direction to ``(cos yaw, sin yaw, 0)``; positive
    ``pitch`` looks up; ``roll`` turns about the optical axis.
    ``R = R_yaw @ R_x(pitch) @ R_z(roll)``.
    """
    cy, sy = math.cos(yaw), math.sin(yaw)
    R0 = np.array([[sy, 0.0, cy], [-cy, 0.0, sy], [0.0, -1.0, 0.0]])
    cp, sp = math.cos(pitch), math.sin(pitch)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    cr, sr = math.cos(roll), math.sin(roll)
    Rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return R0 @ Rx @ Rz


def look_at(eye: Sequence[float], target: Sequence[float],
            up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose at ``eye`` whose optical axis points at ``target``
    and whose image 'up' (-y) is as close to ``up`` as possible."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    x = np.cross(-up, z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = eye
    return T


# ============================================================== trajectories
def _sinusoid_sum(rng: np.random.Generator, t: np.ndarray, n_comp: int,
                  period: Tuple[float, float]) -> Tuple[np.ndarray, np.ndarray]:
    """Sum of sinusoids bounded by 1 in magnitude, and its time derivative's RMS."""
    n_comp = max(1, int(n_comp))
    f = 1.0 / rng.uniform(period[0], period[1], n_comp)
    a = rng.uniform(0.5, 1.0, n_comp)
    a = a / a.sum()
    ph = rng.uniform(0, 2 * np.pi, n_comp)
    value = np.sin(2 * np.pi * f * t[:, None] + ph) @ a
    rms_rate = math.sqrt(0.5 * float(np.sum((2 * np.pi * f * a) ** 2)))
    return value, rms_rate


def _smoothed_noise(rng: np.random.Generator, n: int, dims: int, sigma: float) -> np.ndarray:
    """Unit-std Gaussian-smoothed white noise (n, dims)."""
    from scipy.ndimage import convolve1d

    noise = rng.normal(size=(n, dims))
    if sigma <= 0:
        return noise
    half = int(math.ceil(3 * sigma))
    x = np.arange(-half, half + 1)
    kern = np.exp(-0.5 * (x / sigma) ** 2)
    kern /= kern.sum()
    return convolve1d(noise, kern, axis=0, mode="reflect") / np.linalg.norm(kern)


def make_trajectory(n_frames: int, seed: int,
                    config: TrajectoryConfig = TrajectoryConfig()) -> np.ndarray:
    """(n, 4, 4) hand-held-like camera-to-world poses, deterministic in ``seed``.

    Translation: sums of low-frequency sinusoids (periods ``translation_period``)
    scaled to the RMS speed ``config.speed``, plus smoothed jitter, radially
    squashed to stay within ``max_radius`` of ``center`` (in plan).  Rotation:
    yaw sweep plus constant drift, small pitch/roll oscillations, smoothed
    jitter; the camera looks roughly horizontally.  ``pure_rotation=(s, e)``
    freezes the translation on frames ``s..e-1``.
    """
    n = int(n_frames)
    if n < 1:
        raise ValueError(f"make_trajectory: n_frames must be >= 1, got {n_frames}")
    cfg = config
    rng = np.random.default_rng([int(seed), 2])
    t = np.arange(n) / float(cfg.fps)

    # translation (horizontal: scaled to the requested RMS speed)
    px, rx = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    py, ry = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    scale = cfg.speed / max(math.hypot(rx, ry), 1e-12)
    pz, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.translation_period)
    trans = np.stack([px * scale, py * scale, pz * cfg.height_amplitude], 1)

    # rotation
    yaw0 = (math.radians(cfg.start_yaw_deg) if cfg.start_yaw_deg is not None
            else rng.uniform(0, 2 * np.pi))
    drift = math.radians(rng.uniform(*cfg.yaw_drift_deg_s)) * rng.choice([-1.0, 1.0])
    yaw_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    pitch_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    roll_s, _ = _sinusoid_sum(rng, t, cfg.n_components, cfg.rotation_period)
    yaw = yaw0 + drift * t + math.radians(cfg.yaw_amplitude_deg) * (yaw_s - yaw_s[0])
    pitch = math.radians(cfg.pitch_offset_deg) + math.radians(cfg.pitch_amplitude_deg) * pitch_s
    roll = math.radians(cfg.roll_amplitude_deg) * roll_s

    jitter = _smoothed_noise(rng, n, 6, cfg.jitter_sigma_frames)
    trans = trans + cfg.jitter_translation * jitter[:, :3]
    jit_rot = math.radians(cfg.jitter_rotation_deg) * jitter[:, 3:]

    if cfg.pure_rotation is not None:
        s, e = (int(v) for v in cfg.pure_rotation)
        if not 0 <= s < e <= n:
            raise ValueError(f"make_trajectory: pure_rotation {cfg.pure_rotation} must satisfy "
                             f"0 <= start < end <= n_frames = {n}")
        clock = np.arange(n)
        clock = np.where(clock < s, clock, np.maximum(s, clock - (e - s)))
        trans = trans[clock]

    # keep within the free zone: smooth radial squashing in plan
    r = np.linalg.norm(trans[:, :2], axis=1)
    R = float(cfg.max_radius)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(r > 1e-12, R * np.tanh(r / R) / r, 1.0)
    trans[:, :2] *= factor[:, None]
    trans += np.asarray(cfg.center, float)

    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):  # per frame (not per pixel): a few 3x3 products
        poses[i, :3, :3] = camera_rotation(yaw[i], pitch[i], roll[i]) @ so3_exp(jit_rot[i])
        poses[i, :3, 3] = trans[i]
    return poses


def _so3_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (angles below pi)."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    theta = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-9:
        return 0.5 * w
    return theta / (2 * math.sin(theta)) * w


def orbit_views(T_world_ref: np.ndarray, depth: float, n_views: int, rotation_deg: float,
                baseline_frac: float, seed: int) -> np.ndarray:
    """(n, 4, 4) supporting poses around a reference pose.

    Each view sits at distance ``baseline_frac * depth`` from the reference
    centre (directions spread around the optical axis, mostly sideways/up-down),
    looks at the reference's centre point at ``depth`` and then rotates so that
    its rotation relative to the reference is exactly ``rotation_deg`` (either
    part of the look-at rotation, or the look-at plus an extra random rotation).
    """
    T_ref = check_pose(T_world_ref, "T_world_ref")
    rng = np.random.default_rng([int(seed), 3])
    R_ref, c_ref = T_ref[:3, :3], T_ref[:3, 3]
    target = c_ref + R_ref[:, 2] * float(depth)
    up = -R_ref[:, 1]
    angle_target = math.radians(float(rotation_deg))
    a0 = rng.uniform(0, 2 * np.pi)
    poses = []
    for j in range(int(n_views)):
        a = a0 + 2 * np.pi * j / max(int(n_views), 1) + rng.uniform(-0.3, 0.3)
        b_cam = np.array([math.cos(a), math.sin(a), 0.3 * rng.normal()])
        b_cam /= np.linalg.norm(b_cam)
        eye = c_ref + R_ref @ b_cam * float(baseline_frac) * float(depth)
        R_la = look_at(eye, target, up)[:3, :3]
        rel = _so3_log(R_ref.T @ R_la)
        alpha = float(np.linalg.norm(rel))
        if angle_target <= alpha:
            R = R_ref @ so3_exp(rel * (angle_target / alpha)) if alpha > 0 else R_ref.copy()
        else:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            lo, hi = 0.0, np.pi
            for _ in range(60):  # bisection on the extra rotation's magnitude
                mid = 0.5 * (lo + hi)
                ang = math.radians(rotation_angle_deg(R_ref.T @ R_la @ so3_exp(axis * mid)))
                lo, hi = (mid, hi) if ang < angle_target else (lo, mid)
            R = R_la @ so3_exp(axis * 0.5 * (lo + hi))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = eye
        poses.append(T)
    return np.asarray(poses).reshape(-1, 4, 4)


def make_view_set(scene: SyntheticScene, camera: PinholeCamera, n_views: int = 2,
                  rotation_deg: float = 7.5, baseline_frac: float = 0.05,
                  seed: int = 0) -> Tuple[np.ndarray, np.ndarray]:
    """Reference pose plus ``n_views`` supporting poses looking at the same content.

    The reference camera stands within 0.3 m (in plan) of the room centre at
    1.2-1.6 m height, random yaw, slightly downward pitch.  Supporting views come
    from :func:`orbit_views` with the reference's median depth (rendered at low
    resolution).  Returns ``(T_world_ref (4, 4), T_world_views (n, 4, 4))``.
    """
    rng = np.random.default_rng([int(seed), 4])
    free = min(0.3, 0.5 * scene.config.free_zone_radius)
    rad, az = free * math.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    eye = np.array([rad * math.cos(az), rad * math.sin(az), rng.uniform(1.2, 1.6)])
    T_ref = np.eye(4)
    T_ref[:3, :3] = camera_rotation(rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(-12, 3)),
                                    math.radians(rng.uniform(-3, 3)))
    T_ref[:3, 3] = eye
    small = camera.resized(max(8, camera.width // 8), max(6, camera.height // 8))
    depth = scene.render_depth(small, T_ref)
    median = float(np.nanmedian(depth))
    views = orbit_views(T_ref, median, n_views, rotation_deg, baseline_frac,
                        int(rng.integers(2 ** 31)))
    return T_ref, views


# ========================================================= frames and files
def render_frames(scene: SyntheticScene, camera: PinholeCamera, poses: np.ndarray,
                  timestamps: Optional[Sequence[float]] = None, *, fps: float = 30.0,
                  supersample: int = 1) -> List[Frame]:
    """Render every pose into a :class:`~spgeo.frame.Frame` (name ``%06d``).

    Timestamps default to ``i / fps``.  ``meta`` holds ``normals`` (camera
    frame), ``surface_ids`` and ``scene_seed``.
    """
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    if timestamps is None:
        timestamps = np.arange(len(poses)) / float(fps)
    if len(timestamps) != len(poses):
        raise ValueError(f"render_frames: {len(timestamps)} timestamps for {len(poses)} poses")
    frames = []
    for i, (T, ts) in enumerate(zip(poses, timestamps)):
        view = scene.render(camera, T, supersample=supersample)
        frames.append(Frame(image=view.rgb, camera=camera, timestamp=float(ts), depth=view.depth,
                            T_world_cam=view.T_world_cam, name=f"{i:06d}",
                            meta={"normals": view.normals, "surface_ids": view.surface_ids,
                                  "scene_seed": scene.seed}))
    return frames


def _tum_stamp(start_us: int, offset_us: int) -> str:
    total = start_us + offset_us
    return f"{total // 1_000_000}.{total % 1_000_000:06d}"


def write_tum_sequence(directory: Union[str, os.PathLike], scene: SyntheticScene,
                       camera: PinholeCamera, poses: np.ndarray, fps: float = 30.0, *,
                       start_time: float = 1_000_000_000.0, depth_offset: float = 0.002,
                       supersample: int = 1) -> List[str]:
    """Write a sequence in the raw TUM RGB-D layout and return the rgb timestamps.

    Files: ``rgb/<t>.png`` (8-bit RGB), ``depth/<t'>.png`` (uint16, metres x
    5000, 0 = invalid) with ``t' = t + depth_offset``, ``rgb.txt``, ``depth.txt``
    and ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, camera-to-world,
    at the rgb timestamps), each with 3 ``#`` comment lines, and ``camera.json``
    (:meth:`PinholeCamera.to_dict`).  Timestamps are ``start_time + i / fps``
    with 6 decimals.
    """
    import cv2

    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    root = os.fspath(directory)
    os.makedirs(os.path.join(root, "rgb"), exist_ok=True)
    os.makedirs(os.path.join(root, "depth"), exist_ok=True)
    start_us = int(round(start_time * 1e6))
    rgb_lines, depth_lines, gt_lines, stamps = [], [], [], []
    for i, T in enumerate(poses):
        ts = _tum_stamp(start_us, int(round(i * 1e6 / fps)))
        ts_d = _tum_stamp(start_us, int(round(i * 1e6 / fps + depth_offset * 1e6)))
        view = scene.render(camera, T, supersample=supersample)
        rgb8 = np.clip(np.round(view.rgb * 255.0), 0, 255).astype(np.uint8)
        bgr8 = cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR)
        if not cv2.imwrite(os.path.join(root, "rgb", f"{ts}.png"), bgr8):
            raise OSError(f"cannot write {os.path.join(root, 'rgb', ts + '.png')}")
        d = np.nan_to_num(view.depth.astype(np.float64) * 5000.0, nan=0.0)
        d16 = np.clip(np.round(d), 0, 65535).astype(np.uint16)
        if not cv2.imwrite(os.path.join(root, "depth", f"{ts_d}.png"), d16):
            raise OSError(f"cannot write {os.path.join(root, 'depth', ts_d + '.png')}")
        rgb_lines.append(f"{ts} rgb/{ts}.png")
        depth_lines.append(f"{ts_d} depth/{ts_d}.png")
        gt_lines.append(ts + " " + " ".join(f"{v:.9f}" for v in pose_to_tum(view.T_world_cam)))
        stamps.append(ts)
    name = os.path.basename(os.path.normpath(root))
    headers = {
        "rgb.txt": ["# color images", f"# file: 'spgeo synthetic scene seed {scene.seed}: {name}'",
                    "# timestamp filename"],
        "depth.txt": ["# depth maps", f"# file: 'spgeo synthetic scene seed {scene.seed}: {name}'",
                      "# timestamp filename"],
        "groundtruth.txt": ["# ground truth trajectory",
                            f"# file: 'spgeo synthetic scene seed {scene.seed}: {name}'",
                            "# timestamp tx ty tz qx qy qz qw"],
    }
    for fname, body in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines),
                        ("groundtruth.txt", gt_lines)):
        with open(os.path.join(root, fname), "w", encoding="utf-8") as fh:
            fh.write("\n".join(headers[fname] + body) + "\n")
    with open(os.path.join(root, "camera.json"), "w", encoding="utf-8") as fh:
        json.dump(camera.to_dict(), fh, indent=2)
    logger.info("wrote %d synthetic TUM frames to %s", len(poses), root)
    return stamps
