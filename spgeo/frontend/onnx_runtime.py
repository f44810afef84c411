"""onnxruntime helpers shared by the ONNX adapters: sessions, I/O-contract checks, image resizing.

Every check raises ``ValueError`` whose message names ``what`` (the model
file and role), the tensor and what was expected.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..configs import config_class
from ..images import to_float_image

__all__ = ["open_session", "io_nodes", "np_type", "check_rank", "require_names", "check_size",
           "resize_map", "resize_stack", "as_rgb01", "ImageIOConfig", "image_input", "prepare_image", "to_hwc",
           "uncrop"]

_ORT_TYPES = {
    "tensor(float)": np.float32, "tensor(double)": np.float64, "tensor(float16)": np.float16,
    "tensor(int64)": np.int64, "tensor(int32)": np.int32,
}


def _default_providers() -> List[str]:
    import onnxruntime as ort

    available = ort.get_available_providers()
    if "CUDAExecutionProvider" in available:
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    return ["CPUExecutionProvider"]


def open_session(path, what: str, providers: Optional[Sequence[str]] = None,
                 intra_op_num_threads: int = 0):
    """An ``onnxruntime.InferenceSession`` for ``path``.

    ``providers`` ``None``: CUDA when onnxruntime has it, else CPU;
    ``intra_op_num_threads`` 0: the runtime default.  onnxruntime's own log
    keeps errors only (its warnings about a model's graph are not the user's to
    act on and would break the CLI's one-line error).  Raises ``ValueError``
    for ``path`` None or a file onnxruntime cannot load, ``FileNotFoundError``
    for a missing file.
    """
    import onnxruntime as ort

    if path is None:
        raise ValueError(f"{what}: no model path given")
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{what} model file not found: {path}")
    ort.set_default_logger_severity(3)
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    if intra_op_num_threads:
        opts.intra_op_num_threads = int(intra_op_num_threads)
    try:
        return ort.InferenceSession(path, opts, providers=list(providers or _default_providers()))
    except Exception as exc:  # onnxruntime raises its own exception types
        raise ValueError(f"{what}: onnxruntime cannot load {path}: {exc}") from exc


def io_nodes(session, outputs: bool = False) -> Dict[str, object]:
    """The session's input (or output) nodes by name, in declaration order."""
    nodes = session.get_outputs() if outputs else session.get_inputs()
    return {n.name: n for n in nodes}


def np_type(node, what: str):
    """numpy dtype of an ORT tensor node (float32/64/16, int64/32); ``ValueError`` otherwise."""
    try:
        return _ORT_TYPES[node.type]
    except KeyError:
        raise ValueError(f"{what}: input {node.name!r} has unsupported type {node.type}") from None


def check_rank(node, rank: int, what: str, static: Optional[Dict[int, int]] = None) -> None:
    """Require ``rank`` axes and, for each ``axis: size`` of ``static``, that size
    where the model declares a fixed one."""
    shape = list(node.shape)
    if len(shape) != rank:
        raise ValueError(f"{what}: {node.name!r} must have rank {rank}, model declares {shape}")
    for axis, size in (static or {}).items():
        if isinstance(shape[axis], int) and shape[axis] not in (size, -1):
            raise ValueError(f"{what}: {node.name!r} axis {axis} must be {size}, model declares "
                             f"{shape}")


def require_names(found: Sequence[str], expected: Sequence[str], kind: str, what: str,
                  exact: bool) -> None:
    """Require every ``expected`` tensor name (and, with ``exact``, no others)."""
    found = list(found)
    missing = [n for n in expected if n not in found]
    extra = [n for n in found if n not in expected] if exact else []
    if missing or extra:
        raise ValueError(f"{what}: {kind} names do not match the contract: expected "
                         f"{list(expected)}, found {found}"
                         + (f" (missing {missing})" if missing else "")
                         + (f" (unexpected {extra})" if extra else ""))


def check_size(value, what: str) -> Optional[Tuple[int, int]]:
    """``None``, or ``value`` as an int ``(height, width)`` > 0 (``ValueError`` naming ``what``)."""
    if value is None:
        return None
    size = tuple(int(s) for s in value)
    if len(size) != 2 or min(size) <= 0:
        raise ValueError(f"{what} must be (height, width) > 0, got {value!r}")
    return size


def resize_map(img: np.ndarray, height: int, width: int, bilinear: bool = False) -> np.ndarray:
    """cv2 resize of an (h, w[, c]) map to float32 (height, width[, c]).

    Area averaging when shrinking (unless ``bilinear``), bilinear otherwise;
    returned unchanged when already that size.
    """
    if img.shape[:2] == (height, width):
        return img
    shrink = height < img.shape[0] or width < img.shape[1]
    interp = cv2.INTER_AREA if shrink and not bilinear else cv2.INTER_LINEAR
    out = cv2.resize(np.ascontiguousarray(img, dtype=np.float32), (width, height),
                     interpolation=interp)
    return out.reshape(height, width, *img.shape[2:])


def resize_stack(stack: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize (N, h, w) float maps to float32 (N, height, width), map by map."""
    n = stack.shape[0]
    if stack.shape[1:] == (height, width):
        return stack
    out = np.empty((n, height, width), dtype=np.float32)
    for i in range(n):
        out[i] = resize_map(stack[i], height, width)
    return out


def as_rgb01(image: np.ndarray) -> np.ndarray:
    """Contiguous float32 (H, W, 3) RGB in [0, 1] (:func:`spgeo.images.to_float_image`,
    which raises ``ValueError``); grey is repeated into 3 channels."""
    img = to_float_image(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img, dtype=np.float32)


# ------------------------------------------------ dense image-to-map networks
@config_class
@dataclass(frozen=True, kw_only=True)
class ImageIOConfig:
    """Keyword-only I/O fields shared by the configs of dense image -> map networks
    (:class:`~spgeo.frontend.onnx_normals.NormalOnnxConfig`,
    :class:`~spgeo.frontend.onnx_depth.DepthOnnxConfig`), for :func:`image_input`,
    :func:`prepare_image` and :func:`to_hwc`.

    Attributes:
        resize_mode: ``"stretch"`` (default) or ``"letterbox"`` (keep aspect,
            centre-pad; the pad is cropped from the output).
        pad_value: letterbox pad colour in ``input_range`` units (``None``: ``mean``).
        input_name / output_name: tensor names; ``None`` accepts the model's
            only input / its first output.  Given names must exist.
        input_range: ``"0-1"`` (default) or ``"0-255"`` pixel scale before normalisation.
        mean, std: per-channel normalisation in ``input_range`` units (default ImageNet).
        channel_order: ``"RGB"`` (default) or ``"BGR"``.
        layout / output_layout: ``"NCHW"`` (default) or ``"NHWC"``.
        providers: onnxruntime providers (``None``: CUDA if available, else CPU).
        intra_op_num_threads: onnxruntime intra-op threads (0 = default).
    """

    resize_mode: str = "stretch"
    pad_value: Optional[Tuple[float, float, float]] = None
    input_name: Optional[str] = None
    output_name: Optional[str] = None
    input_range: str = "0-1"
    mean: Tuple[float, float, float] = (0.485, 0.456, 0.406)
    std: Tuple[float, float, float] = (0.229, 0.224, 0.225)
    channel_order: str = "RGB"
    layout: str = "NCHW"
    output_layout: str = "NCHW"
    providers: Optional[Tuple[str, ...]] = None
    intra_op_num_threads: int = 0

    def check_io(self, extra: Sequence[Tuple[str, Sequence[str]]] = ()) -> None:
        """``ValueError`` naming the config class and field for a value outside its choices
        (these fields' and each ``(field, allowed)`` of ``extra``) or a bad mean / std."""
        cls = type(self).__name__
        checks = [("resize_mode", ("stretch", "letterbox")), ("input_range", ("0-1", "0-255")),
                  ("channel_order", ("RGB", "BGR")), ("layout", ("NCHW", "NHWC")),
                  ("output_layout", ("NCHW", "NHWC")), *extra]
        for name, allowed in checks:
            if getattr(self, name) not in allowed:
                raise ValueError(f"{cls}.{name} must be one of {tuple(allowed)}, "
                                 f"got {getattr(self, name)!r}")
        if len(self.mean) != 3 or len(self.std) != 3 or min(self.std) <= 0:
            raise ValueError(f"{cls}.mean / std must hold 3 values, std > 0")

    def prepare(self, rgb01: np.ndarray, size: Optional[Tuple[int, int]], dtype):
        """:func:`prepare_image` with this config's fields."""
        return prepare_image(rgb01, size, input_range=self.input_range,
                             channel_order=self.channel_order, mean=self.mean, std=self.std,
                             layout=self.layout, dtype=dtype, resize_mode=self.resize_mode,
                             pad_value=self.pad_value)


def image_input(session, input_name: Optional[str], layout: str,
                input_size: Optional[Tuple[int, int]], what: str, cfg_name: str):
    """The single image input of a dense network: ``(name, numpy float dtype)``.

    ``input_name`` ``None`` accepts the model's only input; a given name must be
    that only input.  The input must be a rank-4 ``layout`` (``"NCHW"`` /
    ``"NHWC"``) 3-channel float tensor and, where the model declares a static
    size, that size must equal ``input_size`` (``None`` skips the check).
    ``cfg_name`` (the config class) is named in the messages.
    """
    inputs = io_nodes(session)
    if input_name is None:
        if len(inputs) != 1:
            raise ValueError(f"{what}: expected a single input, found {list(inputs)}; set "
                             f"{cfg_name}.input_name")
        input_name = next(iter(inputs))
    elif input_name not in inputs or len(inputs) != 1:
        raise ValueError(f"{what}: expected the single input {input_name!r}, found "
                         f"inputs {list(inputs)}")
    node = inputs[input_name]
    shape = list(node.shape)
    c_axis = 1 if layout == "NCHW" else 3
    if len(shape) != 4 or (isinstance(shape[c_axis], int) and shape[c_axis] != 3):
        raise ValueError(f"{what}: input {input_name!r} must be a {layout} "
                         f"3-channel image, model declares {shape}")
    hw = shape[2:4] if layout == "NCHW" else shape[1:3]
    if input_size is not None and all(isinstance(d, int) and d > 0 for d in hw):
        if tuple(hw) != tuple(input_size):
            raise ValueError(f"{what}: input {input_name!r} is {hw[0]}x{hw[1]} but "
                             f"{cfg_name}.input_size is {input_size}")
    dtype = {"tensor(float)": np.float32, "tensor(float16)": np.float16,
             "tensor(double)": np.float64}.get(node.type)
    if dtype is None:
        raise ValueError(f"{what}: input {input_name!r} has unsupported type {node.type}")
    return input_name, dtype


def prepare_image(rgb01: np.ndarray, size: Optional[Tuple[int, int]], *, input_range: str,
                  channel_order: str, mean, std, layout: str, dtype,
                  resize_mode: str = "stretch", pad_value=None):
    """An RGB ``[0, 1]`` (H, W, 3) image -> ``(network input (1, ...), crop)``.

    Scaled to ``input_range`` (``"0-1"`` / ``"0-255"``), channels reordered
    (``"RGB"`` / ``"BGR"``), resized to ``size`` ``(h, w)`` (``None``: kept) by
    ``resize_mode`` ``"stretch"`` or ``"letterbox"`` (aspect kept, centred,
    padded with ``pad_value``, default ``mean``), normalised ``(x - mean) / std``
    per network channel, laid out as ``layout``, cast to ``dtype``.  ``crop``
    is ``None`` or the letterboxed image's ``(top, left, height, width)`` as
    fractions of the input, for :func:`uncrop`.
    """
    h, w = rgb01.shape[:2]
    x = rgb01 * np.float32(255.0 if input_range == "0-255" else 1.0)
    if channel_order == "BGR":
        x = x[..., ::-1]
    mean = np.asarray(mean, np.float32)
    std = np.asarray(std, np.float32)
    crop = None
    if size is not None:
        ih, iw = size
        if resize_mode == "stretch":
            x = resize_map(x, ih, iw)
        else:
            s = min(ih / h, iw / w)
            rh, rw = max(1, int(round(h * s))), max(1, int(round(w * s)))
            top, left = (ih - rh) // 2, (iw - rw) // 2
            pad = np.asarray(pad_value if pad_value is not None else mean, np.float32)
            canvas = np.empty((ih, iw, 3), np.float32)
            canvas[:] = pad
            canvas[top:top + rh, left:left + rw] = resize_map(x, rh, rw)
            x = canvas
            crop = (top / ih, left / iw, rh / ih, rw / iw)
    x = (x - mean) / std
    x = np.moveaxis(x, -1, 0)[None] if layout == "NCHW" else x[None]
    return np.ascontiguousarray(x, dtype=dtype), crop


def to_hwc(arr: np.ndarray, layout: str, what: str) -> np.ndarray:
    """A network output (1, C, h, w) / (1, h, w, C) / (C, h, w) / (h, w) -> float32 (h, w, C)
    (``layout`` ``"NCHW"`` / ``"NHWC"`` for rank 3-4; ``ValueError`` naming ``what``)."""
    arr = np.asarray(arr, dtype=np.float32)
    if arr.ndim == 4:
        if arr.shape[0] != 1:
            raise ValueError(f"{what}: batch size {arr.shape[0]}, expected 1")
        arr = arr[0]
    if arr.ndim == 2:
        return arr[..., None]
    if arr.ndim != 3:
        raise ValueError(f"{what}: output has shape {arr.shape}, expected an image")
    return np.moveaxis(arr, 0, -1) if layout == "NCHW" else arr


def uncrop(arr: np.ndarray, crop) -> np.ndarray:
    """The part of an output map (h, w[, C]) that covers the image (``crop`` of
    :func:`prepare_image`; ``None``: all of it)."""
    if crop is None:
        return arr
    oh, ow = arr.shape[:2]
    t, l, rh, rw = crop
    t0, l0 = int(round(t * oh)), int(round(l * ow))
    return arr[t0:t0 + max(1, int(round(rh * oh))), l0:l0 + max(1, int(round(rw * ow)))]
