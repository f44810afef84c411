"""Single-image surface normals from an ONNX model, converted to spgeo's convention.

spgeo's convention (docs/design.md §1 / :class:`~spgeo.frontend.base.NormalEstimator`):
OpenCV camera frame, x right, y down, z forward; normals point towards the
camera, so a wall facing the camera has ``n = (0, 0, -1)``.

Every network has its own axes and sign.  :class:`NormalOnnxConfig` declares
it either by a named preset (:data:`NORMAL_CONVENTIONS`), by a sentence such as
``"x right, y up, z towards viewer"`` (see :func:`parse_convention`), or by an
explicit 3x3 signed permutation ``model_to_spgeo`` (``n_spgeo = M @ n_model``).
Conventions of real models cannot be verified offline: run
:func:`check_convention_on_plane` on a new model, which renders a synthetic
room with known normals and ranks all 48 signed permutations by angular error.
"""
from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, Optional, Tuple

import numpy as np

from ..camera import PinholeCamera
from ..configs import config_class
from .normal_conventions import (NORMAL_CONVENTIONS, ConventionScore, RawNormalModel,
                                 check_convention_on_plane, parse_convention, render_synthetic_room,
                                 signed_permutations)
from .onnx_runtime import (ImageIOConfig, as_rgb01, check_size, image_input, io_nodes,
                           open_session, resize_map, to_hwc, uncrop)

__all__ = [
    "NormalOnnxConfig", "NORMAL_CONVENTIONS", "NORMAL_PRESETS", "NormalPrediction",
    "NormalModel", "parse_convention", "signed_permutations", "render_synthetic_room",
    "ConventionScore", "check_convention_on_plane",
]

logger = logging.getLogger(__name__)


# ----------------------------------------------------------------- config
@config_class
@dataclass(frozen=True)
class NormalOnnxConfig(ImageIOConfig):
    """The I/O contract and convention of a single-image normal network.

    The shared I/O fields (``resize_mode`` ... ``intra_op_num_threads``) come
    from :class:`~spgeo.frontend.onnx_runtime.ImageIOConfig` and are keyword-only.

    Attributes:
        model_path: ``.onnx`` file.
        input_size: ``(height, width)`` fed to the network ((480, 640), the
            authors' ScanNet model); ``None`` feeds the image at its own size
            (fully convolutional / dynamic models).
        resize_mode: ``"stretch"`` (default; resize to ``input_size``) or
            ``"letterbox"`` (keep aspect, centre-pad to ``input_size``; the
            pad is cropped from the output).
        pad_value: letterbox pad colour in ``input_range`` units; ``None``
            (default) pads with ``mean`` (zero after normalisation).
        input_name / output_name: tensor names; ``None`` (default) accepts the
            model's only input / its first output.  Given names must exist.
        confidence_output_name: optional separate confidence output (e.g.
            ``normal_confidence``).  A 4-channel normal output's 4th channel
            is read as confidence (e.g. a kappa) whatever this says.
        input_range: ``"0-1"`` (default) or ``"0-255"`` pixel scale before
            normalisation.
        mean, std: per-channel normalisation in ``input_range`` units
            (default ImageNet (0.485, 0.456, 0.406) / (0.229, 0.224, 0.225)).
        channel_order: ``"RGB"`` (default) or ``"BGR"``.
        layout / output_layout: ``"NCHW"`` (default) or ``"NHWC"``.
        output_encoding: ``"unit"`` (default; raw vectors, renormalised) or
            ``"rgb01"`` (``[0, 1]`` colour-coded, mapped by ``2 x - 1``).
        convention: named convention or sentence (see :func:`parse_convention`);
            default ``"spgeo"``.
        model_to_spgeo: explicit 3x3 matrix, overrides ``convention``.
        convention_verified: False logs a warning on load that the convention
            is a guess (set for presets nobody checked).
        providers: onnxruntime providers (``None``: CUDA if available, else CPU).
        intra_op_num_threads: onnxruntime intra-op threads (0 = default).
    """

    model_path: Optional[str] = None
    input_size: Optional[Tuple[int, int]] = (480, 640)
    confidence_output_name: Optional[str] = None
    output_encoding: str = "unit"
    convention: str = "spgeo"
    model_to_spgeo: Optional[Tuple[Tuple[float, float, float], ...]] = None
    convention_verified: bool = True

    def __post_init__(self) -> None:
        self.check_io([("output_encoding", ("unit", "rgb01"))])
        object.__setattr__(self, "input_size",
                           check_size(self.input_size, "NormalOnnxConfig.input_size"))
        self.matrix()  # validate the convention now

    def matrix(self) -> np.ndarray:
        """``model_to_spgeo`` as a 3x3 float array."""
        if self.model_to_spgeo is not None:
            M = np.asarray(self.model_to_spgeo, dtype=np.float64)
            if M.shape != (3, 3) or not np.all(np.isfinite(M)):
                raise ValueError(f"NormalOnnxConfig.model_to_spgeo must be a finite 3x3 matrix, "
                                 f"got {self.model_to_spgeo!r}")
            if abs(abs(np.linalg.det(M)) - 1) > 1e-6 or not np.allclose(np.abs(M @ M.T), np.eye(3),
                                                                       atol=1e-6):
                raise ValueError("NormalOnnxConfig.model_to_spgeo must be orthogonal "
                                 "(a signed permutation or rotation)")
            return M
        return parse_convention(self.convention)


#: Presets for known public models (URLs in :mod:`spgeo.models`).
#: ``metric3d-onnx``: onnx-community/metric3d-vit-* exports (outputs
#: ``predicted_depth``, ``predicted_normal``, ``normal_confidence``;
#: canonical 616x1064 letterbox input, 0-255 ImageNet normalisation).  Its
#: normal convention is NOT verified (guessed like DSINE, same lab of heads):
#: run :func:`check_convention_on_plane` before trusting it.
NORMAL_PRESETS: Mapping[str, NormalOnnxConfig] = MappingProxyType({
    "generic-480x640": NormalOnnxConfig(),
    "metric3d-onnx": NormalOnnxConfig(
        input_size=(616, 1064), resize_mode="letterbox", input_range="0-255",
        mean=(123.675, 116.28, 103.53), std=(58.395, 57.12, 57.375),
        output_name="predicted_normal", confidence_output_name="normal_confidence",
        convention="opencv-outward", convention_verified=False),
})


@dataclass
class NormalPrediction:
    """Normals in spgeo's convention, float32 (H, W, 3) unit (NaN where unknown),
    and the model's confidence channel resized to (H, W) if it has one."""

    normals: np.ndarray
    confidence: Optional[np.ndarray] = None


class NormalModel(RawNormalModel):
    """:class:`~spgeo.frontend.base.NormalEstimator` running an ONNX normal network.

    The image is converted to the network's input (size, range, normalisation,
    channel order, layout), the output is read (layout, encoding, optional
    confidence), mapped to spgeo's convention by ``model_to_spgeo``, resized
    bilinearly to the image size and renormalised to unit length.
    """

    uses_depth = False

    def __init__(self, config: NormalOnnxConfig) -> None:
        self.config = config
        self.M = config.matrix()
        self.session = open_session(config.model_path, "normal", config.providers,
                                    config.intra_op_num_threads)
        what = f"normal model {config.model_path}"
        outputs = io_nodes(self.session, outputs=True)
        self.input_name, self.input_dtype = image_input(
            self.session, config.input_name, config.layout, config.input_size, what,
            "NormalOnnxConfig")
        self.output_name = config.output_name or next(iter(outputs))
        for name in (self.output_name, config.confidence_output_name):
            if name is not None and name not in outputs:
                raise ValueError(f"{what}: expected output {name!r}, found outputs "
                                 f"{list(outputs)}")
        if not config.convention_verified:
            logger.warning("%s: the normal convention %r is an unverified guess; check it with "
                           "spgeo.frontend.onnx_normals.check_convention_on_plane", what,
                           config.convention if config.model_to_spgeo is None
                           else config.model_to_spgeo)

    @classmethod
    def from_path(cls, model_path, preset: str = "generic-480x640", **overrides) -> "NormalModel":
        """Build from a file and a :data:`NORMAL_PRESETS` name (fields overridable)."""
        if preset not in NORMAL_PRESETS:
            raise ValueError(f"unknown normal preset {preset!r}; known: {sorted(NORMAL_PRESETS)}")
        return cls(dataclasses.replace(NORMAL_PRESETS[preset], model_path=os.fspath(model_path),
                                       **overrides))

    # ---- pre / post processing
    def _prepare(self, rgb01: np.ndarray):
        return self.config.prepare(rgb01, self.config.input_size, self.input_dtype)

    def predict_raw(self, image: np.ndarray) -> NormalPrediction:
        """Model output in the MODEL's convention (unit, (H, W, 3)), resized to the image."""
        rgb = as_rgb01(image)
        h, w = rgb.shape[:2]
        x, crop = self._prepare(rgb)
        names = [self.output_name]
        if self.config.confidence_output_name:
            names.append(self.config.confidence_output_name)
        outs = self.session.run(names, {self.input_name: x})
        what = f"normal model {self.config.model_path}"
        raw = to_hwc(outs[0], self.config.output_layout, what)
        if raw.shape[-1] not in (3, 4):
            raise ValueError(f"{what}: output {self.output_name!r} has {raw.shape[-1]} channels, "
                             "expected 3 (normals) or 4 (normals + confidence)")
        conf = raw[..., 3:4] if raw.shape[-1] == 4 else None
        if len(outs) > 1:
            conf = to_hwc(outs[1], self.config.output_layout, what)[..., :1]
        n = raw[..., :3]
        if not np.all(np.isfinite(n)):
            raise ValueError(f"{what}: output contains NaN/inf")
        if self.config.output_encoding == "rgb01":
            n = 2.0 * n - 1.0
        n = resize_map(uncrop(n, crop), h, w, bilinear=True)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.where(norm > 1e-6, n / norm, np.nan).astype(np.float32)
        if conf is not None:
            conf = resize_map(uncrop(conf, crop), h, w, bilinear=True).reshape(h, w)
            conf = conf.astype(np.float32)
        return NormalPrediction(n, conf)

    def predict(self, image: np.ndarray) -> NormalPrediction:
        """Normals in spgeo's convention (and the confidence, if any) for ``image``."""
        raw = self.predict_raw(image)
        n = raw.normals @ self.M.T.astype(np.float32)
        return NormalPrediction(n.astype(np.float32), raw.confidence)

    def estimate(self, image: np.ndarray, camera: PinholeCamera,
                 depth: Optional[np.ndarray] = None) -> np.ndarray:
        """:class:`~spgeo.frontend.base.NormalEstimator` interface (depth is ignored)."""
        camera.check_image(image)
        return self.predict(image).normals
