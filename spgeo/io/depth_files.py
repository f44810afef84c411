"""Depth map files: sparse depth input (16-bit PNG in millimetres or ``.npy`` in
metres) and dense depth output (16-bit PNG in millimetres, written atomically).

Readers validate with :func:`spgeo.validation.check_sparse_depth`; every error is
an :class:`~spgeo.validation.InputError` (or ``FileNotFoundError``) naming the file.
"""
from __future__ import annotations

import os

import numpy as np

from ..images import read_raw_image
from ..validation import InputError, check_input_file, check_real_array, check_sparse_depth
from .outputs import prepare_output_file, write_bytes_atomic

__all__ = ["MAX_PNG_DEPTH_M", "read_sparse_depth", "write_depth_png_mm"]

#: the largest depth (metres) a 16-bit millimetre PNG holds
MAX_PNG_DEPTH_M = 65.535


def read_sparse_depth(path) -> np.ndarray:
    """Sparse depth (H, W) float64 metres, 0 = missing, from a file.

    ``.npy``: a real floating-point array in metres (0 / NaN = missing; integer,
    bool or object arrays are refused).  Any other extension: a single-channel
    16-bit PNG in millimetres (0 = missing); 8-bit or colour images are refused.
    Raises ``FileNotFoundError`` / :class:`~spgeo.validation.InputError` naming
    the file (the checks of :func:`~spgeo.validation.check_sparse_depth`).
    """
    path = os.fspath(path)
    what = f"sparse depth file {path}"
    if path.lower().endswith(".npy"):
        check_input_file(path, "sparse depth")
        try:
            d = np.load(path, allow_pickle=False)
        except Exception as exc:   # numpy raises ValueError / OSError / EOFError / ...
            raise InputError(f"cannot read {what} as a .npy array: {exc}") from None
        return check_sparse_depth(d, what)
    raw = read_raw_image(path, "sparse depth")
    if raw.ndim != 2:
        raise InputError(f"{what} has {raw.shape[2]} channels; expected a single-channel "
                         "16-bit PNG in millimetres")
    if raw.dtype != np.uint16:
        raise InputError(f"{what} is a {raw.dtype} image; expected a single-channel 16-bit "
                         "(uint16) PNG in millimetres (an 8-bit PNG cannot hold millimetres)")
    return check_sparse_depth(raw.astype(np.float64) / 1000.0, what)


def write_depth_png_mm(path, depth: np.ndarray) -> str:
    """Write (H, W) depth in metres as a 16-bit PNG in millimetres, atomically.

    NaN and 0 are written as 0 (missing); positive depths below 0.5 mm round to
    0 as well.  Raises :class:`InputError`, writing nothing, for a path that does
    not end in ``.png`` or is a folder, a non-real or non-2-D array, inf,
    negative depths, or depths above :data:`MAX_PNG_DEPTH_M` (they would clip).
    Returns the path.
    """
    import cv2

    path = os.fspath(path)
    what = f"depth output {path}"
    if not path.lower().endswith(".png"):
        raise InputError(f"{what}: the file name must end in .png")
    d = check_real_array(depth, what)
    if d.ndim != 2 or d.size == 0:
        raise InputError(f"{what}: expected a non-empty (H, W) array, got shape {d.shape}")
    d = np.nan_to_num(d.astype(np.float64), nan=0.0, posinf=np.inf, neginf=-np.inf)
    if np.any(np.isinf(d)):
        raise InputError(f"{what}: {int(np.isinf(d).sum())} depths are inf")
    if np.any(d < 0):
        raise InputError(f"{what}: {int((d < 0).sum())} depths are negative (min {d.min():g} m)")
    mm = np.rint(d * 1000.0)
    if np.any(mm > 65535):
        raise InputError(f"{what}: {int((mm > 65535).sum())} depths exceed the "
                         f"{MAX_PNG_DEPTH_M} m a 16-bit millimetre PNG holds (max "
                         f"{d.max():g} m); they would clip")
    prepare_output_file(path, "depth output")
    ok, buf = cv2.imencode(".png", mm.astype(np.uint16))
    if not ok:   # pragma: no cover - OpenCV encodes any uint16 (H, W) array
        raise OSError(f"could not encode {path} as PNG")
    return write_bytes_atomic(path, buf.tobytes(), "depth output")
