"""Feature-based two-view relative pose with known intrinsics.

The method is described in :mod:`spgeo.twoview.pose`.  Modules, one job each:

* :mod:`~spgeo.twoview.config`: :class:`TwoViewConfig` (the options) and
  :data:`TWO_VIEW_STATUSES`.
* :mod:`~spgeo.twoview.pose`: :func:`estimate_relative_pose` (features,
  matches, geometry, status checks) and :class:`TwoViewResult`.
* :mod:`~spgeo.twoview.backends`: OpenCV and pycolmap features, matching and
  relative-pose geometry.
* :mod:`~spgeo.twoview.geometry`: epipolar helpers (Sampson error, parallax,
  rotation-only fit, refinement, pose uncertainty).
"""
from .backends import colmap_camera, quiet_colmap
from .config import TWO_VIEW_STATUSES, FeatureOptions, TwoViewConfig
from .geometry import parallax_angles_deg, rotation_only_fit
from .pose import (TwoViewResult, estimate_relative_pose, relative_pose_from_matches,
                   to_gray_uint8)

__all__ = [
    "TWO_VIEW_STATUSES", "TwoViewConfig", "TwoViewResult", "estimate_relative_pose",
    "relative_pose_from_matches",
    "to_gray_uint8", "colmap_camera", "rotation_only_fit", "parallax_angles_deg",
    "quiet_colmap",
]
