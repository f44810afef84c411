"""The one frame type every data-set reader and the synthetic renderer return."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from .camera import PinholeCamera

__all__ = ["Frame", "resize_frame"]


@dataclass
class Frame:
    """One image with optional depth and ground-truth pose.

    Attributes:
        image: float32 in [0, 1], (H, W, 3) RGB or (H, W) grey, already undistorted
            when the reader was asked to undistort (then ``camera`` has no distortion).
        camera: intrinsics of ``image``.
        timestamp: seconds (data sets without timestamps use the frame number).
        depth: optional float32 (H, W) depth in metres along the optical axis,
            NaN where invalid.  Registered to ``image`` unless the reader says otherwise.
        T_world_cam: optional 4x4 camera-to-world ground-truth pose.
        name: identifier (file stem or frame number) for logs and outputs.
        meta: free-form reader-specific information (source paths, flags).
    """

    image: np.ndarray
    camera: PinholeCamera
    timestamp: float
    depth: Optional[np.ndarray] = None
    T_world_cam: Optional[np.ndarray] = None
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.camera.check_image(self.image, f"Frame {self.name!r} image")
        if self.depth is not None:
            self.camera.check_image(self.depth, f"Frame {self.name!r} depth")
            if self.depth.ndim != 2:
                raise ValueError(f"Frame {self.name!r}: depth must be (H, W), got {self.depth.shape}")
        if self.T_world_cam is not None:
            from .geometry import check_pose

            self.T_world_cam = check_pose(self.T_world_cam, f"Frame {self.name!r} T_world_cam")

    @property
    def gray(self) -> np.ndarray:
        """(H, W) float32 grey image in [0, 1]."""
        from .images import to_gray

        return to_gray(self.image)


def resize_frame(frame: Frame, resolution: Optional[Tuple[int, int]],
                 keep_depth: bool = False) -> Frame:
    """``frame`` undistorted (if its camera has distortion) and resized to
    ``resolution = (width, height)`` pixels with ``cv2.INTER_AREA`` (depth, if
    kept, with nearest neighbour), the camera follows
    (:meth:`PinholeCamera.resized`).  The same frame is returned when nothing
    changes.  Ground truth, timestamp, name and meta are kept."""
    import cv2

    from .images import to_float_image

    cam = frame.camera
    image = frame.image
    depth = frame.depth if keep_depth else None
    if cam.distortion is not None:
        image = cam.undistort_image(to_float_image(image))
        if depth is not None:
            depth = cam.undistort_image(depth, interpolation=cv2.INTER_NEAREST)
        cam = cam.undistorted()
    if resolution is None or tuple(resolution) == cam.size:
        if cam is frame.camera and (keep_depth or frame.depth is None):
            return frame
        return Frame(image=image, camera=cam, timestamp=frame.timestamp, depth=depth,
                     T_world_cam=frame.T_world_cam, name=frame.name, meta=dict(frame.meta))
    w, h = (int(v) for v in resolution)
    img = cv2.resize(to_float_image(image), (w, h), interpolation=cv2.INTER_AREA)
    if depth is not None:
        depth = cv2.resize(np.asarray(depth, np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
    return Frame(image=img, camera=cam.resized(w, h), timestamp=frame.timestamp, depth=depth,
                 T_world_cam=frame.T_world_cam, name=frame.name, meta=dict(frame.meta))
