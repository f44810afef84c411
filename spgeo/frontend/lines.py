"""Line segments of an image (OpenCV), returned as arrays.

:func:`detect_line_segments` runs OpenCV's fast line detector
(``cv2.ximgproc.createFastLineDetector``, opencv-contrib) or, where that is
missing or ``LineDetectorConfig.method == "lsd"``, the LSD detector
(``cv2.createLineSegmentDetector``), then keeps segments that are long enough.
An image without lines (blank, noise) gives an empty :class:`LineSegments`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from ..configs import config_class
from ..images import to_float_image

__all__ = ["LineDetectorConfig", "LineSegments", "detect_line_segments"]

logger = logging.getLogger(__name__)


@config_class
@dataclass(frozen=True)
class LineDetectorConfig:
    """Options of :func:`detect_line_segments`.

    Attributes:
        method: ``"fld"`` (fast line detector; falls back to LSD when
            opencv-contrib is missing) or ``"lsd"``.
        min_length_frac: segments shorter than this fraction of the image
            diagonal are dropped.
        canny_low, canny_high: FLD's Canny thresholds (grey levels 0-255).
        distance_threshold: FLD's maximal distance of a pixel to its segment
            (pixels).
        blur_sigma: Gaussian pre-blur (pixels; 0 disables), which suppresses
            texture and sensor noise.
    """

    method: str = "fld"
    min_length_frac: float = 0.025
    canny_low: float = 30.0
    canny_high: float = 90.0
    distance_threshold: float = 1.414
    blur_sigma: float = 0.8

    def __post_init__(self) -> None:
        if self.method not in ("fld", "lsd"):
            raise ValueError(f"LineDetectorConfig: method must be 'fld' or 'lsd', "
                             f"got {self.method!r}")
        if not 0.0 <= self.min_length_frac < 1.0:
            raise ValueError(f"LineDetectorConfig: min_length_frac must be in [0, 1), "
                             f"got {self.min_length_frac}")
        if self.blur_sigma < 0:
            raise ValueError(f"LineDetectorConfig: blur_sigma must be >= 0, got {self.blur_sigma}")


@dataclass
class LineSegments:
    """Line segments in pixel coordinates (u right, v down).

    Attributes:
        endpoints: (N, 4) float64 ``(u1, v1, u2, v2)``.
        width, height: image size the segments were found in.
    """

    endpoints: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        self.endpoints = np.asarray(self.endpoints, dtype=np.float64).reshape(-1, 4)

    def __len__(self) -> int:
        return int(self.endpoints.shape[0])

    @property
    def lengths(self) -> np.ndarray:
        """(N,) segment lengths in pixels."""
        e = self.endpoints
        return np.hypot(e[:, 2] - e[:, 0], e[:, 3] - e[:, 1])

    @property
    def midpoints(self) -> np.ndarray:
        """(N, 2) segment midpoints ``(u, v)``."""
        e = self.endpoints
        return 0.5 * (e[:, :2] + e[:, 2:])

    def subset(self, keep: np.ndarray) -> "LineSegments":
        """Segments selected by a bool mask or index array."""
        return LineSegments(self.endpoints[keep], self.width, self.height)


def _grey_u8(image: np.ndarray, blur_sigma: float) -> np.ndarray:
    img = to_float_image(image)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if blur_sigma > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), blur_sigma)
    return np.clip(np.round(grey * 255.0), 0, 255).astype(np.uint8)


def detect_line_segments(image: np.ndarray, config: LineDetectorConfig = LineDetectorConfig()
                         ) -> LineSegments:
    """Line segments of ``image`` ((H, W, 3) RGB or (H, W) grey; uint8/uint16/float [0, 1]).

    Returns the segments at least ``config.min_length_frac`` of the image
    diagonal long (possibly none).  Raises ``ValueError`` on a wrong shape.
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {image.shape}")
    h, w = image.shape[:2]
    grey = _grey_u8(image, config.blur_sigma)
    use_fld = config.method == "fld" and hasattr(cv2, "ximgproc") and hasattr(
        cv2.ximgproc, "createFastLineDetector")
    min_len = config.min_length_frac * float(np.hypot(w, h))
    if use_fld:
        det = cv2.ximgproc.createFastLineDetector(
            length_threshold=max(int(np.floor(min_len)), 2),
            distance_threshold=float(config.distance_threshold),
            canny_th1=float(config.canny_low), canny_th2=float(config.canny_high),
            canny_aperture_size=3, do_merge=False)
        raw = det.detect(grey)
    else:
        raw = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(grey)[0]
    seg = LineSegments(np.zeros((0, 4)) if raw is None else raw.reshape(-1, 4), w, h)
    seg = seg.subset(seg.lengths >= min_len)
    logger.debug("detect_line_segments(%s): %d segments", "fld" if use_fld else "lsd", len(seg))
    return seg
