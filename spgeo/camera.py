"""Pinhole camera with optional OpenCV (Brown-Conrady) distortion.

Conventions (docs/design.md §1): pixel ``u = (u, v)`` with ``u`` the column and ``v``
the row, pixel centres at integer coordinates.  The camera frame is OpenCV's:
x right, y down, z forward (along the optical axis).  Depths ``z`` are metres
along the optical axis (not ray length).

Unprojection ``x = z K^-1 [u, v, 1]^T``; projection ``pi(x) = (K x / z)[:2]``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from .checks import InputError, check_intrinsics, swapped_size_hint

__all__ = ["PinholeCamera"]


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics of an image of ``width`` x ``height`` pixels.

    Construction raises :class:`~spgeo.validation.InputError` (a ``ValueError``)
    for implausible intrinsics (:func:`spgeo.validation.check_intrinsics`: field of
    view, ``fx / fy`` ratio, principal point near the image).

    Attributes:
        fx, fy: focal lengths in pixels (must be > 0; data sets with a flipped
            axis, such as ICL-NUIM's negative ``fy``, are converted by their reader).
        cx, cy: principal point in pixels (pixel centres at integers).
        width, height: image size in pixels.
        distortion: optional OpenCV distortion coefficients
            ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``.  Projection and
            unprojection ignore distortion: undistort images first with
            :meth:`undistortion_maps` / :meth:`undistort_image`, which give
            images seen by :meth:`undistorted` (same K, no distortion).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: Optional[Tuple[float, ...]] = None

    def __post_init__(self) -> None:
        check_intrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height,
                         "PinholeCamera")
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("width", "height"):
            object.__setattr__(self, name, int(getattr(self, name)))
        if self.distortion is not None:
            dist = tuple(float(d) for d in np.asarray(self.distortion, dtype=float).ravel())
            if len(dist) not in (4, 5, 8) or not np.all(np.isfinite(dist)):
                raise InputError(
                    "PinholeCamera: distortion must hold 4, 5 or 8 finite OpenCV coefficients, "
                    f"got {self.distortion!r}")
            object.__setattr__(self, "distortion", dist if any(dist) else None)

    # ------------------------------------------------------------------ basics
    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int,
               distortion: Optional[Tuple[float, ...]] = None) -> "PinholeCamera":
        """Build from a 3x3 intrinsic matrix."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise InputError(f"PinholeCamera.from_K: K must be 3x3, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
            raise InputError("PinholeCamera.from_K: skewed intrinsics are not supported")
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, distortion)

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_inv(self) -> np.ndarray:
        return np.array([[1.0 / self.fx, 0.0, -self.cx / self.fx],
                         [0.0, 1.0 / self.fy, -self.cy / self.fy],
                         [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> Tuple[int, int]:
        """Image shape as ``(height, width)`` (numpy order)."""
        return (self.height, self.width)

    @property
    def size(self) -> Tuple[int, int]:
        """Image size as ``(width, height)`` (OpenCV order)."""
        return (self.width, self.height)

    def check_image(self, image: np.ndarray, name: str = "image") -> np.ndarray:
        """Raise :class:`~spgeo.validation.InputError` unless ``image`` is (H, W) or
        (H, W, C) of this camera's size (the message says when width and height
        look swapped)."""
        image = np.asarray(image)
        if image.ndim not in (2, 3) or image.shape[:2] != self.shape:
            raise InputError(
                f"{name} has shape {image.shape}, expected ({self.height}, {self.width}[, C]) "
                f"for this camera{swapped_size_hint(image.shape, self.shape)}")
        return image

    # ------------------------------------------------------- scaling/resizing
    def resized(self, width: int, height: int) -> "PinholeCamera":
        """Camera of the same view resampled to ``width`` x ``height`` pixels.

        Uses the convention of ``cv2.resize`` (image borders aligned, pixel
        centres at integers): ``cx' = (cx + 0.5) * sx - 0.5``.  Distortion
        coefficients are dimensionless and kept.
        """
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise ValueError(f"resized: size must be positive, got {width}x{height}")
        sx = width / self.width
        sy = height / self.height
        return PinholeCamera(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                             (self.cy + 0.5) * sy - 0.5, width, height, self.distortion)

    def scaled(self, factor: float) -> "PinholeCamera":
        """Camera for the image resized by ``factor`` (``cv2.resize`` convention).

        The new size is ``round(width * factor)`` x ``round(height * factor)``;
        focal lengths and principal point follow the exact per-axis ratio.
        """
        factor = float(factor)
        if not np.isfinite(factor) or factor <= 0:
            raise ValueError(f"scaled: factor must be finite and > 0, got {factor!r}")
        return self.resized(max(1, int(round(self.width * factor))),
                            max(1, int(round(self.height * factor))))

    def decimated(self, step: int = 2) -> "PinholeCamera":
        """Camera of an image decimated by keeping every ``step``-th pixel.

        Pixel ``i'`` of the decimated image is pixel ``step * i'`` of this one, so
        ``x' = x / step`` exactly (this is what :func:`spgeo.images.gaussian_pyramid`
        does after blurring).  Size becomes ``ceil(width / step)``.
        """
        step = int(step)
        if step < 1:
            raise ValueError(f"decimated: step must be >= 1, got {step}")
        return PinholeCamera(self.fx / step, self.fy / step, self.cx / step, self.cy / step,
                             -(-self.width // step), -(-self.height // step), self.distortion)

    def undistorted(self) -> "PinholeCamera":
        """The same intrinsics without distortion (the camera of undistorted images)."""
        return dataclasses.replace(self, distortion=None)

    # ------------------------------------------------------------ undistortion
    def undistortion_maps(self) -> Tuple[np.ndarray, np.ndarray]:
        """OpenCV remap tables (float32 ``map_x``, ``map_y``) that undistort an image.

        The output image has the same K and size (``cv2.initUndistortRectifyMap``
        with ``newCameraMatrix = K``).  Without distortion the maps are the identity.
        """
        import cv2

        dist = np.zeros(5) if self.distortion is None else np.asarray(self.distortion)
        map_x, map_y = cv2.initUndistortRectifyMap(self.K, dist, None, self.K, self.size,
                                                   cv2.CV_32FC1)
        return map_x, map_y

    def undistort_image(self, image: np.ndarray, interpolation: Optional[int] = None,
                        maps: Optional[Tuple[np.ndarray, np.ndarray]] = None) -> np.ndarray:
        """Undistort an image of this camera (bilinear by default; use
        ``cv2.INTER_NEAREST`` for depth or label images).  Pass ``maps`` from
        :meth:`undistortion_maps` to avoid recomputing them per frame."""
        import cv2

        image = self.check_image(image)
        if self.distortion is None:
            return image.copy()
        if maps is None:
            maps = self.undistortion_maps()
        interp = cv2.INTER_LINEAR if interpolation is None else interpolation
        return cv2.remap(image, maps[0], maps[1], interp, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)

    # ------------------------------------------------------------ projections
    def pixel_grid(self) -> Tuple[np.ndarray, np.ndarray]:
        """``(u, v)`` float arrays of shape (H, W): column and row of every pixel."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        return u, v

    def rays(self) -> np.ndarray:
        """(H, W, 3) rays ``K^-1 [u, v, 1]`` (z = 1) for every pixel."""
        u, v = self.pixel_grid()
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], -1)

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """3-D points in the camera frame (metres) of pixels ``uv`` (..., 2) at ``depth`` (...)."""
        uv = np.asarray(uv, dtype=np.float64)
        depth = np.asarray(depth, dtype=np.float64)
        if uv.shape[-1] != 2:
            raise ValueError(f"unproject: uv must have shape (..., 2), got {uv.shape}")
        if depth.shape != uv.shape[:-1]:
            raise ValueError(f"unproject: depth shape {depth.shape} does not match uv {uv.shape}")
        x = (uv[..., 0] - self.cx) / self.fx * depth
        y = (uv[..., 1] - self.cy) / self.fy * depth
        return np.stack([x, y, depth], axis=-1)

    def unproject_depth_map(self, depth: np.ndarray) -> np.ndarray:
        """(H, W, 3) camera-frame points of a depth map (metres); invalid depth gives NaN."""
        depth = np.asarray(self.check_image(depth, "depth"), dtype=np.float64)
        if depth.ndim != 2:
            raise ValueError(f"depth must be (H, W), got {depth.shape}")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
        return self.rays() * depth[..., None]

    def project(self, points: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points (..., 3) -> (pixels (..., 2), depth z (...)).

        Points with ``z <= 0`` get NaN pixel coordinates (they are behind the camera).
        """
        points = np.asarray(points, dtype=np.float64)
        if points.shape[-1] != 3:
            raise ValueError(f"project: points must have shape (..., 3), got {points.shape}")
        z = points[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = np.where(z > 0, 1.0 / z, np.nan)
        u = self.fx * points[..., 0] * inv_z + self.cx
        v = self.fy * points[..., 1] * inv_z + self.cy
        return np.stack([u, v], axis=-1), z

    def in_image(self, uv: np.ndarray, border: float = 0.0) -> np.ndarray:
        """Boolean mask of pixel coordinates inside ``[border, W-1-border] x [border, H-1-border]``."""
        uv = np.asarray(uv)
        u, v = uv[..., 0], uv[..., 1]
        with np.errstate(invalid="ignore"):
            return ((u >= border) & (u <= self.width - 1 - border)
                    & (v >= border) & (v <= self.height - 1 - border))

    # --------------------------------------------------------------- serialise
    def to_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "width": self.width, "height": self.height,
                "distortion": None if self.distortion is None else list(self.distortion)}

    @classmethod
    def from_dict(cls, d: dict) -> "PinholeCamera":
        """Inverse of :meth:`to_dict`; :class:`~spgeo.validation.InputError` for a
        missing key or implausible intrinsics."""
        if not isinstance(d, dict):
            raise InputError(f"camera: expected a JSON object, got {type(d).__name__}")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in d]
        if missing:
            raise InputError(f"camera: missing key(s) {', '.join(missing)}")
        dist = d.get("distortion")
        return cls(d["fx"], d["fy"], d["cx"], d["cy"], int(d["width"]), int(d["height"]),
                   None if dist is None else tuple(dist))

    def __repr__(self) -> str:  # compact, notebook friendly
        dist = "" if self.distortion is None else f", distortion={self.distortion}"
        return (f"PinholeCamera(fx={self.fx:.3f}, fy={self.fy:.3f}, cx={self.cx:.3f}, "
                f"cy={self.cy:.3f}, {self.width}x{self.height}{dist})")
