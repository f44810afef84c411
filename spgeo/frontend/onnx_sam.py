"""SAM-style promptable segmentation with onnxruntime, and the DESIGN.md §3 mask generator.

Two pieces:

* :class:`SegmentModel` runs an image encoder once per image and a prompt
  decoder per point prompt.  It speaks two I/O contracts through small
  adapters (``SamOnnxConfig.flavour``):

  - ``"sam"``: the official segment-anything ONNX decoder
    (``scripts/export_onnx_model.py`` / ``SamOnnxModel``): inputs
    ``image_embeddings`` (1,256,64,64), ``point_coords`` (1,N,2),
    ``point_labels`` (1,N), ``mask_input`` (1,1,256,256), ``has_mask_input``
    (1,), ``orig_im_size`` (2,) -> outputs ``masks`` (1,C,H,W) logits at the
    original size, ``iou_predictions`` (1,C), ``low_res_masks``.  ``C`` is 4
    for an export without ``--return-single-mask`` (token 0 is the
    single-mask output; like ``SamPredictor(multimask_output=True)`` we keep
    tokens 1..3), 3 for exports that already drop it, and 1 for
    ``--return-single-mask`` exports (then every query has one candidate).
    The encoder takes the SAM pre-processed image: longest side resized to
    1024, RGB 0-255 normalised by ``pixel_mean`` / ``pixel_std``, zero-padded
    bottom/right to 1024x1024, NCHW float32 (``encoder_layout="nchw"``), or
    the resized, un-normalised HWC image for exports that pre-process inside
    the graph (``encoder_layout="hwc-raw"``, segment-anything's
    ``ImageEncoderOnnxModel(use_preprocess=True)``).
  - ``"efficientsam"``: the EfficientSAM split export (labelme / yformer
    ``export_to_onnx.py``): encoder ``batched_images`` (1,3,H,W) RGB in
    [0, 1] at the original size -> ``image_embeddings``; decoder
    ``image_embeddings``, ``batched_point_coords`` (1,Q,P,2) in original
    pixels, ``batched_point_labels`` (1,Q,P), ``orig_im_size`` int64 (2,) ->
    ``output_masks`` (1,Q,3,H,W) logits, ``iou_predictions`` (1,Q,3).  Many
    prompts go through one decoder call.

* :class:`SamMaskGenerator` implements :class:`~spgeo.frontend.base.Segmenter`
  exactly as DESIGN.md §3 describes (random prompts, stability filter,
  smallest stable candidate, prompt-inside rule, box-NMS, active prompts in
  the uncovered area).  It does not split masks into connected parts (the
  pipeline does that for every front-end).

Pixel convention: prompts are integer pixels ``(u, v)`` (column, row) with
pixel centres at integers, as :mod:`spgeo.camera`; the official SAM decoder
adds 0.5 itself.
"""
from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..camera import PinholeCamera
from ..images import to_float_image
from .base import Segmentation

__all__ = [
    "SamOnnxConfig", "SAM_PRESETS", "SamEmbedding", "SegmentModel",
    "SamMaskGeneratorConfig", "SamMaskGenerator", "box_nms", "mask_boxes",
    "stability_scores",
]

logger = logging.getLogger(__name__)

SAM_DECODER_INPUTS = ("image_embeddings", "point_coords", "point_labels", "mask_input",
                      "has_mask_input", "orig_im_size")
SAM_DECODER_OUTPUTS = ("masks", "iou_predictions")
EFFICIENTSAM_DECODER_INPUTS = ("image_embeddings", "batched_point_coords",
                               "batched_point_labels", "orig_im_size")
EFFICIENTSAM_DECODER_OUTPUTS = ("output_masks", "iou_predictions")

_ORT_TYPES = {
    "tensor(float)": np.float32, "tensor(double)": np.float64, "tensor(float16)": np.float16,
    "tensor(int64)": np.int64, "tensor(int32)": np.int32,
}


# --------------------------------------------------------------------------- config
@dataclass(frozen=True)
class SamOnnxConfig:
    """The I/O contract of a SAM-style encoder/decoder pair.

    Attributes:
        encoder_path: image-encoder ``.onnx`` file (required to build a model).
        decoder_path: prompt-decoder ``.onnx`` file (required).
        flavour: ``"sam"`` (official segment-anything decoder contract) or
            ``"efficientsam"`` (EfficientSAM split export).  Default ``"sam"``.
        input_size: side of the square encoder input (SAM: 1024).  Only used
            by the ``"sam"`` flavour, which resizes the longest image side to it.
        pixel_mean, pixel_std: RGB normalisation on 0-255 values
            (SAM defaults (123.675, 116.28, 103.53) / (58.395, 57.12, 57.375)).
        encoder_layout: ``"nchw"`` (default: normalised, padded (1,3,S,S)) or
            ``"hwc-raw"`` (resized (h,w,3) 0-255 float; the graph normalises and
            pads).  ``"sam"`` flavour only.
        encoder_input_name: name of the encoder input; ``None`` (default)
            accepts the encoder's only input whatever its name (exports use
            ``x``, ``image``, ``input_image``, ``batched_images``).  A given
            name must exist or loading raises ``ValueError``.
        encoder_output_name: encoder output holding the embedding
            (default ``"image_embeddings"``); ``None`` takes the first output.
        mask_threshold: logit threshold of a mask (SAM: 0.0).
        upsample_to: optional ``(height, width)``: the image is resized to this
            size before encoding and decoding (the authors ran SAM on 480x640
            images upsampled to (960, 1280)); masks come back at the original
            size.  Default ``None`` (no resampling).
        prompt_batch_size: prompts per decoder call for decoders that take
            several (EfficientSAM); the official SAM decoder takes one prompt
            set per call whatever this says.  Default 16.
        providers: onnxruntime execution providers; ``None`` (default) uses
            CUDA when onnxruntime has it, else CPU.
        intra_op_num_threads: onnxruntime intra-op threads (0 = runtime default).
    """

    encoder_path: Optional[str] = None
    decoder_path: Optional[str] = None
    flavour: str = "sam"
    input_size: int = 1024
    pixel_mean: Tuple[float, float, float] = (123.675, 116.28, 103.53)
    pixel_std: Tuple[float, float, float] = (58.395, 57.12, 57.375)
    encoder_layout: str = "nchw"
    encoder_input_name: Optional[str] = None
    encoder_output_name: Optional[str] = "image_embeddings"
    mask_threshold: float = 0.0
    upsample_to: Optional[Tuple[int, int]] = None
    prompt_batch_size: int = 16
    providers: Optional[Tuple[str, ...]] = None
    intra_op_num_threads: int = 0

    def __post_init__(self) -> None:
        if self.flavour not in ("sam", "efficientsam"):
            raise ValueError(f"SamOnnxConfig.flavour must be 'sam' or 'efficientsam', "
                             f"got {self.flavour!r}")
        if self.encoder_layout not in ("nchw", "hwc-raw"):
            raise ValueError(f"SamOnnxConfig.encoder_layout must be 'nchw' or 'hwc-raw', "
                             f"got {self.encoder_layout!r}")
        if int(self.input_size) <= 0:
            raise ValueError(f"SamOnnxConfig.input_size must be > 0, got {self.input_size}")
        if len(self.pixel_mean) != 3 or len(self.pixel_std) != 3 or min(self.pixel_std) <= 0:
            raise ValueError("SamOnnxConfig.pixel_mean / pixel_std must hold 3 values, std > 0")
        if self.upsample_to is not None:
            up = tuple(int(s) for s in self.upsample_to)
            if len(up) != 2 or min(up) <= 0:
                raise ValueError(f"SamOnnxConfig.upsample_to must be (height, width) > 0, "
                                 f"got {self.upsample_to!r}")
            object.__setattr__(self, "upsample_to", up)
        if int(self.prompt_batch_size) < 1:
            raise ValueError("SamOnnxConfig.prompt_batch_size must be >= 1")


#: Named contracts.  ``sam-official``: segment-anything export (encoder input
#: name taken from the file); ``sam-labelme``: the labelme / osam quantized
#: exports (encoder input ``x``, output ``image_embeddings``; their decoders are
#: single-mask exports); ``efficientsam``: labelme's EfficientSAM split export.
SAM_PRESETS: Mapping[str, SamOnnxConfig] = MappingProxyType({
    "sam-official": SamOnnxConfig(),
    "sam-labelme": SamOnnxConfig(encoder_input_name="x"),
    "efficientsam": SamOnnxConfig(flavour="efficientsam", encoder_input_name="batched_images"),
})


# ----------------------------------------------------------------- ort helpers
def _default_providers() -> List[str]:
    import onnxruntime as ort

    available = ort.get_available_providers()
    if "CUDAExecutionProvider" in available:
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    return ["CPUExecutionProvider"]


def open_session(path, what: str, providers: Optional[Sequence[str]] = None,
                 intra_op_num_threads: int = 0):
    """An ``onnxruntime.InferenceSession`` for ``path``; clear errors for a missing or bad file."""
    import onnxruntime as ort

    if path is None:
        raise ValueError(f"{what}: no model path given")
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{what} model file not found: {path}")
    opts = ort.SessionOptions()
    if intra_op_num_threads:
        opts.intra_op_num_threads = int(intra_op_num_threads)
    try:
        return ort.InferenceSession(path, opts, providers=list(providers or _default_providers()))
    except Exception as exc:  # onnxruntime raises its own exception types
        raise ValueError(f"{what}: onnxruntime cannot load {path}: {exc}") from exc


def _io(session, outputs: bool = False) -> Dict[str, object]:
    nodes = session.get_outputs() if outputs else session.get_inputs()
    return {n.name: n for n in nodes}


def _np_type(node, what: str):
    try:
        return _ORT_TYPES[node.type]
    except KeyError:
        raise ValueError(f"{what}: input {node.name!r} has unsupported type {node.type}") from None


def _check_rank(node, rank: int, what: str, static: Optional[Dict[int, int]] = None) -> None:
    shape = list(node.shape)
    if len(shape) != rank:
        raise ValueError(f"{what}: {node.name!r} must have rank {rank}, model declares {shape}")
    for axis, size in (static or {}).items():
        if isinstance(shape[axis], int) and shape[axis] not in (size, -1):
            raise ValueError(f"{what}: {node.name!r} axis {axis} must be {size}, model declares "
                             f"{shape}")


def _require_names(found: Sequence[str], expected: Sequence[str], kind: str, what: str,
                   exact: bool) -> None:
    found = list(found)
    missing = [n for n in expected if n not in found]
    extra = [n for n in found if n not in expected] if exact else []
    if missing or extra:
        raise ValueError(f"{what}: {kind} names do not match the contract: expected "
                         f"{list(expected)}, found {found}"
                         + (f" (missing {missing})" if missing else "")
                         + (f" (unexpected {extra})" if extra else ""))


# ------------------------------------------------------------- pre-processing
def resize_longest_side(height: int, width: int, target: int) -> Tuple[int, int]:
    """SAM's ``ResizeLongestSide.get_preprocess_shape``: ``(new_h, new_w)``."""
    scale = target * 1.0 / max(height, width)
    return int(height * scale + 0.5), int(width * scale + 0.5)


def _resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    if image.shape[:2] == (height, width):
        return image
    shrink = height < image.shape[0] or width < image.shape[1]
    return cv2.resize(image, (width, height),
                      interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _resize_stack(stack: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize (N, h, w) float maps to (N, height, width), map by map (no transposes)."""
    n = stack.shape[0]
    if stack.shape[1:] == (height, width):
        return stack
    out = np.empty((n, height, width), dtype=np.float32)
    for i in range(n):
        out[i] = _resize(np.ascontiguousarray(stack[i], dtype=np.float32), height, width)
    return out


def _as_rgb01(image: np.ndarray) -> np.ndarray:
    img = to_float_image(image)  # validates dtype / NaN / range
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img, dtype=np.float32)


# -------------------------------------------------------------------- adapters
@dataclass
class SamEmbedding:
    """Result of :meth:`SegmentModel.encode`.

    Attributes:
        embedding: the encoder output (e.g. (1, 256, 64, 64) float32).
        image_size: ``(height, width)`` of the caller's image.
        model_size: ``(height, width)`` the decoder works at (``upsample_to``
            or the image size).
    """

    embedding: np.ndarray
    image_size: Tuple[int, int]
    model_size: Tuple[int, int]


class _Backend:
    """One I/O contract: builds feeds and parses outputs.  Subclasses stay small."""

    decoder_inputs: Tuple[str, ...] = ()
    decoder_outputs: Tuple[str, ...] = ()
    default_encoder_input: Optional[str] = None
    max_prompts_per_call: int = 1
    chunk_limit: Optional[int] = None  # prompts per decode() (None: any number)

    def __init__(self, config: SamOnnxConfig, encoder, decoder) -> None:
        self.config = config
        self.encoder = encoder
        self.decoder = decoder
        self._check_encoder()
        self._check_decoder()

    # ---- checks
    def _check_encoder(self) -> None:
        what = f"encoder {self.config.encoder_path}"
        inputs = _io(self.encoder)
        name = self.config.encoder_input_name or self.default_encoder_input
        if name is None:
            if len(inputs) != 1:
                raise ValueError(f"{what}: expected a single input, found {list(inputs)}; set "
                                 "SamOnnxConfig.encoder_input_name")
            name = next(iter(inputs))
        elif name not in inputs:
            raise ValueError(f"{what}: expected input {name!r}, found inputs {list(inputs)}")
        if len(inputs) != 1:
            raise ValueError(f"{what}: the encoder must take one input, found {list(inputs)}")
        self.encoder_input = name
        self.encoder_input_type = _np_type(inputs[name], what)
        self._check_encoder_input(inputs[name], what)
        outputs = _io(self.encoder, outputs=True)
        out = self.config.encoder_output_name
        if out is None:
            out = next(iter(outputs))
        elif out not in outputs:
            raise ValueError(f"{what}: expected output {out!r}, found outputs {list(outputs)}")
        _check_rank(outputs[out], 4, what)
        self.encoder_output = out

    def _check_encoder_input(self, node, what: str) -> None:
        _check_rank(node, 4, what, {1: 3})

    def _check_decoder(self) -> None:
        what = f"decoder {self.config.decoder_path}"
        inputs = _io(self.decoder)
        _require_names(list(inputs), self.decoder_inputs, "input", what, exact=True)
        outputs = _io(self.decoder, outputs=True)
        _require_names(list(outputs), self.decoder_outputs, "output", what, exact=False)
        self.decoder_types = {n: _np_type(node, what) for n, node in inputs.items()}
        emb_in = list(inputs["image_embeddings"].shape)
        emb_out = list(_io(self.encoder, outputs=True)[self.encoder_output].shape)
        _check_rank(inputs["image_embeddings"], 4, what)
        for a, (i, o) in enumerate(zip(emb_in, emb_out)):
            if isinstance(i, int) and isinstance(o, int) and i != o:
                raise ValueError(f"encoder output {self.encoder_output!r} shape {emb_out} does "
                                 f"not fit decoder input 'image_embeddings' {emb_in} (axis {a})")
        self._check_decoder_shapes(inputs, what)

    def _check_decoder_shapes(self, inputs, what: str) -> None:
        pass

    # ---- running
    def encoder_feed(self, rgb01: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def decode(self, embedding: np.ndarray, points: np.ndarray, size: Tuple[int, int]
               ) -> Tuple[np.ndarray, np.ndarray]:
        """``points`` (Q, 2) (u, v) in the model frame -> logits (Q, C, h, w), iou (Q, C)."""
        raise NotImplementedError


class _SamBackend(_Backend):
    """Official segment-anything decoder contract (one prompt set per call)."""

    decoder_inputs = SAM_DECODER_INPUTS
    decoder_outputs = SAM_DECODER_OUTPUTS

    def _check_encoder_input(self, node, what: str) -> None:
        s = int(self.config.input_size)
        if self.config.encoder_layout == "nchw":
            _check_rank(node, 4, what, {1: 3, 2: s, 3: s})
        else:
            _check_rank(node, 3, what, {2: 3})

    def _check_decoder_shapes(self, inputs, what: str) -> None:
        _check_rank(inputs["point_coords"], 3, what, {2: 2})
        _check_rank(inputs["point_labels"], 2, what)
        _check_rank(inputs["mask_input"], 4, what)
        _check_rank(inputs["has_mask_input"], 1, what)
        _check_rank(inputs["orig_im_size"], 1, what, {0: 2})
        mask_shape = list(inputs["mask_input"].shape)
        self.mask_input_shape = tuple(d if isinstance(d, int) and d > 0 else (1 if i < 2 else 256)
                                      for i, d in enumerate(mask_shape))

    def encoder_feed(self, rgb01: np.ndarray) -> np.ndarray:
        cfg = self.config
        h, w = rgb01.shape[:2]
        nh, nw = resize_longest_side(h, w, cfg.input_size)
        x = _resize(rgb01 * np.float32(255.0), nh, nw)
        if cfg.encoder_layout == "hwc-raw":
            return x.astype(self.encoder_input_type)
        x = (x - np.asarray(cfg.pixel_mean, np.float32)) / np.asarray(cfg.pixel_std, np.float32)
        s = int(cfg.input_size)
        out = np.zeros((1, 3, s, s), dtype=self.encoder_input_type)
        out[0, :, :nh, :nw] = np.moveaxis(x, -1, 0)
        return out

    def decode(self, embedding, points, size):
        h, w = size
        nh, nw = resize_longest_side(h, w, self.config.input_size)
        t = self.decoder_types
        scale = np.array([nw / w, nh / h])
        logits = ious = None
        feed = {  # no mask prompt; the image size of the embedded image
            "image_embeddings": embedding.astype(t["image_embeddings"], copy=False),
            "point_labels": np.array([[1, -1]], dtype=t["point_labels"]),
            "mask_input": np.zeros(self.mask_input_shape, dtype=t["mask_input"]),
            "has_mask_input": np.zeros((1,), dtype=t["has_mask_input"]),
            "orig_im_size": np.array([h, w], dtype=t["orig_im_size"]),
        }
        for i, p in enumerate(np.asarray(points, dtype=np.float64)):
            # SamPredictor: coords in the resized frame, plus the padding point
            # (0, 0) with label -1 because no box is given.
            feed["point_coords"] = np.array([[p * scale, [0.0, 0.0]]], dtype=t["point_coords"])
            masks, iou = self.decoder.run(list(SAM_DECODER_OUTPUTS), feed)
            masks, iou = np.asarray(masks), np.asarray(iou)
            what = f"decoder {self.config.decoder_path}"
            if masks.ndim != 4 or masks.shape[0] != 1 or masks.shape[2:] != (h, w):
                raise ValueError(f"{what}: output 'masks' has shape {masks.shape}, expected "
                                 f"(1, C, {h}, {w})")
            if iou.shape != masks.shape[:2]:
                raise ValueError(f"{what}: output 'iou_predictions' has shape {iou.shape}, "
                                 f"expected {masks.shape[:2]}")
            if masks.shape[1] == 4:  # all mask tokens: keep the multimask ones (1..3)
                masks, iou = masks[:, 1:], iou[:, 1:]
            if logits is None:
                logits = np.empty((len(points),) + masks.shape[1:], dtype=np.float32)
                ious = np.empty((len(points), masks.shape[1]), dtype=np.float64)
            logits[i] = masks[0]
            ious[i] = iou[0]
        return logits, ious


class _EfficientSamBackend(_Backend):
    """EfficientSAM split export: batched queries, coordinates in original pixels."""

    decoder_inputs = EFFICIENTSAM_DECODER_INPUTS
    decoder_outputs = EFFICIENTSAM_DECODER_OUTPUTS
    default_encoder_input = None

    @property
    def max_prompts_per_call(self) -> int:  # type: ignore[override]
        return int(self.config.prompt_batch_size)

    @property
    def chunk_limit(self) -> int:  # type: ignore[override]
        return int(self.config.prompt_batch_size)

    def _check_decoder_shapes(self, inputs, what: str) -> None:
        _check_rank(inputs["batched_point_coords"], 4, what, {3: 2})
        _check_rank(inputs["batched_point_labels"], 3, what)
        _check_rank(inputs["orig_im_size"], 1, what, {0: 2})

    def encoder_feed(self, rgb01: np.ndarray) -> np.ndarray:
        return np.moveaxis(rgb01, -1, 0)[None].astype(self.encoder_input_type)

    def decode(self, embedding, points, size):
        h, w = size
        t = self.decoder_types
        pts = np.asarray(points, dtype=np.float64)
        feed = {
            "image_embeddings": embedding.astype(t["image_embeddings"], copy=False),
            "batched_point_coords": pts[None, :, None, :].astype(t["batched_point_coords"]),
            "batched_point_labels": np.ones((1, len(pts), 1), dtype=t["batched_point_labels"]),
            "orig_im_size": np.array([h, w], dtype=t["orig_im_size"]),
        }
        masks, iou = self.decoder.run(list(EFFICIENTSAM_DECODER_OUTPUTS), feed)
        masks, iou = np.asarray(masks), np.asarray(iou)
        q = len(pts)
        what = f"decoder {self.config.decoder_path}"
        if masks.ndim != 5 or masks.shape[:2] != (1, q) or masks.shape[3:] != (h, w):
            raise ValueError(f"{what}: output 'output_masks' has shape {masks.shape}, expected "
                             f"(1, {q}, C, {h}, {w})")
        if iou.shape != masks.shape[:3]:
            raise ValueError(f"{what}: output 'iou_predictions' has shape {iou.shape}, expected "
                             f"{masks.shape[:3]}")
        return masks[0].astype(np.float32, copy=False), iou[0].astype(np.float64)


_BACKENDS = {"sam": _SamBackend, "efficientsam": _EfficientSamBackend}


# ------------------------------------------------------------------ the model
class SegmentModel:
    """A promptable segmenter run with onnxruntime (see the module docstring).

    ``encode(image)`` once per image, then ``predict(embedding, points_uv)``
    for any number of single positive point prompts; logits come back at the
    image's own size.
    """

    def __init__(self, config: SamOnnxConfig) -> None:
        if config.encoder_path is None or config.decoder_path is None:
            raise ValueError("SegmentModel needs SamOnnxConfig.encoder_path and decoder_path")
        self.config = config
        encoder = open_session(config.encoder_path, "SAM encoder", config.providers,
                               config.intra_op_num_threads)
        decoder = open_session(config.decoder_path, "SAM decoder", config.providers,
                               config.intra_op_num_threads)
        self.backend = _BACKENDS[config.flavour](config, encoder, decoder)
        logger.info("SegmentModel (%s): encoder %s [%s -> %s], decoder %s", config.flavour,
                    config.encoder_path, self.backend.encoder_input,
                    self.backend.encoder_output, config.decoder_path)

    @classmethod
    def from_paths(cls, encoder_path, decoder_path, preset: str = "sam-official",
                   **overrides) -> "SegmentModel":
        """Build from two files and a :data:`SAM_PRESETS` name (fields overridable)."""
        if preset not in SAM_PRESETS:
            raise ValueError(f"unknown SAM preset {preset!r}; known: {sorted(SAM_PRESETS)}")
        cfg = dataclasses.replace(SAM_PRESETS[preset], encoder_path=os.fspath(encoder_path),
                                  decoder_path=os.fspath(decoder_path), **overrides)
        return cls(cfg)

    @property
    def mask_threshold(self) -> float:
        return float(self.config.mask_threshold)

    @property
    def max_prompts_per_call(self) -> int:
        return int(self.backend.max_prompts_per_call)

    def encode(self, image: np.ndarray) -> SamEmbedding:
        """Run the encoder on a float [0, 1] (H, W, 3) RGB or (H, W) grey image."""
        rgb = _as_rgb01(image)
        h, w = rgb.shape[:2]
        model_size = self.config.upsample_to or (h, w)
        rgb = _resize(rgb, *model_size)
        feed = self.backend.encoder_feed(rgb)
        (emb,) = self.backend.encoder.run([self.backend.encoder_output],
                                          {self.backend.encoder_input: feed})
        emb = np.asarray(emb)
        if not np.all(np.isfinite(emb)):
            raise ValueError(f"SAM encoder {self.config.encoder_path} produced NaN/inf embeddings")
        return SamEmbedding(emb, (h, w), tuple(model_size))

    def predict(self, embedding: SamEmbedding, points_uv: np.ndarray
                ) -> Tuple[np.ndarray, np.ndarray]:
        """Mask logits for single positive point prompts.

        Args:
            embedding: from :meth:`encode`.
            points_uv: (Q, 2) pixels ``(u, v)`` of the caller's image.

        Returns:
            ``(logits, iou)``: float32 (Q, C, H, W) logits at the image size and
            (Q, C) predicted IoU.
        """
        pts = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(pts)):
            raise ValueError("SegmentModel.predict: prompt points contain NaN/inf")
        h, w = embedding.image_size
        mh, mw = embedding.model_size
        if (mh, mw) != (h, w):  # cv2.resize convention (pixel centres at integers)
            pts = (pts + 0.5) * np.array([mw / w, mh / h]) - 0.5
        if len(pts) == 0:
            return np.zeros((0, 0, h, w), np.float32), np.zeros((0, 0))
        out_logits = out_iou = None
        # the SAM backend loops over prompts itself; batched backends take a limit
        step = max(1, self.backend.chunk_limit or len(pts))
        if len(pts) <= step and (mh, mw) == (h, w):  # one call: no copies
            logits, iou = self.backend.decode(embedding.embedding, pts, (mh, mw))
            if not (np.isfinite(logits).all() and np.isfinite(iou).all()):
                raise ValueError(f"SAM decoder {self.config.decoder_path} produced NaN/inf")
            return logits, iou
        for s in range(0, len(pts), step):
            logits, iou = self.backend.decode(embedding.embedding, pts[s:s + step], (mh, mw))
            if not (np.isfinite(logits).all() and np.isfinite(iou).all()):
                raise ValueError(f"SAM decoder {self.config.decoder_path} produced NaN/inf")
            q, c = logits.shape[:2]
            if (mh, mw) != (h, w):
                logits = _resize_stack(logits.reshape(q * c, mh, mw), h, w).reshape(q, c, h, w)
            if out_logits is None:
                out_logits = np.empty((len(pts), c, h, w), dtype=np.float32)
                out_iou = np.empty((len(pts), c), dtype=np.float64)
            out_logits[s:s + q] = logits
            out_iou[s:s + q] = iou
        return out_logits, out_iou


# ------------------------------------------------------------ mask utilities
def stability_scores(logits: np.ndarray, threshold: float = 0.0, offset: float = 1.0
                     ) -> np.ndarray:
    """SAM's stability score: IoU of ``logits > t + offset`` and ``logits > t - offset``.

    Over the last two axes; the first mask lies inside the second, so the IoU
    is the ratio of their areas.  Empty masks score 0.
    """
    flat = logits.reshape(*logits.shape[:-2], -1)
    inter = np.count_nonzero(flat > threshold + offset, axis=-1)
    union = np.count_nonzero(flat > threshold - offset, axis=-1)
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def mask_boxes(regions: Sequence[np.ndarray], width: int) -> np.ndarray:
    """(N, 4) inclusive pixel boxes ``(u0, v0, u1, v1)`` of flat-index regions."""
    boxes = np.zeros((len(regions), 4), dtype=np.int64)
    for i, r in enumerate(regions):
        v, u = np.divmod(r, width)
        boxes[i] = (u.min(), v.min(), u.max(), v.max())
    return boxes


def box_nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy box NMS; returns kept indices ordered by decreasing score.

    Boxes are inclusive pixel boxes ``(u0, v0, u1, v1)`` (area counts pixels).
    A box is removed when its IoU with a higher-scored kept box exceeds
    ``iou_threshold``.  Ties in score keep the earlier index.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    n = len(boxes)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-scores, kind="stable")
    b = boxes[order]
    area = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
    iw = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0])
                 + 1, 0, None)
    ih = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1])
                 + 1, 0, None)
    inter = iw * ih
    iou = inter / (area[:, None] + area[None, :] - inter)
    alive = np.ones(n, dtype=bool)
    for i in range(n):
        if alive[i]:
            alive[i + 1:] &= ~(iou[i, i + 1:] > iou_threshold)
    return order[alive]


# ---------------------------------------------------------- mask generator
@dataclass(frozen=True)
class SamMaskGeneratorConfig:
    """DESIGN.md §3 segment generation.

    Attributes:
        num_prompts: uniformly random single positive point prompts (300).
        num_active_prompts: prompts sampled afterwards in the area no kept mask
            covers (100; 0 disables the active pass).
        seed: seed of the prompt RNG (prompts and jitter are deterministic).
        stability_threshold: keep a candidate if its stability score is at
            least this (0.90).
        stability_offset: logit offset of the stability score around the mask
            threshold (1.0: IoU of ``logits > +1`` and ``logits > -1``).
        nms_iou: box-NMS IoU threshold (0.8), ranked by predicted IoU.
        active_jitter: uniform jitter (pixels, +-) of the active-prompt grid (3.0).
        keep_all_candidates: keep every stable candidate of a query that
            contains its prompt instead of only the smallest (the authors'
            re-run for depth completion when coverage is low).  False.
        chunk_size: prompts decoded before their logits are reduced to masks
            (bounds memory; 16).
    """

    num_prompts: int = 300
    num_active_prompts: int = 100
    seed: int = 0
    stability_threshold: float = 0.90
    stability_offset: float = 1.0
    nms_iou: float = 0.8
    active_jitter: float = 3.0
    keep_all_candidates: bool = False
    chunk_size: int = 16

    def __post_init__(self) -> None:
        if self.num_prompts < 0 or self.num_active_prompts < 0:
            raise ValueError("SamMaskGeneratorConfig: prompt counts must be >= 0")
        if not 0.0 <= self.stability_threshold <= 1.0:
            raise ValueError("SamMaskGeneratorConfig.stability_threshold must lie in [0, 1]")
        if self.stability_offset < 0 or self.active_jitter < 0:
            raise ValueError("SamMaskGeneratorConfig: stability_offset and active_jitter must "
                             "be >= 0")
        if not 0.0 < self.nms_iou <= 1.0:
            raise ValueError("SamMaskGeneratorConfig.nms_iou must lie in (0, 1]")
        if self.chunk_size < 1:
            raise ValueError("SamMaskGeneratorConfig.chunk_size must be >= 1")


@dataclass
class _Kept:
    regions: List[np.ndarray] = field(default_factory=list)
    anchors: List[int] = field(default_factory=list)
    scores: List[float] = field(default_factory=list)
    queries: int = 0
    dropped_stability: int = 0
    dropped_prompt_outside: int = 0
    removed_nms: int = 0

    def subset(self, keep: np.ndarray) -> "_Kept":
        out = dataclasses.replace(self, regions=[self.regions[i] for i in keep],
                                  anchors=[self.anchors[i] for i in keep],
                                  scores=[self.scores[i] for i in keep])
        out.removed_nms = self.removed_nms + len(self.regions) - len(keep)
        return out


class SamMaskGenerator:
    """:class:`~spgeo.frontend.base.Segmenter` over a :class:`SegmentModel` (DESIGN.md §3).

    Per query (one positive point): the decoder's candidates (usually 3) are
    kept if their stability score >= ``stability_threshold``; the smallest
    kept one (pixel count at the mask threshold) is the query's mask; the
    query is dropped if no candidate is stable or the chosen mask does not
    contain the prompt pixel.  Masks are box-NMSed (ranked by predicted IoU).
    Then ``num_active_prompts`` prompts are placed on a jittered grid over the
    uncovered pixels, filtered the same way, NMSed among themselves and
    appended.  Anchor = prompt pixel; score = predicted IoU.

    ``Segmentation.meta`` holds: ``queries`` (all decoder queries),
    ``initial_queries``, ``active_prompts`` (number of active queries),
    ``dropped_stability``, ``dropped_prompt_outside``, ``removed_nms`` (counts
    of queries, or of candidates with ``keep_all_candidates``),
    ``num_initial`` / ``num_active`` (regions from each pass; the first
    ``num_initial`` regions come from the random prompts), ``coverage_initial``
    / ``coverage_final`` (fraction of pixels covered), ``initial_prompts_uv`` /
    ``active_prompts_uv`` ((K, 2) int pixels queried), ``candidates_per_query``
    and ``keep_all_candidates``.
    """

    def __init__(self, model: SegmentModel,
                 config: SamMaskGeneratorConfig = SamMaskGeneratorConfig()) -> None:
        self.model = model
        self.config = config

    # ---- prompts
    @staticmethod
    def random_prompts(height: int, width: int, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` distinct uniformly random pixels as (n, 2) int ``(u, v)``."""
        n = min(int(n), height * width)
        flat = np.sort(rng.choice(height * width, size=n, replace=False))
        v, u = np.divmod(flat, width)
        return np.stack([u, v], axis=1).astype(np.int64)

    @staticmethod
    def active_prompts(uncovered: np.ndarray, n: int, jitter: float,
                       rng: np.random.Generator) -> np.ndarray:
        """Up to ``n`` (u, v) pixels on a jittered grid over ``uncovered`` (H, W) bool.

        The grid spacing starts at ``sqrt(#uncovered / n)`` and shrinks until
        at least ``n`` grid points fall on uncovered pixels (or spacing 1);
        only uncovered points are kept, subsampled at random to ``n``.
        """
        uncovered = np.asarray(uncovered, dtype=bool)
        h, w = uncovered.shape
        n_unc = int(uncovered.sum())
        if n <= 0 or n_unc == 0:
            return np.zeros((0, 2), dtype=np.int64)
        spacing = max(1.0, float(np.sqrt(n_unc / n)))
        flat = np.zeros(0, dtype=np.int64)
        for _ in range(40):
            gv, gu = np.meshgrid(np.arange(spacing / 2, h, spacing),
                                 np.arange(spacing / 2, w, spacing), indexing="ij")
            ju = rng.uniform(-jitter, jitter, gu.shape)
            jv = rng.uniform(-jitter, jitter, gv.shape)
            u = np.clip(np.rint(gu + ju), 0, w - 1).astype(np.int64).ravel()
            v = np.clip(np.rint(gv + jv), 0, h - 1).astype(np.int64).ravel()
            ok = uncovered[v, u]
            flat = np.unique(v[ok] * w + u[ok])
            if len(flat) >= n or spacing <= 1.0:
                break
            spacing = max(1.0, spacing * 0.8)
        if len(flat) > n:
            flat = np.sort(rng.choice(flat, size=n, replace=False))
        v, u = np.divmod(flat, w)
        return np.stack([u, v], axis=1).astype(np.int64)

    # ---- queries
    def _query(self, embedding: SamEmbedding, prompts: np.ndarray) -> Tuple[_Kept, int]:
        cfg = self.config
        h, w = embedding.image_size
        thr = self.model.mask_threshold
        kept = _Kept(queries=len(prompts))
        n_cand = 0
        for s in range(0, len(prompts), cfg.chunk_size):
            pts = prompts[s:s + cfg.chunk_size]
            logits, iou = self.model.predict(embedding, pts)
            q, c = logits.shape[:2]
            n_cand = c
            flat = logits.reshape(q, c, h * w)
            masks = flat > thr
            area = np.count_nonzero(masks, axis=-1)
            stab = stability_scores(logits, thr, cfg.stability_offset)
            stable = (stab >= cfg.stability_threshold) & (area > 0)
            prompt_flat = pts[:, 1] * w + pts[:, 0]
            inside = masks[np.arange(q)[:, None], np.arange(c)[None, :], prompt_flat[:, None]]
            if cfg.keep_all_candidates:
                kept.dropped_stability += int(np.count_nonzero(~stable))
                kept.dropped_prompt_outside += int(np.count_nonzero(stable & ~inside))
                sel_q, sel_c = np.nonzero(stable & inside)
            else:
                any_stable = stable.any(axis=1)
                choice = np.argmin(np.where(stable, area, np.iinfo(np.int64).max), axis=1)
                chosen_inside = inside[np.arange(q), choice]
                kept.dropped_stability += int(np.count_nonzero(~any_stable))
                kept.dropped_prompt_outside += int(np.count_nonzero(any_stable & ~chosen_inside))
                sel_q = np.flatnonzero(any_stable & chosen_inside)
                sel_c = choice[sel_q]
            for qi, ci in zip(sel_q, sel_c):
                kept.regions.append(np.flatnonzero(masks[qi, ci]))
                kept.anchors.append(int(prompt_flat[qi]))
                kept.scores.append(float(iou[qi, ci]))
        return kept, n_cand

    def _nms(self, kept: _Kept, width: int) -> _Kept:
        if not kept.regions:
            return kept
        keep = box_nms(mask_boxes(kept.regions, width), np.asarray(kept.scores),
                       self.config.nms_iou)
        return kept.subset(keep)

    @staticmethod
    def _coverage(regions: Sequence[np.ndarray], h: int, w: int) -> np.ndarray:
        covered = np.zeros(h * w, dtype=bool)
        for r in regions:
            covered[r] = True
        return covered.reshape(h, w)

    # ---- public
    def segment_with_prompts(self, image: np.ndarray, camera: PinholeCamera,
                             prompts_uv: np.ndarray,
                             rng: Optional[np.random.Generator] = None) -> Segmentation:
        """Run DESIGN.md §3 with the given initial prompts ((K, 2) int ``(u, v)``)."""
        cfg = self.config
        image = camera.check_image(image)
        h, w = camera.height, camera.width
        prompts = np.asarray(prompts_uv).reshape(-1, 2)
        if prompts.size and (not np.all(np.isfinite(prompts)) or np.any(prompts < 0)
                             or np.any(prompts[:, 0] > w - 1) or np.any(prompts[:, 1] > h - 1)):
            raise ValueError(f"prompts must be pixels inside the {w}x{h} image")
        prompts = np.rint(prompts).astype(np.int64)
        rng = np.random.default_rng(cfg.seed) if rng is None else rng
        embedding = self.model.encode(image)

        first, n_cand = self._query(embedding, prompts)
        first = self._nms(first, w)
        covered = self._coverage(first.regions, h, w)
        cov_initial = float(covered.mean())

        active_pts = self.active_prompts(~covered, cfg.num_active_prompts, cfg.active_jitter, rng)
        second, n_cand2 = self._query(embedding, active_pts)
        second = self._nms(second, w)
        n_cand = n_cand or n_cand2

        regions = first.regions + second.regions
        cov_final = float(self._coverage(regions, h, w).mean())
        meta = {
            "segmenter": f"sam-onnx/{self.model.config.flavour}",
            "queries": first.queries + second.queries,
            "initial_queries": first.queries,
            "active_prompts": second.queries,
            "dropped_stability": first.dropped_stability + second.dropped_stability,
            "dropped_prompt_outside": first.dropped_prompt_outside + second.dropped_prompt_outside,
            "removed_nms": first.removed_nms + second.removed_nms,
            "num_initial": len(first.regions),
            "num_active": len(second.regions),
            "coverage_initial": cov_initial,
            "coverage_final": cov_final,
            "initial_prompts_uv": prompts,
            "active_prompts_uv": active_pts,
            "candidates_per_query": int(n_cand),
            "keep_all_candidates": bool(cfg.keep_all_candidates),
        }
        logger.debug("SamMaskGenerator: %d queries -> %d + %d regions (coverage %.3f -> %.3f)",
                     meta["queries"], meta["num_initial"], meta["num_active"], cov_initial,
                     cov_final)
        return Segmentation(h, w, regions, np.asarray(first.anchors + second.anchors, np.int64),
                            np.asarray(first.scores + second.scores, np.float64), meta)

    def segment(self, image: np.ndarray, camera: PinholeCamera) -> Segmentation:
        """Segment ``image`` (float [0, 1], (H, W, 3) or (H, W), matching ``camera``)."""
        rng = np.random.default_rng(self.config.seed)
        prompts = self.random_prompts(camera.height, camera.width, self.config.num_prompts, rng)
        return self.segment_with_prompts(image, camera, prompts, rng)
