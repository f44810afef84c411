"""The model options shared by the commands that take a front-end (``spgeo vo``,
``spgeo sfm``): ``--sam-family``, ``--normal-model`` and ``--depth-model``, the
arguments of :func:`spgeo.frontend.build_frontend`.

``--normal-model`` names the ``onnx`` front-end's normal network only;
``--depth-model`` names the ``onnx-depth`` front-end's depth network.  Giving
``--normal-model`` with ``onnx-depth`` (its former meaning) or ``--depth-model``
with another front-end is an input error (exit code 2) that names the right
option.
"""
from __future__ import annotations

import argparse
from typing import Optional

from ..validation import InputError

__all__ = ["add_model_arguments", "check_depth_model_flag"]


def add_model_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--sam-family``, ``--normal-model`` and ``--depth-model`` (default None each)."""
    p.add_argument("--sam-family", default=None,
                   help="onnx / onnx-depth: SAM model family in the cache (default "
                        "efficientsam-vitt for onnx; onnx-depth uses classical segments "
                        "without it)")
    p.add_argument("--normal-model", default=None, metavar="NAME|PATH",
                   help="onnx: normal network, a model name (`spgeo models list`) or an "
                        ".onnx path (default metric3d-vit-small-fp16)")
    p.add_argument("--depth-model", default=None, metavar="NAME|PATH",
                   help="onnx-depth: depth network whose depth gives the normals, a model "
                        "name (built-in or `spgeo models register NAME PATH --preset P`) or "
                        "an .onnx path (generic-depth-518 preset; default "
                        "depth-anything-v2-small)")


def check_depth_model_flag(depth_model: Optional[str], frontend: str) -> None:
    """:class:`~spgeo.validation.InputError` when a depth model (``--depth-model``,
    or ``depth_model`` from ``--set`` / ``--config``) is given for a front-end other
    than ``onnx-depth`` (``frontend`` is the effective one)."""
    if depth_model is not None and frontend != "onnx-depth":
        raise InputError(f"--depth-model is the onnx-depth front-end's depth network; the "
                         f"front-end is {frontend!r}: add --frontend onnx-depth")
