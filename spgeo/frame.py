"""The one frame type every data-set reader and the synthetic renderer return."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from .camera import PinholeCamera
from .validation import InputError

__all__ = ["Frame", "resize_frame", "frame_label", "check_frame_image", "MAX_FLOAT_IMAGE_VALUE"]

#: a floating-point image whose largest value exceeds this is refused: its values look
#: like 0-255 (or 0-65535) intensities, not the [0, 1] of :attr:`Frame.image`
MAX_FLOAT_IMAGE_VALUE = 1.5


def frame_label(name, index: Optional[int] = None) -> str:
    """How error messages name a frame: ``"frame 17 ('kitchen_0017')"`` or, for an
    unnamed frame (``name`` ``""`` or None), ``"frame 17"`` when its position
    ``index`` in a run is known; ``"Frame 'kitchen_0017'"`` or ``"unnamed Frame"``
    when not."""
    named = name is not None and str(name) != ""
    if index is not None:
        return f"frame {int(index)} ({name!r})" if named else f"frame {int(index)}"
    return f"Frame {name!r}" if named else "unnamed Frame"


def check_frame_image(image, camera: PinholeCamera, what: str = "Frame image") -> np.ndarray:
    """The image of a :class:`Frame` of ``camera``, checked (and converted from
    8 / 16 bits); ``what`` names it in messages.

    Accepts (H, W, 3) RGB, (H, W) grey or (H, W, 1) grey of ``camera``'s
    (height, width): floating point in [0, 1] is returned as given; uint8 and
    uint16 are converted to float32 in [0, 1] (divided by 255, 65535:
    :func:`spgeo.images.to_float_image`).  Cost: one ``max`` over a float image.

    Raises :class:`~spgeo.validation.InputError` (a ``ValueError``) for another
    (H, W) (saying so when width and height look swapped), 4 channels (RGBA:
    the message says to drop alpha), another channel count, another dtype, or a
    float image whose maximum exceeds :data:`MAX_FLOAT_IMAGE_VALUE` (0-255
    values).  NaN / inf are left to the consumer (``Odometry.track`` refuses them).
    """
    image = camera.check_image(image, what)
    channels = image.shape[2] if image.ndim == 3 else None
    if channels == 4:
        raise InputError(f"{what} has 4 channels (RGBA?), expected (H, W, 3) RGB or (H, W) "
                         "grey: drop the alpha channel with image[..., :3]")
    if channels not in (None, 1, 3):
        raise InputError(f"{what} has {channels} channels (shape {image.shape}), expected "
                         "(H, W, 3) RGB or (H, W) grey")
    if image.dtype in (np.uint8, np.uint16):
        from .images import to_float_image

        return to_float_image(image)
    if not np.issubdtype(image.dtype, np.floating):
        raise InputError(f"{what} has dtype {image.dtype}, expected float in [0, 1] "
                         "(or uint8 / uint16, converted on construction)")
    hi = float(image.max())
    if hi > MAX_FLOAT_IMAGE_VALUE:
        raise InputError(f"{what} is float with values up to {hi:g}, expected [0, 1]: these "
                         "look like 0-255 intensities: divide by 255 (65535 for 16-bit data), "
                         "or pass the uint8 / uint16 array itself (converted on construction)")
    return image


@dataclass
class Frame:
    """One image with optional depth and ground-truth pose.

    Attributes:
        image: float32 in [0, 1], (H, W, 3) RGB or (H, W) grey, already undistorted
            when the reader was asked to undistort (then ``camera`` has no distortion).
            Construction checks it (:func:`check_frame_image`): uint8 / uint16
            images are converted to float32 in [0, 1] (divided by 255 / 65535);
            other floating-point dtypes are kept as given; an image whose (H, W)
            is not ``camera``'s, an RGBA image (drop alpha: ``image[..., :3]``),
            another dtype, or float values above :data:`MAX_FLOAT_IMAGE_VALUE`
            (0-255 floats) raise :class:`~spgeo.validation.InputError`.
        camera: intrinsics of ``image`` (``width`` x ``height`` pixels: ``image`` is
            (height, width[, 3])).
        timestamp: seconds (data sets without timestamps use the frame number).
        depth: optional float32 (H, W) depth in metres along the optical axis,
            NaN where invalid.  Registered to ``image`` unless the reader says otherwise.
        T_world_cam: optional 4x4 camera-to-world ground-truth pose.
        name: identifier (file stem or frame number) for logs and outputs; messages
            name an unnamed frame (``""``) by its index in a VO run
            (:func:`frame_label`).
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
        label = frame_label(self.name)
        self.image = check_frame_image(self.image, self.camera, f"{label} image")
        if self.depth is not None:
            self.camera.check_image(self.depth, f"{label} depth")
            if self.depth.ndim != 2:
                raise InputError(f"{label}: depth must be (H, W), got {self.depth.shape}")
        if self.T_world_cam is not None:
            from .geometry import check_pose

            self.T_world_cam = check_pose(self.T_world_cam, f"{label} T_world_cam")

    def __repr__(self) -> str:
        """One line: name, timestamp, image size and kind, depth, ground truth, camera."""
        kind = "RGB" if self.image.ndim == 3 and self.image.shape[2] == 3 else "grey"
        extras = "".join(f", {what}" for what, has in (
            ("depth", self.depth is not None), ("ground truth", self.T_world_cam is not None))
            if has)
        cam = self.camera
        return (f"Frame({self.name or 'unnamed'}, t={float(self.timestamp):.3f}, "
                f"{cam.width}x{cam.height} {kind} {self.image.dtype}{extras}, "
                f"fx={cam.fx:.2f} fy={cam.fy:.2f} cx={cam.cx:.2f} cy={cam.cy:.2f})")

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
