"""SAM-style promptable segmentation with onnxruntime (the segment-model adapters).

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

* :class:`spgeo.frontend.mask_generator.SamMaskGenerator` (its own module) turns a
  :class:`SegmentModel` into a :class:`~spgeo.frontend.base.Segmenter` as
  docs/design.md §3 describes.

Pixel convention: prompts are integer pixels ``(u, v)`` (column, row) with
pixel centres at integers, as :mod:`spgeo.camera`; the official SAM decoder
adds 0.5 itself.
"""
from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, Optional, Tuple

import numpy as np

from ..configs import config_class
from .onnx_runtime import (as_rgb01, check_rank, check_size, io_nodes, np_type, open_session,
                           require_names, resize_map, resize_stack)

__all__ = ["SamOnnxConfig", "SAM_PRESETS", "SamEmbedding", "SegmentModel"]

logger = logging.getLogger(__name__)

SAM_DECODER_INPUTS = ("image_embeddings", "point_coords", "point_labels", "mask_input",
                      "has_mask_input", "orig_im_size")
SAM_DECODER_OUTPUTS = ("masks", "iou_predictions")
EFFICIENTSAM_DECODER_INPUTS = ("image_embeddings", "batched_point_coords",
                               "batched_point_labels", "orig_im_size")
EFFICIENTSAM_DECODER_OUTPUTS = ("output_masks", "iou_predictions")


# --------------------------------------------------------------------------- config
@config_class
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
        object.__setattr__(self, "upsample_to",
                           check_size(self.upsample_to, "SamOnnxConfig.upsample_to"))
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



# ------------------------------------------------------------- pre-processing
def resize_longest_side(height: int, width: int, target: int) -> Tuple[int, int]:
    """SAM's ``ResizeLongestSide.get_preprocess_shape``: ``(new_h, new_w)``."""
    scale = target * 1.0 / max(height, width)
    return int(height * scale + 0.5), int(width * scale + 0.5)



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
        inputs = io_nodes(self.encoder)
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
        self.encoder_input_type = np_type(inputs[name], what)
        self._check_encoder_input(inputs[name], what)
        outputs = io_nodes(self.encoder, outputs=True)
        out = self.config.encoder_output_name
        if out is None:
            out = next(iter(outputs))
        elif out not in outputs:
            raise ValueError(f"{what}: expected output {out!r}, found outputs {list(outputs)}")
        check_rank(outputs[out], 4, what)
        self.encoder_output = out

    def _check_encoder_input(self, node, what: str) -> None:
        check_rank(node, 4, what, {1: 3})

    def _check_decoder(self) -> None:
        what = f"decoder {self.config.decoder_path}"
        inputs = io_nodes(self.decoder)
        require_names(list(inputs), self.decoder_inputs, "input", what, exact=True)
        outputs = io_nodes(self.decoder, outputs=True)
        require_names(list(outputs), self.decoder_outputs, "output", what, exact=False)
        self.decoder_types = {n: np_type(node, what) for n, node in inputs.items()}
        emb_in = list(inputs["image_embeddings"].shape)
        emb_out = list(io_nodes(self.encoder, outputs=True)[self.encoder_output].shape)
        check_rank(inputs["image_embeddings"], 4, what)
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
            check_rank(node, 4, what, {1: 3, 2: s, 3: s})
        else:
            check_rank(node, 3, what, {2: 3})

    def _check_decoder_shapes(self, inputs, what: str) -> None:
        check_rank(inputs["point_coords"], 3, what, {2: 2})
        check_rank(inputs["point_labels"], 2, what)
        check_rank(inputs["mask_input"], 4, what)
        check_rank(inputs["has_mask_input"], 1, what)
        check_rank(inputs["orig_im_size"], 1, what, {0: 2})
        mask_shape = list(inputs["mask_input"].shape)
        self.mask_input_shape = tuple(d if isinstance(d, int) and d > 0 else (1 if i < 2 else 256)
                                      for i, d in enumerate(mask_shape))

    def encoder_feed(self, rgb01: np.ndarray) -> np.ndarray:
        cfg = self.config
        h, w = rgb01.shape[:2]
        nh, nw = resize_longest_side(h, w, cfg.input_size)
        x = resize_map(rgb01 * np.float32(255.0), nh, nw)
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
        check_rank(inputs["batched_point_coords"], 4, what, {3: 2})
        check_rank(inputs["batched_point_labels"], 3, what)
        check_rank(inputs["orig_im_size"], 1, what, {0: 2})

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
        rgb = as_rgb01(image)
        h, w = rgb.shape[:2]
        model_size = self.config.upsample_to or (h, w)
        rgb = resize_map(rgb, *model_size)
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
                logits = resize_stack(logits.reshape(q * c, mh, mw), h, w).reshape(q, c, h, w)
            if out_logits is None:
                out_logits = np.empty((len(pts), c, h, w), dtype=np.float32)
                out_iou = np.empty((len(pts), c), dtype=np.float64)
            out_logits[s:s + q] = logits
            out_iou[s:s + q] = iou
        return out_logits, out_iou

