"""Surface normals from a monocular depth network (ONNX), via :func:`normals_from_depth`.

Any single-image depth network exported to ONNX (e.g. Depth Anything V2,
MiDaS / DPT, metric-depth heads) becomes a
:class:`~spgeo.frontend.base.NormalEstimator`: the image is fed like the
normal-network path feeds it (:func:`~spgeo.frontend.onnx_runtime.prepare_image`:
size, range, mean / std, channel order, layout), the output map is turned
into depth up to an unknown global scale, resized to the image and
differentiated by :func:`spgeo.frontend.depth_normals.normals_from_depth`.
Normals do not depend on the global scale of depth, so relative depth is
enough.  The estimator reads no sensor depth (``uses_depth = False``).

Output kinds (:attr:`DepthOnnxConfig.output_kind`), ``o`` the network output:

* ``"depth"``: ``o`` is depth, metric or up to scale (``z = o``; ``o <= 0``
  is invalid).  Normals are exact for exact depth.
* ``"inverse_depth"``: ``o`` is proportional to ``1 / z`` (no offset):
  ``z = 1 / o`` up to scale; exact for exact inverse depth.
* ``"disparity"``: ``o`` is *affine-invariant* relative inverse depth,
  ``o = a / z + b`` with unknown ``a > 0`` and shift ``b`` (Depth Anything,
  MiDaS).  The shift cannot be recovered from one image, and it changes the
  geometry: on a plane ``1 / z`` is affine in the pixel coordinates, so a
  wrong shift maps planes to planes of another orientation.  The output is
  normalised by its 99th percentile ``p`` and read as
  ``z = 1 / (o / p + disparity_shift)`` (default shift 0: ``b = 0`` assumed),
  so **normals from affine-invariant outputs are approximate**; they are exact
  only when ``disparity_shift = -b / p`` after the scaling.

Resampling to the image size is done on inverse depth (bilinear), which is
affine in the pixel coordinates on a plane, so planes stay planes.  Inverse
depth at or below ``min_inverse`` (after the percentile normalisation: depth
beyond ``1 / min_inverse`` times the near-range depth) is invalid (NaN depth).

Metric depth: a config with ``metric=True`` (``"depth"`` or ``"inverse_depth"``
outputs in metres / inverse metres, e.g. the ``"fastdepth"`` preset) also gives
:meth:`OnnxDepthNormals.predict_metric`: the same inverse-depth resampling
without the percentile normalisation, so the result is in metres
(:class:`~spgeo.frontend.base.MetricDepthEstimator`).
"""
from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from .depth_normals import DepthNormalEstimatorConfig, normals_from_depth
from .onnx_runtime import (ImageIOConfig, as_rgb01, check_size, image_input, io_nodes,
                           open_session, resize_map, to_hwc, uncrop)

__all__ = ["DepthOnnxConfig", "DEPTH_PRESETS", "DEPTH_OUTPUT_KINDS", "OnnxDepthNormals",
           "static_size_mismatch", "network_input_size"]

logger = logging.getLogger(__name__)

DEPTH_OUTPUT_KINDS = ("depth", "inverse_depth", "disparity")
_PERCENTILE = 99.0


@config_class
@dataclass(frozen=True)
class DepthOnnxConfig(ImageIOConfig):
    """The I/O contract of a single-image depth network and the depth -> normals step.

    Attributes:
        model_path: ``.onnx`` file.
        input_size: fixed ``(height, width)`` fed to the network (a multiple
            of ``multiple_of`` on both sides); ``None`` (dynamic-size models)
            sizes each image by :func:`network_input_size`.  A model that
            declares a static size is fed that size when this is ``None``.
        aspect_side: ``input_size=None``: keep the aspect ratio and scale so
            that the side whose scale is nearer 1 becomes ``aspect_side``
            (the DPT / Depth Anything processor rule).  Default 518.
        multiple_of: each network side is rounded to a multiple of this
            (14: ViT patch size).  Default 14.
        resize_mode, pad_value, input_name, output_name, input_range, mean,
            std, channel_order, layout, output_layout, providers,
            intra_op_num_threads: keyword-only, see
            :class:`~spgeo.frontend.onnx_runtime.ImageIOConfig` (``"letterbox"``
            needs a fixed ``input_size``; a rank-3 ``(1, h, w)`` or rank-2
            output is one channel whatever ``output_layout`` says).
        output_kind: ``"depth"``, ``"inverse_depth"`` or ``"disparity"``
            (module docstring).  Default ``"depth"``.
        disparity_shift: ``"disparity"`` only: the assumed shift added to the
            percentile-normalised output before inverting.  Default 0.
        min_inverse: normalised inverse depth at or below this is invalid.
            Default 1e-3.
        metric: the output is metric (``"depth"``: metres, ``"inverse_depth"``:
            1 / metres), which enables :meth:`OnnxDepthNormals.predict_metric`.
            Not allowed with ``"disparity"`` (affine-invariant).  Default False.
        normals: :class:`~spgeo.frontend.depth_normals.DepthNormalEstimatorConfig`
            of the depth -> normals step (default PCA, holes filled from the
            nearest known normal).
    """

    model_path: Optional[str] = None
    input_size: Optional[Tuple[int, int]] = (518, 518)
    aspect_side: int = 518
    multiple_of: int = 14
    output_kind: str = "depth"
    disparity_shift: float = 0.0
    min_inverse: float = 1e-3
    metric: bool = False
    normals: DepthNormalEstimatorConfig = field(
        default_factory=lambda: DepthNormalEstimatorConfig(fill_holes=True))

    def __post_init__(self) -> None:
        self.check_io([("output_kind", DEPTH_OUTPUT_KINDS)])
        object.__setattr__(self, "input_size",
                           check_size(self.input_size, "DepthOnnxConfig.input_size"))
        if int(self.multiple_of) != self.multiple_of or self.multiple_of < 1:
            raise ValueError(f"DepthOnnxConfig.multiple_of must be an integer >= 1, "
                             f"got {self.multiple_of!r}")
        if self.input_size is not None and any(s % self.multiple_of for s in self.input_size):
            raise ValueError(f"DepthOnnxConfig.input_size {self.input_size} must be a multiple "
                             f"of multiple_of={self.multiple_of} on both sides")
        if self.aspect_side < self.multiple_of:
            raise ValueError(f"DepthOnnxConfig.aspect_side must be >= multiple_of, "
                             f"got {self.aspect_side!r}")
        if self.resize_mode == "letterbox" and self.input_size is None:
            raise ValueError("DepthOnnxConfig.resize_mode 'letterbox' needs a fixed input_size")
        if not np.isfinite(self.disparity_shift):
            raise ValueError(f"DepthOnnxConfig.disparity_shift must be finite, "
                             f"got {self.disparity_shift!r}")
        if self.metric and self.output_kind == "disparity":
            raise ValueError("DepthOnnxConfig.metric needs output_kind 'depth' or "
                             "'inverse_depth' (a 'disparity' output is affine-invariant)")
        if not (self.min_inverse > 0):
            raise ValueError(f"DepthOnnxConfig.min_inverse must be > 0, got {self.min_inverse!r}")
        if not isinstance(self.normals, DepthNormalEstimatorConfig):
            raise ValueError("DepthOnnxConfig.normals must be a DepthNormalEstimatorConfig, "
                             f"got {type(self.normals).__name__}")


#: Presets for known public models (URLs in :mod:`spgeo.models`).
#: ``depth-anything-v2``: onnx-community/depth-anything-v2-* exports (input
#: ``pixel_values`` (1, 3, H, W) dynamic, output ``predicted_depth`` (1, H, W):
#: affine-invariant relative inverse depth; DPT processor: keep aspect, side
#: nearer 518 -> 518, multiples of 14, ImageNet mean / std on [0, 1]).
#: ``fastdepth``: FastDepth (NYU Depth v2) exported to ONNX (input
#: ``serving_default_input.1_0`` (1, 3, 224, 224) RGB in [0, 1], no mean / std,
#: image stretched to 224 x 224; output ``StatefulPartitionedCall_0``
#: (1, 1, 224, 224): metric depth in metres).
DEPTH_PRESETS: Mapping[str, DepthOnnxConfig] = MappingProxyType({
    "generic-depth-518": DepthOnnxConfig(),
    "depth-anything-v2": DepthOnnxConfig(
        input_size=None, aspect_side=518, multiple_of=14, input_name="pixel_values",
        output_name="predicted_depth", output_kind="disparity"),
    "fastdepth": DepthOnnxConfig(
        input_size=(224, 224), resize_mode="stretch", input_range="0-1",
        mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0), channel_order="RGB", layout="NCHW",
        output_layout="NCHW", input_name="serving_default_input.1_0",
        output_name="StatefulPartitionedCall_0", output_kind="depth", metric=True),
})


def network_input_size(height: int, width: int, side: int = 518,
                       multiple_of: int = 14) -> Tuple[int, int]:
    """``(h, w)`` fed to a dynamic-size network for a ``height`` x ``width`` image.

    Aspect kept; the scale is whichever of ``side / height`` and
    ``side / width`` is nearer 1; each side rounded to a multiple of
    ``multiple_of`` (at least one multiple).
    """
    if height <= 0 or width <= 0:
        raise ValueError(f"image size must be > 0, got {height}x{width}")
    s_h, s_w = side / height, side / width
    s = s_w if abs(1.0 - s_w) < abs(1.0 - s_h) else s_h
    m = int(multiple_of)
    return (max(m, int(round(height * s / m)) * m), max(m, int(round(width * s / m)) * m))


def _one_channel_output(session, name: Optional[str], layout: str, what: str) -> str:
    """The name of the model's depth output (``name``, or its first output when ``None``);
    ``ValueError`` naming ``what`` when it is missing, not rank 2-4, or declares a static
    channel count other than 1 (rank 4, channel axis of ``layout``)."""
    outputs = io_nodes(session, outputs=True)
    name = name or next(iter(outputs))
    if name not in outputs:
        raise ValueError(f"{what}: expected output {name!r}, found outputs {list(outputs)}")
    shape = list(outputs[name].shape)
    if len(shape) not in (2, 3, 4):
        raise ValueError(f"{what}: output {name!r} must be a one-channel map (rank 2-4), "
                         f"model declares {shape}")
    channels = shape[1 if layout == "NCHW" else 3] if len(shape) == 4 else 1
    if isinstance(channels, int) and channels not in (1, -1):
        raise ValueError(f"{what}: output {name!r} must be a one-channel map, model declares "
                         f"{shape} ({channels} channels)")
    return name


def static_size_mismatch(model_path, input_name: str, static: Tuple[int, int],
                         input_size: Tuple[int, int], preset: Optional[str] = None) -> str:
    """The one-line message for a depth model whose declared static input size
    ``static`` ``(h, w)`` is not the config's ``input_size``: it names the file,
    both sizes, the preset (when known) and the fix (register the file with a
    :data:`DEPTH_PRESETS` preset of that input size, or another preset / input
    size).  Presets are never guessed: mean / std cannot be read from a model."""
    fits = sorted(n for n, p in DEPTH_PRESETS.items()
                  if p.input_size is not None and tuple(p.input_size) == tuple(static))
    used = f"preset {preset!r} feeds" if preset else "DepthOnnxConfig.input_size is"
    if fits:
        fix = (f"register the file with the preset its network was trained with, e.g. "
               f"`spgeo models register NAME {model_path} --preset {fits[0]}`, and give NAME"
               + (f" (presets of that size: {', '.join(fits)})" if len(fits) > 1 else ""))
    else:
        fix = (f"no preset takes {static[0]}x{static[1]}: register the file with a preset of "
               f"that size or set DepthOnnxConfig.input_size={tuple(static)}")
    return (f"depth model {model_path}: input {input_name!r} is a static {static[0]}x{static[1]} "
            f"image but {used} {input_size[0]}x{input_size[1]} (input_size is "
            f"{tuple(input_size)}); {fix}")


class OnnxDepthNormals:
    """:class:`~spgeo.frontend.base.NormalEstimator`: depth network -> normals.

    ``estimate`` returns float32 (H, W, 3) unit normals in spgeo's convention
    (towards the camera), computed by :func:`normals_from_depth` from
    :meth:`predict_depth`.  ``uses_depth = False``: any sensor depth passed
    to ``estimate`` is ignored.  With a ``metric`` config it is also a
    :class:`~spgeo.frontend.base.MetricDepthEstimator` (:meth:`predict_metric`).
    Raises ``ValueError`` naming the model file when the model breaks the
    contract (not one 3-channel image input of the config's static size, an
    output that is not one channel, NaN output).
    """

    uses_depth = False

    def __init__(self, config: DepthOnnxConfig, preset: Optional[str] = None) -> None:
        self.config = config
        self.what = f"depth model {config.model_path}"
        self.session = open_session(config.model_path, "depth", config.providers,
                                    config.intra_op_num_threads)
        self.input_name, self.input_dtype = image_input(
            self.session, config.input_name, config.layout, None, self.what, "DepthOnnxConfig")
        in_shape = list(io_nodes(self.session)[self.input_name].shape)
        hw = in_shape[2:4] if config.layout == "NCHW" else in_shape[1:3]
        self.static_size = (tuple(hw) if all(isinstance(d, int) and d > 0 for d in hw)
                            else None)
        if (self.static_size is not None and config.input_size is not None
                and self.static_size != tuple(config.input_size)):
            raise ValueError(static_size_mismatch(config.model_path, self.input_name,
                                                  self.static_size, config.input_size, preset))
        self.output_name = _one_channel_output(self.session, config.output_name,
                                               config.output_layout, self.what)

    @classmethod
    def from_path(cls, model_path, preset: str = "generic-depth-518",
                  **overrides) -> "OnnxDepthNormals":
        """Build from a file and a :data:`DEPTH_PRESETS` name (fields overridable)."""
        if preset not in DEPTH_PRESETS:
            raise ValueError(f"unknown depth preset {preset!r}; known: {sorted(DEPTH_PRESETS)}")
        return cls(dataclasses.replace(DEPTH_PRESETS[preset], model_path=os.fspath(model_path),
                                       **overrides), preset=preset)

    def input_size_for(self, height: int, width: int) -> Tuple[int, int]:
        """The network input ``(h, w)`` used for a ``height`` x ``width`` image."""
        cfg = self.config
        if cfg.input_size is not None:
            return cfg.input_size
        if self.static_size is not None:
            return self.static_size
        return network_input_size(height, width, cfg.aspect_side, cfg.multiple_of)

    def predict_raw(self, image: np.ndarray) -> np.ndarray:
        """The network output as a float32 (h, w) map at the network's resolution
        (letterbox pad cropped), before any conversion."""
        cfg = self.config
        rgb = as_rgb01(image)
        size = self.input_size_for(*rgb.shape[:2])
        x, crop = cfg.prepare(rgb, size, self.input_dtype)
        out = self.session.run([self.output_name], {self.input_name: x})[0]
        arr = np.asarray(out, np.float32)
        if arr.ndim == 3 and arr.shape[0] == 1 and cfg.output_layout == "NHWC":
            arr = arr[0]  # (1, h, w): batch of one-channel maps
        raw = to_hwc(arr, cfg.output_layout, self.what)
        if raw.shape[-1] != 1:
            raise ValueError(f"{self.what}: output {self.output_name!r} has shape {out.shape}; "
                             "expected a one-channel map ((1, h, w), (1, 1, h, w), (h, w))")
        if not np.all(np.isfinite(raw)):
            raise ValueError(f"{self.what}: output contains NaN/inf")
        return uncrop(raw[..., 0], crop)

    def _network_inverse(self, image: np.ndarray) -> np.ndarray:
        """The output as inverse depth at the network's resolution, float32 (h, w)
        (``"depth"``: ``1 / o``, 0 where ``o <= 0``; otherwise ``o``)."""
        raw = self.predict_raw(image)
        if self.config.output_kind == "depth":
            with np.errstate(divide="ignore"):
                raw = np.where(raw > 0, 1.0 / np.where(raw > 0, raw, 1.0), 0.0)
        return raw.astype(np.float32)

    def predict_metric(self, image: np.ndarray) -> np.ndarray:
        """Metric depth in metres, float32 (H, W) at the image size, NaN where invalid.

        ``image``: (H, W) grey or (H, W, 3) RGB, uint8 / uint16 or float in [0, 1]
        (:func:`~spgeo.frontend.onnx_runtime.as_rgb01`; grey is repeated into 3
        channels).  The output is resampled on inverse depth (bilinear) without any
        normalisation; pixels with no positive inverse depth, or interpolated from a
        network pixel without one, are NaN.  Raises
        ``ValueError`` naming the model file when the config is not ``metric``
        (an affine-invariant or up-to-scale model has no metric depth), for a
        NaN / inf output or one with no valid pixel; ``InputError`` (a
        ``ValueError``) for a bad image.
        """
        if not self.config.metric:
            raise ValueError(f"{self.what}: not a metric-depth model (DepthOnnxConfig.metric "
                             f"is False, output_kind {self.config.output_kind!r}); use "
                             "predict_depth (depth up to scale) or a metric preset such as "
                             "'fastdepth'")
        h, w = np.asarray(image).shape[:2]
        inv_net = self._network_inverse(image)
        if not np.any(inv_net > 0):
            raise ValueError(f"{self.what}: output has no positive {self.config.output_kind} "
                             "value")
        inv = resize_map(inv_net, h, w, bilinear=True)
        # a pixel interpolated from an invalid network pixel is invalid too
        full = resize_map((inv_net > 0).astype(np.float32), h, w, bilinear=True)
        valid = (inv > 0) & (full > 1.0 - 1e-4)
        with np.errstate(divide="ignore"):
            return np.where(valid, 1.0 / np.where(valid, inv, 1.0), np.nan).astype(np.float32)

    def predict_depth(self, image: np.ndarray) -> np.ndarray:
        """Depth up to an unknown global scale, float32 (H, W) at the image size, NaN
        where invalid (see the module docstring for each output kind)."""
        cfg = self.config
        h, w = np.asarray(image).shape[:2]
        inv = resize_map(self._network_inverse(image), h, w, bilinear=True)
        positive = inv[inv > 0]
        if positive.size == 0:
            raise ValueError(f"{self.what}: output has no positive {cfg.output_kind} value")
        inv = inv / np.float32(np.percentile(positive, _PERCENTILE))
        if cfg.output_kind == "disparity":
            inv = inv + np.float32(cfg.disparity_shift)
        valid = inv > cfg.min_inverse
        if not valid.any():
            raise ValueError(f"{self.what}: no pixel has inverse depth above min_inverse="
                             f"{cfg.min_inverse} (disparity_shift={cfg.disparity_shift})")
        with np.errstate(divide="ignore"):
            return np.where(valid, 1.0 / np.where(valid, inv, 1.0), np.nan).astype(np.float32)

    def estimate(self, image: np.ndarray, camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        """:class:`~spgeo.frontend.base.NormalEstimator` interface (``depth`` is ignored)."""
        camera.check_image(image)
        return normals_from_depth(self.predict_depth(image), camera, self.config.normals)

    def __repr__(self) -> str:
        return f"OnnxDepthNormals({self.config.model_path!r}, kind={self.config.output_kind!r})"
