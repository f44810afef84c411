"""onnxruntime helpers shared by the ONNX adapters: sessions, I/O-contract checks, image resizing.

Every check raises ``ValueError`` whose message names ``what`` (the model
file and role), the tensor and what was expected.
"""
from __future__ import annotations

import os
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..images import to_float_image

__all__ = ["open_session", "io_nodes", "np_type", "check_rank", "require_names", "check_size",
           "resize_map", "resize_stack", "as_rgb01"]

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
    ``intra_op_num_threads`` 0: the runtime default.  Raises ``ValueError``
    for ``path`` None or a file onnxruntime cannot load, ``FileNotFoundError``
    for a missing file.
    """
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
