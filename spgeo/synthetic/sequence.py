"""Rendering pose sequences into frames, and writing them in the raw TUM RGB-D layout."""
from __future__ import annotations

import json
import logging
import os
from typing import List, Optional, Sequence, Union

import numpy as np

from ..camera import PinholeCamera
from ..frame import Frame
from ..geometry import pose_to_tum
from .scene import SyntheticScene

__all__ = ["render_frames", "write_tum_sequence"]

logger = logging.getLogger(__name__)


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
