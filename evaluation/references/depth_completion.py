"""Depth-completion baselines and the oracle front-end of the completion tables.

The baselines (linear interpolation, IP-Basic, the colorization fill, with their
configs) live in :mod:`spgeo.completion.baselines`, whose docstring describes them (the
held-out choice of :mod:`spgeo.completion.choose` uses them as candidates); they are
re-exported here for the evaluation protocols.

:func:`oracle_frontend` (ground-truth segments and normals) is the *oracle*
upper bound of the primitive pipeline; label its rows "oracle".  It lives in
:mod:`spgeo.frontend.oracle` (the demo uses it too) and is re-exported here.

Sparse depth maps are (H, W) metres with 0 or NaN = missing (the VOID
convention is 0); negative or infinite values raise ``ValueError``.
"""
from __future__ import annotations

from spgeo.completion import check_sparse_depth, nearest_fill
from spgeo.completion.baselines import (ColorizationConfig, IPBasicConfig,
                                        colorization_completion, diamond_kernel,
                                        ip_basic_completion, linear_interpolation_completion)
from spgeo.frontend.oracle import OracleNormals, oracle_frontend

__all__ = ["check_sparse_depth", "linear_interpolation_completion", "nearest_fill",
           "IPBasicConfig", "ip_basic_completion", "diamond_kernel",
           "ColorizationConfig", "colorization_completion", "OracleNormals",
           "oracle_frontend"]
