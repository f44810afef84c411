"""The command-line arguments shared with the ``spgeo.evaluation`` tools; they live in
:mod:`spgeo.apps.args` (below the command line) and are re-exported here."""
from __future__ import annotations

from ..apps.args import (DATASET_KINDS, add_dataset_arguments, add_verbose_argument,
                         parse_intrinsics, parse_resolution, setup_logging)

__all__ = ["DATASET_KINDS", "add_dataset_arguments", "add_verbose_argument", "setup_logging",
           "parse_resolution", "parse_intrinsics"]
