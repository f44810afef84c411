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
(docs/design.md §1).  A horizontal camera with yaw ``psi`` looks along
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

from .config import (ForwardTrajectoryConfig, SceneConfig, TextureConfig, TrajectoryConfig,
                     forward_scene_config)
from .objects import (BoxSpec, CylinderSpec, PanelSpec, RenderedView, SphereSpec, Surface,
                      SurfaceKind)
from .poses import (camera_rotation, default_camera, look_at, make_forward_trajectory,
                    make_trajectory, make_view_set, orbit_views)
from .scene import SyntheticScene
from .sequence import render_frames, write_tum_sequence
from .road import RoadScene, block_loop, straight_street
from .street import STREET_SIZE, street_camera, street_drive, street_scene

__all__ = [
    "TextureConfig", "SceneConfig", "TrajectoryConfig", "ForwardTrajectoryConfig",
    "forward_scene_config", "make_forward_trajectory", "SurfaceKind", "Surface",
    "BoxSpec", "CylinderSpec", "SphereSpec", "PanelSpec", "RenderedView", "SyntheticScene",
    "default_camera", "look_at", "camera_rotation", "make_trajectory", "orbit_views",
    "make_view_set", "render_frames", "write_tum_sequence", "STREET_SIZE", "street_scene",
    "street_camera", "street_drive", "RoadScene", "straight_street", "block_loop",
]
