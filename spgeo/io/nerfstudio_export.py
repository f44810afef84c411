"""nerfstudio export: posed images as a ``transforms.json`` data set.

:func:`export_nerfstudio` writes a folder that ``ns-train ... nerfstudio-data
--data DIR`` (and the trainers that read nerfstudio's format) load::

    DIR/transforms.json       camera model, intrinsics and one frame per image
    DIR/images/<name>.png     the images at the processed resolution

Format and conventions (nerfstudio's "Data conventions",
https://docs.nerf.studio/quickstart/data_conventions.html):

* intrinsics shared by all frames at the top level: ``camera_model``
  (``"PINHOLE"``: spgeo's images are undistorted), ``fl_x``, ``fl_y``,
  ``cx``, ``cy`` (pixels), ``w``, ``h``;
* nerfstudio's pixel coordinates put pixel ``(0, 0)``'s *corner* at 0 (a ray
  for pixel ``(i, j)`` goes through ``(i + 0.5, j + 0.5)``), spgeo's put its
  *centre* at 0: ``cx`` and ``cy`` are spgeo's plus 0.5 (as in the COLMAP export);
* each frame's ``transform_matrix`` is the 4x4 camera-to-world matrix in
  nerfstudio's OpenGL / Blender camera convention (x right, y up, z back:
  the camera looks along -z), i.e. spgeo's camera-to-world ``T_world_cam``
  (OpenCV axes: x right, y down, z forward) with its y and z axes negated:
  ``transform_matrix = T_world_cam @ diag(1, -1, -1, 1)``
  (:func:`opengl_from_opencv`, its inverse :func:`opencv_from_opengl`);
* the world frame is the poses' own (for a VO run keyframe 0's camera, VO
  units); nerfstudio re-orients and re-scales it when it loads the data.

The folder is written under a temporary sibling name and renamed into place
(:func:`spgeo.io.outputs.staged_directory`); an existing ``DIR`` is replaced
only when it is empty or a previous export (``images/`` and
``transforms.json`` only).
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Dict, Iterable, Optional, Sequence, Set, Tuple, Union

import numpy as np

from ..camera import PinholeCamera
from .colmap_export import IMAGES_SUBDIR, check_export_directory, odometry_images, write_image
from .outputs import staged_directory

__all__ = ["TRANSFORMS_FILE", "NERFSTUDIO_ENTRIES", "OPENGL_FROM_OPENCV", "opengl_from_opencv",
           "opencv_from_opengl", "camera_fields", "check_nerfstudio_directory",
           "export_nerfstudio", "export_odometry_nerfstudio"]

log = logging.getLogger(__name__)

#: the file nerfstudio reads
TRANSFORMS_FILE = "transforms.json"
#: what a previous export holds (an export directory may hold nothing else)
NERFSTUDIO_ENTRIES = frozenset({IMAGES_SUBDIR, TRANSFORMS_FILE})
#: camera axes change OpenCV (x right, y down, z forward) -> OpenGL (x right,
#: y up, z back); its own inverse
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def opengl_from_opencv(T_world_cam: np.ndarray) -> np.ndarray:
    """nerfstudio's ``transform_matrix`` (camera-to-world, OpenGL camera axes)
    of spgeo's camera-to-world ``T_world_cam`` (OpenCV camera axes); (4, 4) or
    (n, 4, 4)."""
    return np.asarray(T_world_cam, dtype=np.float64) @ OPENGL_FROM_OPENCV


def opencv_from_opengl(transform_matrix: np.ndarray) -> np.ndarray:
    """spgeo's ``T_world_cam`` (OpenCV camera axes) of a nerfstudio
    ``transform_matrix`` (OpenGL camera axes): the inverse of
    :func:`opengl_from_opencv`."""
    return np.asarray(transform_matrix, dtype=np.float64) @ OPENGL_FROM_OPENCV


def camera_fields(camera: PinholeCamera) -> Dict[str, object]:
    """The top-level intrinsics of ``transforms.json`` for ``camera``:
    ``camera_model`` ``"PINHOLE"``, ``fl_x``, ``fl_y``, ``cx``, ``cy`` (nerfstudio
    pixel coordinates: spgeo's principal point + 0.5), ``w``, ``h`` (pixels)."""
    return {"camera_model": "PINHOLE", "fl_x": float(camera.fx), "fl_y": float(camera.fy),
            "cx": float(camera.cx) + 0.5, "cy": float(camera.cy) + 0.5,
            "w": int(camera.width), "h": int(camera.height)}


def check_nerfstudio_directory(directory: Union[str, os.PathLike],
                               output: Union[None, str, os.PathLike] = None) -> Path:
    """``directory`` as a Path after checking, before any work, that an export
    may be written there: absent, empty or a previous export, not ``output``
    (the run's folder), its parent writable.  Raises
    :class:`~spgeo.validation.InputError` naming it otherwise."""
    return check_export_directory(directory, output, NERFSTUDIO_ENTRIES,
                                  "nerfstudio export directory")


def export_nerfstudio(directory: Union[str, os.PathLike], camera: PinholeCamera,
                      images: Iterable[Tuple[str, np.ndarray]],
                      T_world_cam: np.ndarray) -> Path:
    """Write a nerfstudio data set of posed images (module docstring).

    Args:
        directory: export folder (created; replaced when a previous export).
        camera: the undistorted pinhole camera of every image.
        images: ``(name, image)`` per pose, in order (a list or a generator:
            written one at a time); ``image`` (H, W[, 3]) uint8 or float
            [0, 1] at ``camera``'s size; ``name`` gives the unique file name
            (:func:`spgeo.io.colmap_export.image_file_name`).
        T_world_cam: (n, 4, 4) camera-to-world poses (OpenCV camera axes), one
            per image.

    Returns:
        The path of ``transforms.json``.
    Raises:
        ValueError: bad poses or images, an image count that differs from the
            poses', or a ``directory`` that holds other files
            (:class:`~spgeo.validation.InputError`).
    """
    from ..geometry import check_poses

    d = check_nerfstudio_directory(directory)
    T = check_poses(T_world_cam)
    with staged_directory(d) as tmp:
        (tmp / IMAGES_SUBDIR).mkdir()
        frames = _write_frames(tmp / IMAGES_SUBDIR, camera, images, T)
        doc = {**camera_fields(camera), "frames": frames}
        (tmp / TRANSFORMS_FILE).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    log.info("nerfstudio export: %d images in %s", len(frames), d)
    return d / TRANSFORMS_FILE


def _write_frames(image_dir: Path, camera: PinholeCamera,
                  images: Iterable[Tuple[str, np.ndarray]], T: np.ndarray) -> list:
    """Write the images; returns the ``frames`` entries of ``transforms.json``."""
    names: Set[str] = set()
    frames = []
    for i, (name, image) in enumerate(images):
        if i >= len(T):
            raise ValueError(f"export_nerfstudio: more images than poses ({len(T)})")
        fname = write_image(image_dir, camera, name, image, names, "export_nerfstudio")
        frames.append({"file_path": f"{IMAGES_SUBDIR}/{fname}",
                       "transform_matrix": opengl_from_opencv(T[i]).tolist()})
    if len(frames) != len(T):
        raise ValueError(f"export_nerfstudio: {len(frames)} images for {len(T)} poses")
    return frames


def export_odometry_nerfstudio(directory: Union[str, os.PathLike], odometry,
                               names: Sequence[str], keyframe_images: Dict[int, np.ndarray],
                               frames: Optional[Iterable[Tuple[str, np.ndarray]]] = None
                               ) -> Path:
    """nerfstudio data set of a VO run (:class:`spgeo.vo.Odometry`; world =
    keyframe 0's camera, VO units): the keyframes, or with ``frames`` every
    frame not lost, selected as for the COLMAP export
    (:func:`spgeo.io.colmap_export.odometry_images`: arguments and errors),
    at their final poses.  Returns the path of ``transforms.json``."""
    sel, images = odometry_images(odometry, names, keyframe_images, frames)
    return export_nerfstudio(directory, odometry.camera, images,
                             odometry.result().poses[sel])
