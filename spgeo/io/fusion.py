"""One map of the scene: TSDF fusion of posed depth maps into a mesh and a cloud.

:func:`fuse_views` integrates posed RGB-D views, one at a time, into a
scalable TSDF: open3d's ``VoxelBlockGrid`` (hashed blocks of voxels allocated
where depth is observed: memory grows with the observed surface, not with the
number of views, and no scene bounds are needed), then extracts a triangle mesh
and a point cloud (the zero crossing of the TSDF, coloured; marching cubes).
``VoxelBlockGrid`` is the successor of the legacy ``ScalableTSDFVolume`` and
the same algorithm; the legacy class is not used because, in the open3d
release spgeo is tested with (0.20), it allocates its volume units from the
depth divided by 1000 when the depth image holds metres as floats
(``PointCloud.create_from_depth_image`` scales float depth too), so everything
beyond the first volume unit around the camera is lost.  :func:`fuse_odometry`
does it for a VO run: each keyframe that carries depth
(:meth:`spgeo.vo.Odometry.keyframes_with_depth`) contributes its primitives'
depth map (:meth:`spgeo.primitives.PrimitiveSet.depth_map` with the final
log-scales) and its input image as colour, at its final pose; keyframes that
left the window are read back from the keyframe store one at a time.
:meth:`FusionResult.write` saves ``mesh.ply`` and ``cloud.ply`` atomically.

Frames and units: ``T_world_cam`` is the 4x4 camera-to-world pose with OpenCV
camera axes (x right, y down, z forward); depth is the z coordinate along the
camera's optical axis, in world units (metres for sensor depth, VO units for a
monocular run); pixel centres are at integer coordinates.  The outputs are in
the poses' world frame and unit.

Scale: unless given, the voxel size, the truncation distance and the depth
cut-off are fractions / multiples of the median depth of the first view with
valid depth (:class:`FusionConfig`), so a VO map in arbitrary units fuses as a
metric one does.
"""
from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Iterable, Iterator, Optional, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class, config_to_dict

__all__ = ["FusionConfig", "FusionResult", "FusionView", "fuse_views", "fuse_odometry",
           "odometry_views", "MESH_FILE", "CLOUD_FILE", "FUSION_FILES"]

log = logging.getLogger(__name__)

#: file names of :meth:`FusionResult.write`
MESH_FILE = "mesh.ply"
CLOUD_FILE = "cloud.ply"

#: what the files of :meth:`FusionResult.write` are, by the keys of the paths it returns
#: (an output manifest's ``"what"``, :mod:`spgeo.io.outputs`); in the poses' world frame
#: and unit
FUSION_FILES = {
    "mesh": "the fused TSDF mesh (all keyframes' depth maps at their final poses; marching "
            "cubes): triangles with vertex colours and normals, binary PLY",
    "cloud": "the fused TSDF point cloud (all keyframes): the zero crossing of the TSDF, "
             "coloured, with normals, binary PLY (the per-keyframe clouds are in clouds/)",
}

#: one view to fuse: ``(image, depth, camera, T_world_cam)`` (:func:`fuse_views`)
FusionView = Tuple[Optional[np.ndarray], np.ndarray, PinholeCamera, np.ndarray]


@config_class
@dataclass(frozen=True)
class FusionConfig:
    """Options of :func:`fuse_views` (lengths in the poses' world unit).

    Attributes:
        voxel_size: TSDF voxel edge; default None: ``voxel_fraction`` times
            the reference depth (the median valid depth of the first view).
        voxel_fraction: voxel edge per unit of reference depth (default 1/100).
        sdf_trunc: truncation distance of the signed distance; default None:
            ``trunc_voxels`` voxels.
        trunc_voxels: truncation in voxels when ``sdf_trunc`` is None (default 5).
        depth_max: depths beyond this are not integrated; default None:
            ``depth_max_factor`` times the reference depth.
        depth_max_factor: see ``depth_max`` (default 3).
        min_views: a voxel is on the extracted surface only when at least
            this many views integrated it (its TSDF weight; default 1).
        colour: integrate the images' colours (default True; else grey).
        block_count: initial capacity of the block hash map (blocks of 8^3
            voxels; it grows when needed).
    """

    voxel_size: Optional[float] = None
    voxel_fraction: float = 0.01
    sdf_trunc: Optional[float] = None
    trunc_voxels: float = 5.0
    depth_max: Optional[float] = None
    depth_max_factor: float = 3.0
    min_views: int = 1
    colour: bool = True
    block_count: int = 4096

    def __post_init__(self) -> None:
        for name in ("voxel_size", "sdf_trunc", "depth_max"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"FusionConfig.{name} must be None or a positive number, "
                                 f"got {v!r}")
        for name in ("voxel_fraction", "trunc_voxels", "depth_max_factor"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"FusionConfig.{name} must be a positive number, got {v!r}")
        for name in ("min_views", "block_count"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"FusionConfig.{name} must be an integer >= 1, got {v!r}")

    def resolved(self, reference_depth: float) -> Tuple[float, float, float]:
        """``(voxel_size, sdf_trunc, depth_max)`` for a scene whose reference
        (median) depth is ``reference_depth`` (world units, > 0)."""
        voxel = self.voxel_size or self.voxel_fraction * reference_depth
        trunc = self.sdf_trunc or self.trunc_voxels * voxel
        dmax = self.depth_max or self.depth_max_factor * reference_depth
        return float(voxel), float(trunc), float(dmax)


@dataclass
class FusionResult:
    """The fused map (world frame of the poses, their unit).

    Attributes:
        mesh: ``open3d.geometry.TriangleMesh`` (vertex colours in [0, 1] and normals).
        cloud: ``open3d.geometry.PointCloud`` (colours in [0, 1], with normals).
        voxel_size, sdf_trunc, depth_max: the values used.
        n_views: views integrated.
        config: the :class:`FusionConfig` they were resolved from (None for a
            hand-made result).
        reference_depth: the median valid depth of the first view with depth,
            which the config's fractions multiply (world units).
        n_colours_clipped: colour channels of the mesh and the cloud clipped to
            [0, 1] (the TSDF's weighted colour averages round past 1).
    """

    mesh: Any
    cloud: Any
    voxel_size: float
    sdf_trunc: float
    depth_max: float
    n_views: int
    config: Optional["FusionConfig"] = None
    reference_depth: Optional[float] = None
    n_colours_clipped: int = 0

    def __repr__(self) -> str:
        """One line: views, mesh and cloud sizes, the resolved voxel size,
        truncation and depth cut-off (world units)."""
        return (f"FusionResult({self.n_views} views, {len(self.mesh.vertices)} vertices, "
                f"{len(self.mesh.triangles)} triangles, {len(self.cloud.points)} points; voxel "
                f"{self.voxel_size:.4g}, truncation {self.sdf_trunc:.4g}, depth max "
                f"{self.depth_max:.4g})")

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) float64 mesh vertices."""
        return np.asarray(self.mesh.vertices)

    @property
    def triangles(self) -> np.ndarray:
        """(T, 3) int32 vertex indices of the mesh's triangles."""
        return np.asarray(self.mesh.triangles)

    def summary(self) -> Dict[str, object]:
        """JSON-ready counts and parameters (``report.json``'s ``"fusion"``):
        the resolved ``voxel_size``, ``sdf_trunc`` and ``depth_max`` (world
        units), ``reference_depth``, ``config`` (:class:`FusionConfig` as a dict,
        None when unknown), counts and ``n_colours_clipped``."""
        return {"n_views": self.n_views, "voxel_size": self.voxel_size,
                "sdf_trunc": self.sdf_trunc, "depth_max": self.depth_max,
                "reference_depth": self.reference_depth,
                "config": None if self.config is None else config_to_dict(self.config),
                "n_vertices": len(self.mesh.vertices), "n_triangles": len(self.mesh.triangles),
                "n_points": len(self.cloud.points), "n_colours_clipped": self.n_colours_clipped}

    def write(self, folder: Union[str, os.PathLike]) -> Dict[str, Path]:
        """Write ``folder/mesh.ply`` and ``folder/cloud.ply`` (binary PLY; the
        folder is created), each atomically (a temporary file renamed into
        place).  Returns ``{"mesh": path, "cloud": path}`` (what they are:
        :data:`FUSION_FILES`); raises ``OSError`` when open3d cannot write.
        Open3D's own messages below errors are silenced while it writes (its
        colour clamping is counted by the fusion instead: :attr:`n_colours_clipped`)."""
        import open3d as o3d

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        out = {}
        for key, fname, write in (("mesh", MESH_FILE, o3d.io.write_triangle_mesh),
                                  ("cloud", CLOUD_FILE, o3d.io.write_point_cloud)):
            path = folder / fname
            fd, tmp = tempfile.mkstemp(prefix=f".{fname}.", suffix=".tmp.ply", dir=folder)
            os.close(fd)
            try:
                with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
                    ok = write(tmp, getattr(self, key), write_ascii=False)
                if not ok:
                    raise OSError(f"open3d could not write {path}")
                os.chmod(tmp, 0o644)   # mkstemp creates 0600
                os.replace(tmp, path)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
            out[key] = path
        return out


#: voxels per block edge of the ``VoxelBlockGrid``
_BLOCK_RESOLUTION = 8


def _tensors(view: FusionView, colour: bool):
    """``(depth image float32 with 0 = invalid, colour image float32 [0, 1],
    intrinsic (3, 3), T_cam_world (4, 4))`` as open3d tensors.

    The intrinsic's principal point is shifted by +0.5: open3d truncates a
    projected voxel's continuous pixel coordinate to the pixel index, spgeo
    puts pixel centres at integers (``floor(u + 0.5)`` is the nearest pixel)."""
    import open3d as o3d
    import open3d.core as o3c

    from ..geometry import check_pose, invert_pose
    from ..images import to_float_image

    image, depth, cam, T = view
    d = np.asarray(depth, dtype=np.float32)
    if d.shape != cam.shape:
        raise ValueError(f"fuse_views: depth is {d.shape}, the camera {cam.shape}")
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32)
    if colour and image is not None:
        rgb = to_float_image(cam.check_image(image, "fuse_views image")).astype(np.float32)
        rgb = rgb if rgb.ndim == 3 else np.repeat(rgb[..., None], 3, axis=2)
    else:
        rgb = np.full(cam.shape + (3,), 0.5, np.float32)
    K = np.array([[cam.fx, 0.0, cam.cx + 0.5], [0.0, cam.fy, cam.cy + 0.5], [0.0, 0.0, 1.0]])
    T_cam_world = invert_pose(check_pose(np.asarray(T, dtype=np.float64), "T_world_cam"))
    return (o3d.t.geometry.Image(o3c.Tensor(d)),
            o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb))),
            o3c.Tensor(K), o3c.Tensor(np.ascontiguousarray(T_cam_world)))


def _grid(voxel: float, block_count: int):
    """An empty ``VoxelBlockGrid`` (TSDF, weight, colour) on the CPU."""
    import open3d as o3d
    import open3d.core as o3c

    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32), attr_channels=(1, 1, 3),
        voxel_size=float(voxel), block_resolution=_BLOCK_RESOLUTION,
        block_count=int(block_count), device=o3c.Device("CPU:0"))


def fuse_views(views: Iterable[FusionView], config: FusionConfig = FusionConfig()
               ) -> FusionResult:
    """TSDF fusion of posed depth maps (module docstring).

    Args:
        views: ``(image, depth, camera, T_world_cam)`` per view, read once and
            one at a time (a generator keeps one view in memory): ``image``
            (H, W[, 3]) uint8 or float [0, 1] colours, or None (grey);
            ``depth`` (H, W) z-depth in world units, NaN or <= 0 where
            invalid; ``camera`` the view's undistorted pinhole camera (H, W);
            ``T_world_cam`` its 4x4 camera-to-world pose (OpenCV axes).
        config: :class:`FusionConfig`.

    Returns:
        A :class:`FusionResult` (empty mesh and cloud when the views hold no
        surface inside the depth range).
    Raises:
        ValueError: no view with valid depth, or a view whose depth, image or
            pose is malformed.
    """
    grid, params, n, ref = None, None, 0, None
    for view in views:
        depth, color, K, T_cam_world = _tensors(view, config.colour)
        if grid is None:
            d = depth.as_tensor().numpy()
            if not np.any(d > 0):
                continue
            ref = float(np.median(d[d > 0]))
            params = config.resolved(ref)
            grid = _grid(params[0], config.block_count)
        mult = params[1] / params[0]
        blocks = grid.compute_unique_block_coordinates(depth, K, T_cam_world, 1.0, params[2],
                                                       trunc_voxel_multiplier=mult)
        grid.integrate(blocks, depth, color, K, K, T_cam_world, 1.0, params[2],
                       trunc_voxel_multiplier=mult)
        n += 1
    if grid is None:
        raise ValueError("fuse_views: no view with valid depth")
    weight = config.min_views - 0.5
    mesh = grid.extract_triangle_mesh(weight_threshold=weight).to_legacy()
    mesh.compute_vertex_normals()
    cloud = grid.extract_point_cloud(weight_threshold=weight).to_legacy()
    clipped = _clip_colours(mesh, cloud)
    log.info("TSDF fusion of %d views (voxel %.4g, truncation %.4g): %d vertices, %d "
             "triangles, %d points", n, params[0], params[1], len(mesh.vertices),
             len(mesh.triangles), len(cloud.points))
    return FusionResult(mesh, cloud, *params, n, config, ref, clipped)


#: colour excess over [0, 1] that rounding explains (the weighted averages of values in [0, 1])
_COLOUR_ROUNDING = 1e-4


def _clip_colours(mesh, cloud) -> int:
    """The TSDF's weighted colour averages clipped to [0, 1] in place: rounding takes them
    past 1 on some CPUs (plots refuse them; open3d warns once per file when it writes them
    as bytes, which clamps them the same way, so the files do not change).  Returns the
    number of colour channels clipped, logged once here (INFO; a WARNING when some lay
    further out than rounding explains)."""
    import open3d as o3d

    n, excess = 0, 0.0
    for geom, name in ((mesh, "vertex_colors"), (cloud, "colors")):
        c = np.asarray(getattr(geom, name))
        if c.size == 0:
            continue
        out = (c < 0) | (c > 1)
        if out.any():
            n += int(out.sum())
            excess = max(excess, float(np.max(np.maximum(c - 1, -c))))
            setattr(geom, name, o3d.utility.Vector3dVector(np.clip(c, 0, 1)))
    if n:
        level = logging.WARNING if excess > _COLOUR_ROUNDING else logging.INFO
        log.log(level, "TSDF fusion: %d colour channels of the mesh and cloud clipped to "
                "[0, 1] (at most %.2g outside)", n, excess)
    return n


def odometry_views(odometry) -> Iterator[FusionView]:
    """The fusion views of a VO run (:class:`spgeo.vo.Odometry` after its
    last frame): per keyframe with depth (:meth:`~spgeo.vo.Odometry.keyframes_with_depth`),
    in order, ``(input image, primitives' depth map, primitives' camera,
    final T_world_kf)``; the image is resized (``INTER_AREA``) to the
    primitives' camera when the front-end works at another size.  One
    keyframe is read from the store at a time (:meth:`Odometry.iter_keyframes`)."""
    import cv2

    for _, image, kf in odometry.iter_keyframes(odometry.keyframes_with_depth()):
        prims = kf.primitives
        cam = prims.camera
        img = None if image is None else np.asarray(image)
        if img is not None and img.shape[:2] != cam.shape:
            img = cv2.resize(img, cam.size, interpolation=cv2.INTER_AREA)
        yield img, prims.depth_map(), cam, kf.T_world_kf


def fuse_odometry(odometry, config: FusionConfig = FusionConfig()) -> FusionResult:
    """:func:`fuse_views` of :func:`odometry_views` (world = keyframe 0's
    camera, VO units).  Raises ``ValueError`` when no keyframe carries depth
    (a monocular run whose map was never initialised)."""
    return fuse_views(odometry_views(odometry), config)
