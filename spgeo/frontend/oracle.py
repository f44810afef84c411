"""The **oracle** front-end: ground-truth segments and normals (e.g. of a synthetic render).

The upper bound of the primitive pipeline: :func:`oracle_frontend` segments by the
ground-truth surface ids (:class:`~spgeo.frontend.pipeline.LabelSegmenter`) and takes
the ground-truth normals (:class:`OracleNormals`).  It reads ground truth, so it is
never monocular (``uses_depth``); label its rows "oracle".  The demo's completion
table and the completion evaluation use it.
"""
from __future__ import annotations

import cv2
import numpy as np

from .pipeline import FrontEndConfig, LabelSegmenter, PrimitiveFrontEnd

__all__ = ["OracleNormals", "oracle_frontend"]


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


def oracle_frontend(surface_ids: np.ndarray, normals: np.ndarray,
                    working_size=None) -> PrimitiveFrontEnd:
    """ORACLE front-end (evaluation only): ground-truth segments
    (:class:`~spgeo.frontend.pipeline.LabelSegmenter` of ``surface_ids``, -1 unlabelled)
    and ground-truth normals (:class:`OracleNormals`) at ``working_size`` (None: the
    input resolution).  Name ``"oracle"``."""
    return PrimitiveFrontEnd(LabelSegmenter(surface_ids), OracleNormals(normals),
                             FrontEndConfig(working_size=working_size), name="oracle")
