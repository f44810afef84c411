"""COLMAP export: posed images and primitive points as a COLMAP sparse model.

:func:`export_colmap` writes a self-contained folder in the layout COLMAP's
MVS, ``colmap gui`` (File > Import model) and COLMAP-reading splatting / NeRF
trainers expect::

    DIR/images/<name>.png         the images at the processed resolution
    DIR/sparse/0/cameras.bin      one PINHOLE camera
    DIR/sparse/0/images.bin       every image, registered, with cam_from_world
    DIR/sparse/0/points3D.bin     subsampled primitive points with colours
    DIR/sparse/0/rigs.bin, frames.bin   (COLMAP >= 3.12: trivial rig and frames)

Conventions: spgeo poses are camera-to-world ``T_world_cam``; COLMAP stores
world-to-camera ``cam_from_world`` (its inverse).  spgeo pixel centres are at
integer coordinates, COLMAP's at half-integers: the principal point and every
2-D observation are shifted by +0.5 (:func:`spgeo.twoview.backends.colmap_camera`).
Each 3-D point carries one track element, the pixel of the image it was
unprojected from, so COLMAP's tools (which reject points without tracks)
accept the model; its reprojection error is then zero by construction.

The folder is written next to ``DIR`` under a temporary name and renamed into
place, so a reader never sees a half-written model.  An existing ``DIR`` is
replaced only when it is empty or a previous export (``images/`` and
``sparse/`` only); anything else raises ``ValueError``
(:func:`check_export_directory`, which callers run before long computations).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import AbstractSet, Dict, Iterable, List, Optional, Sequence, Set, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose
from ..primitives import PrimitiveSet
from ..validation import InputError
from .outputs import check_writable_parent, staged_directory

__all__ = ["ColmapPoints", "primitive_points", "keyframe_points", "export_colmap",
           "export_sfm_result", "export_odometry", "check_export_directory", "image_file_name",
           "write_image", "odometry_images", "MODEL_SUBDIR", "IMAGES_SUBDIR"]

log = logging.getLogger(__name__)

#: model folder inside the export directory (the layout splatting trainers read)
MODEL_SUBDIR = os.path.join("sparse", "0")
#: image folder inside the export directory
IMAGES_SUBDIR = "images"
_EXPORT_ENTRIES = {"images", "sparse"}
_IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class ColmapPoints:
    """3-D points to export, each observed in one image.

    Attributes:
        xyz: (M, 3) float64 world points (the frame of the exported poses).
        rgb: (M, 3) uint8 colours.
        image_index: (M,) int index, into the exported image sequence, of the
            image observing each point.
        uv: (M, 2) float64 pixel of the observation in that image, spgeo
            convention (pixel centres at integers).
    """

    xyz: np.ndarray
    rgb: np.ndarray
    image_index: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        m = len(xyz)
        rgb = np.asarray(self.rgb)
        idx = np.asarray(self.image_index)
        uv = np.asarray(self.uv, dtype=np.float64)
        if rgb.shape != (m, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"ColmapPoints.rgb must be ({m}, 3) uint8, got {rgb.shape} "
                             f"{rgb.dtype}")
        if idx.shape != (m,) or not np.issubdtype(idx.dtype, np.integer) or np.any(idx < 0):
            raise ValueError(f"ColmapPoints.image_index must be ({m},) non-negative integers, "
                             f"got {idx.shape} {idx.dtype}")
        if uv.shape != (m, 2):
            raise ValueError(f"ColmapPoints.uv must be ({m}, 2), got {uv.shape}")
        if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(uv))):
            raise ValueError("ColmapPoints.xyz and .uv must be finite")
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "image_index", idx.astype(np.int64))
        object.__setattr__(self, "uv", uv)

    def __len__(self) -> int:
        return len(self.xyz)

    @classmethod
    def concatenate(cls, parts: Sequence["ColmapPoints"]) -> "ColmapPoints":
        """All points of ``parts`` in order (an empty set for no parts)."""
        if not parts:
            return cls(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.int64),
                       np.zeros((0, 2)))
        return cls(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("xyz", "rgb", "image_index", "uv")))

    def subsample(self, max_points: int) -> "ColmapPoints":
        """At most ``max_points`` points, evenly spaced in the current order
        (deterministic)."""
        if max_points < 0:
            raise ValueError(f"max_points must be >= 0, got {max_points}")
        if len(self) <= max_points:
            return self
        keep = np.unique(np.linspace(0, len(self) - 1, int(max_points)).round().astype(np.int64))
        return ColmapPoints(self.xyz[keep], self.rgb[keep], self.image_index[keep],
                            self.uv[keep])


def _rgb8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 of an RGB or grey image (uint8 or float [0, 1])."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        from ..images import to_float_image

        img = np.clip(np.round(to_float_image(img) * 255.0), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got {np.asarray(image).shape}")
    return img


def primitive_points(primitives: PrimitiveSet, T_world_cam: np.ndarray, image_index: int,
                     image: Optional[np.ndarray] = None, stride: int = 4) -> ColmapPoints:
    """Points of ``primitives`` on a pixel lattice, in the world frame.

    Keeps the pixels whose column and row are multiples of ``stride`` (one
    point per pixel: where primitives overlap, the first primitive's), with a
    finite positive depth.

    Args:
        primitives: a :class:`PrimitiveSet` with its log-scales (its camera is
            the image's).
        T_world_cam: 4x4 camera-to-world pose of the primitives' image.
        image_index: index of that image in the export.
        image: (H, W[, 3]) colours at the primitives' resolution (default:
            mid-grey points).
        stride: lattice step in pixels (>= 1).
    """
    if int(stride) < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    stride = int(stride)
    cam = primitives.camera
    pix = primitives.pixels
    u, v = pix % cam.width, pix // cam.width
    on = np.flatnonzero((u % stride == 0) & (v % stride == 0))
    _, first = np.unique(pix[on], return_index=True)
    sel = on[np.sort(first)]
    z = np.exp(primitives.scaled_log_depth()[sel])
    ok = np.isfinite(z) & (z > 0)
    sel, z = sel[ok], z[ok]
    uv = np.stack([u[sel], v[sel]], axis=-1).astype(np.float64)
    from ..geometry import transform_points

    xyz = transform_points(np.asarray(T_world_cam, dtype=np.float64), cam.unproject(uv, z))
    if image is None:
        rgb = np.full((len(sel), 3), 128, np.uint8)
    else:
        rgb = _rgb8(cam.check_image(image, "primitive_points image")).reshape(-1, 3)[pix[sel]]
    return ColmapPoints(xyz, rgb, np.full(len(sel), int(image_index), np.int64), uv)


def image_file_name(name: str) -> str:
    """The exported file name of an image called ``name``: a ``.png``
    extension replaces ``.png`` / ``.jpg`` / ``.jpeg`` or is appended (names
    may hold dots, e.g. TUM timestamps)."""
    base = str(name)
    if base.lower().endswith(_IMAGE_EXTENSIONS):
        base = base[:base.rfind(".")]
    return base + ".png"


def check_export_directory(directory: Union[str, os.PathLike],
                           output: Union[None, str, os.PathLike] = None,
                           entries: AbstractSet[str] = frozenset(_EXPORT_ENTRIES),
                           what: str = "COLMAP export directory") -> Path:
    """``directory`` as a Path, after checking that an export may replace it:
    absent, empty, or a previous export (holding only ``entries``: by default
    ``images/`` and ``sparse/``), not the run's ``output`` folder, and its parent
    writable (:func:`spgeo.io.outputs.check_writable_parent`; created if needed).
    Raises :class:`~spgeo.validation.InputError` naming it (as ``what``) otherwise."""
    d = Path(directory)
    if output is not None and d.resolve() == Path(output).resolve():
        raise InputError(f"the {what} {d} is the output folder: give its own "
                         "folder (e.g. a sub-folder)")
    if d.exists():
        if not d.is_dir():
            raise InputError(f"{what} {d} exists and is not a folder")
        other = sorted(set(os.listdir(d)) - set(entries))
        if other:
            raise InputError(f"{what} {d} holds other files "
                             f"({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}): "
                             "give an empty or new folder")
    check_writable_parent(d, what)
    return d


def write_image(image_dir: Path, camera: PinholeCamera, name: str, image: np.ndarray,
                written: Set[str], what: str = "export") -> str:
    """Write ``image`` (H, W[, 3], uint8 or float [0, 1], at ``camera``'s size)
    as ``image_dir/<image_file_name(name)>`` (8-bit RGB PNG) and return that
    file name, added to ``written``.  Raises ``ValueError`` when the name is
    repeated (in ``written``) or not a plain file name, or the image is not at
    the camera's size."""
    fname = image_file_name(name)
    if fname in written or os.path.basename(fname) != fname or fname.startswith("."):
        raise ValueError(f"{what}: image name {name!r} is repeated or not a plain file name")
    from ..viz import save_png

    rgb = _rgb8(camera.check_image(image, f"{what} image {name!r}"))
    save_png(Path(image_dir) / fname, rgb)
    written.add(fname)
    return fname


def _pycolmap():
    import pycolmap

    if not hasattr(pycolmap.Reconstruction, "add_image_with_trivial_frame"):
        raise ImportError(f"COLMAP export needs a pycolmap with rigs and frames "
                          f"(Reconstruction.add_image_with_trivial_frame); found "
                          f"{getattr(pycolmap, '__version__', '?')}")
    return pycolmap


def _rigid(pycolmap, T_cam_world: np.ndarray):
    """``pycolmap.Rigid3d`` of a 4x4 world-to-camera transform."""
    return pycolmap.Rigid3d(pycolmap.Rotation3d(T_cam_world[:3, :3]), T_cam_world[:3, 3].copy())


def _write_model(model_dir: Path, camera: PinholeCamera,
                 images: Iterable[Tuple[str, np.ndarray]], T_world_cam: np.ndarray,
                 points: ColmapPoints, image_dir: Path) -> Tuple[int, int]:
    """Write the images and the binary model; returns (images, points) written."""
    pycolmap = _pycolmap()
    from ..twoview.backends import colmap_camera

    n = len(T_world_cam)
    order = np.argsort(points.image_index, kind="stable")
    starts = np.searchsorted(points.image_index[order], np.arange(n + 1))
    point2d_idx = np.empty(len(points), np.int64)   # rank of each point in its image
    point2d_idx[order] = np.arange(len(points)) - starts[points.image_index[order]]

    rec = pycolmap.Reconstruction()
    cam = colmap_camera(camera)
    cam.camera_id = 1
    rec.add_camera_with_trivial_rig(cam)
    names: Set[str] = set()
    count = 0
    for i, (name, image) in enumerate(images):
        if i >= n:
            raise ValueError(f"export_colmap: more images than poses ({n})")
        fname = write_image(image_dir, camera, name, image, names, "export_colmap")
        kp = points.uv[order[starts[i]:starts[i + 1]]] + 0.5      # COLMAP pixel centres
        img = pycolmap.Image(name=fname, keypoints=kp, camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, _rigid(pycolmap, invert_pose(T_world_cam[i])))
        count += 1
    if count != n:
        raise ValueError(f"export_colmap: {count} images for {n} poses")
    for j in range(len(points)):
        track = pycolmap.Track([pycolmap.TrackElement(int(points.image_index[j]) + 1,
                                                      int(point2d_idx[j]))])
        rec.add_point3D(points.xyz[j], track, points.rgb[j])
    rec.update_point_3d_errors()
    model_dir.mkdir(parents=True)
    rec.write(str(model_dir))
    return n, len(points)


def export_colmap(directory: Union[str, os.PathLike], camera: PinholeCamera,
                  images: Iterable[Tuple[str, np.ndarray]], T_world_cam: np.ndarray,
                  points: Optional[ColmapPoints] = None,
                  max_points: int = 200_000) -> Path:
    """Write a COLMAP model of posed images and points (module docstring).

    Args:
        directory: export folder (created; replaced when a previous export).
        camera: the undistorted pinhole camera of every image.
        images: ``(name, image)`` per pose, in order (a list or a generator:
            images are written one at a time); ``image`` (H, W[, 3]) uint8 or
            float [0, 1] at ``camera``'s size; ``name`` gives the file name
            (:func:`image_file_name`), unique.
        T_world_cam: (n, 4, 4) camera-to-world poses, one per image.
        points: the 3-D points (default none); observations must index the
            images and lie inside them.
        max_points: cap on the points written (evenly subsampled beyond it).

    Returns:
        The model folder ``directory/sparse/0`` (``pycolmap.Reconstruction``
        reads it).
    Raises:
        ValueError: bad poses, images or points, an image count that differs
            from the poses', or a ``directory`` that holds other files.
    """
    from ..geometry import check_poses

    d = check_export_directory(directory)
    T = check_poses(T_world_cam)
    pts = ColmapPoints.concatenate([]) if points is None else points
    if len(pts) and pts.image_index.max() >= len(T):
        raise ValueError(f"ColmapPoints.image_index reaches {pts.image_index.max()}, "
                         f"only {len(T)} images")
    inside = ((pts.uv > -0.5) & (pts.uv < np.array([camera.width, camera.height]) - 0.5))
    if not np.all(inside):
        raise ValueError("ColmapPoints.uv: observations outside the image")
    pts = pts.subsample(max_points)
    with staged_directory(d) as tmp:
        (tmp / IMAGES_SUBDIR).mkdir()
        n_img, n_pts = _write_model(tmp / MODEL_SUBDIR, camera, images, T, pts,
                                    tmp / IMAGES_SUBDIR)
    log.info("COLMAP export: %d images, %d points in %s", n_img, n_pts, d)
    return d / MODEL_SUBDIR


def keyframe_points(keyframes: Sequence[Tuple[int, np.ndarray, object]],
                    stride: int = 4) -> ColmapPoints:
    """:func:`primitive_points` of several images: ``(image_index, colour
    image or None, keyframe)`` with ``keyframe.primitives`` and
    ``keyframe.T_world_kf`` (:class:`spgeo.vo.keyframe.Keyframe`)."""
    parts: List[ColmapPoints] = [primitive_points(kf.primitives, kf.T_world_kf, i, img, stride)
                                 for i, img, kf in keyframes]
    return ColmapPoints.concatenate(parts)


def export_sfm_result(directory: Union[str, os.PathLike], result, images: Sequence[np.ndarray],
                      names: Sequence[str], stride: int = 4, max_points: int = 200_000) -> Path:
    """COLMAP model of a :class:`spgeo.sfm.SfMResult` (world = the reference camera).

    ``images``: the reference then the supporting images (any common size:
    resized with ``INTER_AREA`` to ``result.camera``, the working resolution),
    ``names`` their names.  Points: the supported reference primitives
    (``result.supported_primitives``: a flagged result's unconstrained ones are
    left out) on a ``stride``-pixel lattice, observed in the reference image.
    Returns the model folder.
    """
    import cv2

    from ..images import to_float_image

    cam = result.camera
    if len(images) != len(result.T_ref_view) + 1 or len(names) != len(images):
        raise ValueError(f"export_sfm_result: {len(images)} images and {len(names)} names for "
                         f"{len(result.T_ref_view) + 1} SfM images")
    small = [img if img.shape[:2] == cam.shape
             else cv2.resize(img, cam.size, interpolation=cv2.INTER_AREA)
             for img in (to_float_image(np.asarray(i)) for i in images)]
    T = np.stack([np.eye(4)] + [np.asarray(t, dtype=np.float64) for t in result.T_ref_view])
    points = primitive_points(result.supported_primitives, T[0], 0, small[0], stride)
    return export_colmap(directory, cam, list(zip(names, small)), T, points, max_points)


def export_odometry(directory: Union[str, os.PathLike], odometry, names: Sequence[str],
                    keyframe_images: Dict[int, np.ndarray],
                    frames: Optional[Iterable[Tuple[str, np.ndarray]]] = None, stride: int = 4,
                    max_points: int = 200_000) -> Path:
    """COLMAP model of a VO run (:class:`spgeo.vo.Odometry`; world = keyframe
    0's camera, VO units).

    Args:
        directory: export folder (:func:`export_colmap`).
        odometry: the odometry after its last frame.
        names: (n,) name of every frame it tracked.
        keyframe_images: keyframe index -> the image it was made from, at the
            VO camera's size (colours; the images of a keyframe-only export).
        frames: None for the keyframes only; else ``(name, image)`` of every
            tracked frame again, in order (e.g. a re-opened data set; any
            size, resized with ``INTER_AREA`` as the VO runner does, one at a
            time): then every frame not flagged ``"lost"`` is exported.
        stride, max_points: points of the keyframes' primitives
            (:func:`primitive_points`), each observed in its keyframe's image.

    Raises ``ValueError`` when ``frames`` are not the run's (names, count) or
    the keyframes' primitives are not at the VO camera's size.
    """
    res, cam = odometry.result(), odometry.camera
    kf_frame = _keyframe_frames(odometry)
    kfs = odometry.keyframes
    for kf in kfs:
        if kf.primitives.camera.shape != cam.shape:
            raise ValueError(f"keyframe primitives are {kf.primitives.camera.size}, the VO "
                             f"camera {cam.size}: the front-end's working size must be the "
                             "VO resolution for a COLMAP export")
    sel, images = odometry_images(odometry, names, keyframe_images, frames)
    pos = {i: p for p, i in enumerate(sel)}
    points = keyframe_points([(pos[kf_frame[k]], keyframe_images.get(k), kf)
                              for k, kf in enumerate(kfs) if k in kf_frame], stride)
    return export_colmap(directory, cam, images, res.poses[sel], points, max_points)


def _keyframe_frames(odometry) -> Dict[int, int]:
    """Keyframe index -> index of the frame it was made from (a saved map's keyframe,
    no frame of this run, has none: it is not exported)."""
    return {f.keyframe_index: f.index for f in odometry.frames if f.keyframe_index is not None}


def odometry_images(odometry, names: Sequence[str], keyframe_images: Dict[int, np.ndarray],
                    frames: Optional[Iterable[Tuple[str, np.ndarray]]] = None
                    ) -> Tuple[List[int], Iterable[Tuple[str, np.ndarray]]]:
    """The frames of a VO run that an export writes, and their images.

    Args:
        odometry: the :class:`spgeo.vo.Odometry` after its last frame.
        names: (n,) name of every frame it tracked.
        keyframe_images: keyframe index -> its image at the VO camera's size.
        frames: None for the keyframes only; else ``(name, image)`` of every
            tracked frame again, in order (any size: resized with
            ``INTER_AREA`` to the VO camera, one at a time); then every frame
            not flagged ``"lost"`` is selected.

    Returns:
        ``(frame indices, (name, image) per selected frame)``: indices into
        ``odometry.result()`` in increasing order; the images are produced
        lazily, in the same order (a generator: read it once).
    Raises ``ValueError`` when ``names`` is not one name per tracked frame (or
    later, while reading, when ``frames`` are not the run's).
    """
    res, cam = odometry.result(), odometry.camera
    if len(names) != len(res.poses):
        raise ValueError(f"export: {len(names)} names for {len(res.poses)} frames")
    if frames is None:
        kf_frame = _keyframe_frames(odometry)
        made = [k for k in range(odometry.n_keyframes) if k in kf_frame]
        sel = [kf_frame[k] for k in made]
        images: Iterable = ((names[kf_frame[k]], keyframe_images[k]) for k in made)
    else:
        sel = [i for i, s in enumerate(res.statuses) if s != "lost"]
        images = _processed(frames, names, set(sel), cam)
    return sel, images


def _processed(frames: Iterable[Tuple[str, np.ndarray]], names: Sequence[str], keep: set,
               camera: PinholeCamera):
    """``(name, image at camera's size)`` of the frames whose index is in ``keep``."""
    import cv2

    from ..images import to_float_image

    n = 0
    for i, (name, image) in enumerate(frames):
        if i >= len(names) or str(name) != names[i]:
            raise ValueError(f"frame {i} ({name!r}) is not the run's frame "
                             f"{names[i] if i < len(names) else None!r}")
        n += 1
        if i in keep:
            img = np.asarray(image)
            img = img if img.dtype == np.float32 else to_float_image(img)
            if img.shape[:2] != camera.shape:
                img = cv2.resize(img, camera.size, interpolation=cv2.INTER_AREA)
            yield names[i], img
    if n != len(names):
        raise ValueError(f"{n} frames given, the run had {len(names)}")
