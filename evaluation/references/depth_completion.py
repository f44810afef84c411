"""Depth-completion baselines and the oracle front-end of the completion tables.

The baselines (linear interpolation, IP-Basic, the colorization fill, with their
configs) live in :mod:`spgeo.completion.baselines`, whose docstring describes them (the
held-out choice of :mod:`spgeo.completion.choose` uses them as candidates); they are
re-exported here for the evaluation protocols.

:func:`oracle_frontend` (ground-truth segments and normals) is the *oracle*
upper bound of the primitive pipeline; label its rows "oracle".

Sparse depth maps are (H, W) metres with 0 or NaN = missing (the VOID
convention is 0); negative or infinite values raise ``ValueError``.
"""
from __future__ import annotations

import cv2
import numpy as np

from spgeo.completion import check_sparse_depth, nearest_fill
from spgeo.completion.baselines import (ColorizationConfig, IPBasicConfig,
                                        colorization_completion, diamond_kernel,
                                        ip_basic_completion, linear_interpolation_completion)

__all__ = ["check_sparse_depth", "linear_interpolation_completion", "nearest_fill",
           "IPBasicConfig", "ip_basic_completion", "diamond_kernel",
           "ColorizationConfig", "colorization_completion", "OracleNormals",
           "oracle_frontend"]


# ----------------------------------------------------------------- oracle front-end
class OracleNormals:
    """**Oracle** normal estimator for evaluation: returns given (e.g. rendered
    ground-truth) camera-frame normals, resized with nearest neighbour to the
    front-end's working camera.  ``uses_depth = True`` marks it as not
    monocular, so :func:`spgeo.completion.complete_depth` only accepts it with
    an explicit ``frontend_depth`` and flags the result ``uses_depth``."""

    uses_depth = True

    def __init__(self, normals: np.ndarray) -> None:
        normals = np.asarray(normals, dtype=np.float32)
        if normals.ndim != 3 or normals.shape[2] != 3:
            raise ValueError(f"normals must be (H, W, 3), got {normals.shape}")
        self.normals = normals

    def estimate(self, image, camera, depth=None) -> np.ndarray:
        n = self.normals
        if n.shape[:2] != camera.shape:
            n = cv2.resize(n, camera.size, interpolation=cv2.INTER_NEAREST)
        return n


def oracle_frontend(surface_ids: np.ndarray, normals: np.ndarray, working_size=None):
    """ORACLE front-end (evaluation only): ground-truth segments
    (:class:`spgeo.frontend.LabelSegmenter` of ``surface_ids``, -1 unlabelled)
    and ground-truth normals (:class:`OracleNormals`).  Name ``"oracle"``."""
    from spgeo.frontend import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd

    return PrimitiveFrontEnd(LabelSegmenter(surface_ids), OracleNormals(normals),
                             FrontEndConfig(working_size=working_size), name="oracle")
