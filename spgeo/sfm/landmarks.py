"""The landmark bundle inside the few-view solve (docs/design.md §5, "Landmark bundle").

:class:`LandmarkStage` owns the tracks and the bundle of one :func:`spgeo.sfm.few_view_sfm`
call: it starts the solve (the views' poses, the primitives' log-scales from the
landmarks seen in the reference) and judges the photometric refinement that follows:
each view keeps its photometric pose only where its held-out matches fit it at least as
well as the bundle's pose (:func:`spgeo.sfm.bundle.heldout_errors`); otherwise it takes
the bundle's, held while the scales are solved once more.
"""
from __future__ import annotations

import logging
from typing import List, Optional, Sequence, Tuple

import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.priors import pose_gauge_prior
from ..geometry import rotation_angle_deg
from ..graph.keys import pose_key
from ..primitives import PrimitiveSet
from ..twoview import TwoViewConfig
from .bundle import FeatureBundle, feature_bundle, heldout_errors
from .init import scales_from_points
from .tracks import ViewTracks, match_views

__all__ = ["LandmarkStage"]

log = logging.getLogger(__name__)


class LandmarkStage:
    """Tracks and landmark bundle of a reference image and its views.

    Args:
        images: the reference image then the views, of ``camera``'s size.
        camera: their intrinsics.
        config: features and pair geometry (:class:`~spgeo.twoview.TwoViewConfig`).
    """

    def __init__(self, images: Sequence[np.ndarray], camera: PinholeCamera,
                 config: TwoViewConfig) -> None:
        self.camera = camera.undistorted()
        self.tracks: ViewTracks = match_views(images, camera, config)
        self.bundle: FeatureBundle = feature_bundle(self.tracks, self.camera)

    @property
    def active(self) -> bool:
        """True when the bundle has landmarks (it started the solve and judges it)."""
        return self.bundle.ok

    def initial_poses(self) -> List[np.ndarray]:
        """Per supporting view, its bundle pose ``T_ref_view`` (identity where none)."""
        return [np.eye(4) if T is None else T.copy() for T in self.bundle.T_ref_view[1:]]

    def unverified(self) -> List[bool]:
        """Per supporting view, True when the features could not place it (neither
        registered nor given a low-parallax rotation)."""
        return [s not in ("ok", "low_parallax") for s in self.bundle.view_status[1:]]

    def scaled_primitives(self, prims: PrimitiveSet, report: dict) -> PrimitiveSet:
        """``prims`` with log-scales from the depths of the landmarks seen in the
        reference (unchanged without landmarks); counts in ``report``."""
        b = self.bundle
        if not self.active:
            return prims
        px = self.tracks.track_pixels(0, b.track_rows)
        seen = np.isfinite(px[:, 0])
        prims, n_pts, n_prims = scales_from_points(prims, self.camera, px[seen],
                                                   b.points[seen, 2])
        report.update(landmark_points=n_pts, primitives_with_points=n_prims)
        return prims

    def poses_of(self, values: gtsam.Values) -> List[Optional[np.ndarray]]:
        """The bundle-registered views' poses in ``values`` (None for the others);
        the reference first."""
        return [None if T is None else values.atPose3(pose_key(v)).matrix()
                for v, T in enumerate(self.bundle.T_ref_view)]

    def choose_poses(self, values: gtsam.Values, report: dict) -> Tuple[gtsam.Values, bool]:
        """Per registered view, the photometric pose in ``values`` where the view's
        held-out matches fit it at least as well as the bundle's pose
        (:func:`heldout_errors`), else the bundle's.  Returns ``(values with the chosen
        poses, True when some view took the bundle's)``; the errors, the choices and
        the largest rotation the photometric term made go to ``report["heldout_px"]``."""
        b = self.bundle
        photo = self.poses_of(values)
        e_b = heldout_errors(self.tracks, b.heldout_rows, b.T_ref_view, self.camera)
        e_p = heldout_errors(self.tracks, b.heldout_rows, photo, self.camera)
        out = gtsam.Values(values)
        kept: List[bool] = []
        for v, T in enumerate(b.T_ref_view):
            if T is None or v == 0:
                continue
            kept.append(bool(e_p[v] <= e_b[v]) if np.isfinite(e_b[v]) else True)
            if not kept[-1]:
                out.update(pose_key(v), gtsam.Pose3(T))
        moved = [rotation_angle_deg(Tb[:3, :3].T @ Tp[:3, :3])
                 for Tb, Tp in zip(b.T_ref_view[1:], photo[1:]) if Tb is not None]
        report["heldout_px"] = {"features": e_b[1:].tolist(), "photometric": e_p[1:].tolist(),
                                "photometric_kept": kept,
                                "photometric_rotation_change_deg": max(moved, default=0.0)}
        log.debug("held-out Sampson px: features %s, photometric %s", e_b, e_p)
        return out, not all(kept)

    def hold_poses(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        """Tight priors holding the registered views' poses at ``values``."""
        for v, T in enumerate(self.bundle.T_ref_view):
            if T is not None and v > 0:
                graph.add(pose_gauge_prior(pose_key(v), values.atPose3(pose_key(v)).matrix()))

    def covariances(self) -> List[Optional[np.ndarray]]:
        """Per supporting view, the bundle's 6x6 pose covariance (None if unregistered)."""
        return list(self.bundle.covariances[1:])
