"""Command-line arguments shared by ``spgeo`` and the ``spgeo.evaluation`` tools:
``--dataset KIND PATH`` / ``--frames`` / ``-v``, logging set-up, and the
``WIDTHxHEIGHT`` resolution and ``fx,fy,cx,cy`` intrinsics parsers (argparse
only; no computation).  Here, below :mod:`spgeo.cli`, so that the evaluation tools
need not import the command line."""
from __future__ import annotations

import argparse
import logging
from typing import Optional, Tuple

from ..datasets import DATASET_KINDS
from ..validation import MAX_IMAGE_SIDE, InputError

__all__ = ["DATASET_KINDS", "add_dataset_arguments", "add_verbose_argument", "setup_logging",
           "parse_resolution", "parse_intrinsics"]

_NATIVE = ("native", "none", "full")


def add_dataset_arguments(parser: argparse.ArgumentParser,
                          frames_help: str = "frame numbers A:B[:S] (A <= n < B)",
                          frames_nargs: Optional[str] = None) -> None:
    """``--dataset KIND PATH`` (required) and ``--frames`` (default None: all)."""
    parser.add_argument("--dataset", nargs=2, metavar=("KIND", "PATH"), required=True,
                        help=f"data-set kind ({', '.join(DATASET_KINDS)}) and its folder")
    kw = {"nargs": frames_nargs} if frames_nargs else {}
    parser.add_argument("--frames", default=None, help=frames_help, **kw)


def add_verbose_argument(parser: argparse.ArgumentParser) -> None:
    """``-v`` / ``--verbose``: log progress (INFO)."""
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")


def setup_logging(verbose: bool) -> None:
    """Root logging at INFO (``verbose``) or WARNING, ``LEVEL name: message``."""
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


def parse_resolution(text: str, allow_native: bool = False, min_size: int = 16,
                     max_size: int = MAX_IMAGE_SIDE) -> Optional[Tuple[int, int]]:
    """``"WxH"`` (e.g. ``"160x120"``, case-insensitive) -> ``(width, height)``
    in pixels; with ``allow_native``, ``"native"`` (or ``"none"``, ``"full"``)
    -> None (keep the frames' size).

    Raises :class:`~spgeo.validation.InputError` for anything but two integers in
    ``[min_size, max_size]`` separated by ``x``.
    """
    s = str(text).strip().lower()
    if allow_native and s in _NATIVE:
        return None
    parts = s.split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        alt = " or 'native'" if allow_native else ""
        raise InputError(f"invalid resolution {text!r}: expected WIDTHxHEIGHT{alt}, e.g. 160x120")
    w, h = (int(p) for p in parts)
    if w < min_size or h < min_size:
        raise InputError(f"invalid resolution {text!r}: width and height must be >= "
                         f"{min_size} pixels")
    if w > max_size or h > max_size:
        raise InputError(f"invalid resolution {text!r}: width and height must be <= "
                         f"{max_size} pixels")
    return w, h


def parse_intrinsics(text: str) -> Tuple[float, float, float, float]:
    """``"fx,fy,cx,cy"`` (pixels) -> four floats; ``ValueError`` otherwise."""
    parts = [p for p in str(text).replace(" ", "").split(",") if p]
    if len(parts) != 4:
        raise InputError(f"--intrinsics must be fx,fy,cx,cy, got {text!r}")
    try:
        return tuple(float(p) for p in parts)  # type: ignore[return-value]
    except ValueError:
        raise InputError(f"--intrinsics must be four numbers fx,fy,cx,cy, got {text!r}") from None
