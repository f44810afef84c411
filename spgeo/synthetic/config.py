"""Configuration dataclasses of the synthetic scenes, textures and trajectories.

All lengths are metres, angles degrees unless a name says otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple

from ..configs import config_class

__all__ = ["TextureConfig", "SceneConfig", "TrajectoryConfig"]


@config_class
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


@config_class
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


@config_class
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


@config_class
@dataclass(frozen=True)
class ForwardTrajectoryConfig:
    """Parameters of :func:`~spgeo.synthetic.poses.make_forward_trajectory`: a
    forward drive with large inter-frame motion (a vehicle at a low frame rate).

    Attributes:
        step: forward distance between consecutive frames (m), default 0.25.
        start: first camera centre (world, m), default (0, -3.4, 1.2).
        heading_deg: mean driving direction (yaw, degrees; 90 drives along +y),
            default 90.
        lateral_amplitude: amplitude of the sideways weave (m), default 0.3.
        weave_wavelength: wavelength of the weave along the path (m), default 8.
        yaw_follows_path: the camera looks along the path's tangent (so it
            turns with the weave), default True.
        pitch_deg: constant pitch (positive looks up), default -4.
        bounce_deg: amplitude of a pitch/roll bounce (degrees), default 1.
        bounce_period: period of the bounce (frames), default 7.
    """

    step: float = 0.25
    start: Tuple[float, float, float] = (0.0, -3.4, 1.2)
    heading_deg: float = 90.0
    lateral_amplitude: float = 0.3
    weave_wavelength: float = 8.0
    yaw_follows_path: bool = True
    pitch_deg: float = -4.0
    bounce_deg: float = 1.0
    bounce_period: float = 7.0


def forward_scene_config() -> SceneConfig:
    """A long hall for :class:`ForwardTrajectoryConfig`: a 12 x 12 x 3 m room
    whose objects keep 3.6 m (in plan) from the centre, so the default drive
    (28 frames: 6.75 m along y through the centre, weaving 0.3 m) never
    enters one."""
    return SceneConfig(room_size=(12.0, 12.0, 3.0), free_zone_radius=3.6, n_boxes=10,
                       n_cylinders=4, n_spheres=3, n_panels=4)

