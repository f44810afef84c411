"""Few-view structure from motion on SuperPrimitives (docs/design.md §4, §5).

The method is described in :mod:`spgeo.sfm.solve`.  Modules, one job each:

* :mod:`~spgeo.sfm.config`: :class:`SfMConfig` (the options).
* :mod:`~spgeo.sfm.solve`: :func:`few_view_sfm`: coarse-to-fine Levenberg-Marquardt
  over photometric factors (one pyramid level's graph:
  :func:`spgeo.graph.builders.build_level_graph`; keys: :mod:`spgeo.graph.keys`),
  marginals, gauge-free scale stds.
* :mod:`~spgeo.sfm.result`: :class:`SfMResult` and the status assessment of a solution.
* :mod:`~spgeo.sfm.tracks`: SIFT tracks over every pair of views, a pair's planar
  ambiguity.
* :mod:`~spgeo.sfm.bundle`: the landmark bundle (best pair, PnP, GTSAM bundle
  adjustment, held-out matches, calibrated covariances).
* :mod:`~spgeo.sfm.landmarks`: :class:`LandmarkStage`, the bundle inside the solve
  (its start, the acceptance of the photometric poses).
* :mod:`~spgeo.sfm.init`: initialisation from two-view geometry (poses,
  initial log-scales; the VO's start and ``SfMConfig(init="twoview")``).
* :mod:`~spgeo.sfm.orientation`: planar primitives' orientation hypotheses
  decided by the photometric cost.
"""
from .config import SfMConfig
from .result import SfMResult
from .solve import SFM_WORKING_SIZE, few_view_sfm

__all__ = ["SfMConfig", "SfMResult", "SFM_WORKING_SIZE", "few_view_sfm"]
