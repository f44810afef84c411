"""Result of :func:`spgeo.sfm.few_view_sfm`: :class:`SfMResult` and the
status assessment of a solution (:func:`assess_result`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from ..camera import PinholeCamera
from ..geometry import invert_pose, rotation_angle_deg
from ..primitives import PointCloud, PrimitiveSet
from .config import SfMConfig

__all__ = ["SfMResult", "assess_result"]


@dataclass
class SfMResult:
    """Output of :func:`spgeo.sfm.few_view_sfm`.

    Attributes:
        status: ``"ok"`` or the first problem found, in this order:
            ``"diverged"`` (non-finite result), ``"unverified"`` (the features
            could not place a view, which then started at identity: often little
            overlap, and the photometric result is not trusted; the features'
            reason is in ``report["init"]["view_status"]``), ``"low_parallax"``,
            ``"low_overlap"``.
        view_status: status per supporting view.
        T_ref_view: 4x4 pose of each supporting view in the reference camera
            (camera-to-reference), translation in the map's (unknown) scale.
        primitives: the reference primitives with solved log-scales (planar
            model: the planes' depths are baked into ``log_depth``).
        depth: (H, W) reference depth (metres up to the global scale), NaN where
            no reported primitive covers the pixel (see ``unconstrained``).
        camera: the reference camera at the working resolution.
        log_scale_std: (N,) gauge-free marginal std of each primitive's
            log-scale: conditioned on the mean log-scale, since the global scale
            is fixed only by the weak prior and its (large) variance is shared by
            every primitive (scaled model; NaN otherwise or when marginals are
            off/failed).
        unconstrained: indices of primitives whose depth the views do not
            support; they are in neither ``depth`` nor :meth:`point_cloud`.
            These are: every primitive when no view has parallax (each
            ``view_status`` is ``"low_parallax"`` or ``"diverged"``: the
            structure is not observable), or when the status is not ``"ok"``
            and the marginals failed (an indeterminate system:
            ``report["marginals_error"]``); otherwise those whose log-scale
            only the prior constrains (marginal std over half the prior's: no
            view sees them usefully) or whose ``log_scale_std`` exceeds
            ``config.max_log_scale_std`` (needs ``config.marginals``).
            ``primitives`` keeps every primitive at its solved (for these:
            unsupported) log-scale.
        pose_covariances: 6x6 covariance per view (rotation first, gtsam
            ``Pose3`` tangent at the estimate; radians and the map's translation
            units), conditioned on the gauge (the reference pose, and the distance
            to the farthest view for the scale).  With the landmark bundle
            (``init="features"``, a view it registered): the bundle adjustment's
            marginal with the projection noise at the robust spread of its
            reprojection residuals (``report["init"]["pixel_sigma"]``), inflated
            by :data:`spgeo.sfm.bundle.COVARIANCE_INFLATION` so that the real
            rotation error is within 3 sigma on at least 90 % of the views
            measured (docs/results.md, issue 40); None for a view the bundle did not
            register (no calibrated uncertainty: its pose is flagged or only a
            rotation).  With ``init="identity"`` or given initial poses (the VO):
            the photometric marginal with the residuals' robust std
            (``report["pixel_sigma"]``), pixels treated as independent: far too
            small (docs/results.md, issue 40), not a calibrated uncertainty.
        report: per-level iterations, costs, valid fractions, timings.
    """

    status: str
    view_status: List[str]
    T_ref_view: List[np.ndarray]
    primitives: PrimitiveSet
    depth: np.ndarray
    camera: PinholeCamera
    log_scale_std: np.ndarray
    pose_covariances: List[Optional[np.ndarray]]
    brightness: List[np.ndarray]
    report: dict
    unconstrained: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def view_rows(self) -> List[tuple]:
        """Per supporting view: ``(view, status, rotation deg, |t|)``
        (translation in the map's units), for :meth:`_repr_html_`."""
        return [(j + 1, s, f"{rotation_angle_deg(T[:3, :3]):.2f}",
                 f"{np.linalg.norm(T[:3, 3]):.3f}")
                for j, (s, T) in enumerate(zip(self.view_status, self.T_ref_view))]

    def __repr__(self) -> str:
        """One line: status, views, primitives (unconstrained), the depth's size
        and coverage, the views' rotations (degrees) and baselines (map units)."""
        h, w = self.depth.shape
        cover = float(np.isfinite(self.depth).mean()) if self.depth.size else 0.0
        views = ", ".join(f"{s} (rotation {r} deg, baseline {t})"
                          for _, s, r, t in self.view_rows()[:4])
        more = ", ..." if len(self.view_status) > 4 else ""
        return (f"SfMResult({self.status}, {len(self.primitives)} primitives "
                f"({len(self.unconstrained)} unconstrained), depth {w}x{h} covering "
                f"{100 * cover:.0f} %, {len(self.view_status)} views: {views}{more})")

    def _repr_html_(self) -> str:
        """The per-view table (notebooks)."""
        from ..html_table import html_table

        h, w = self.depth.shape
        title = (f"SfMResult: {self.status}, {len(self.primitives)} primitives "
                 f"({len(self.unconstrained)} unconstrained), depth {w}x{h}")
        return html_table(title, self.view_rows(),
                          ("view", "status", "rotation (deg)", "baseline (map units)"))

    @property
    def supported_primitives(self) -> PrimitiveSet:
        """The primitives that ``depth`` reports (all but ``unconstrained``, in
        order): what a point cloud or a model export of this result may show."""
        keep = np.setdiff1d(np.arange(len(self.primitives)), self.unconstrained)
        return self.primitives.subset(keep)

    def point_cloud(self, image: Optional[np.ndarray] = None) -> PointCloud:
        """Reference-frame point cloud of the solved primitives that ``depth``
        reports: those in ``unconstrained`` and non-finite points are left out
        (an empty cloud when nothing is supported).  ``image``: colours, at
        ``camera``'s size."""
        cloud = self.primitives.point_cloud(image)
        keep = np.all(np.isfinite(cloud.points), axis=1)
        if self.unconstrained.size:
            keep &= ~np.isin(cloud.primitive_ids, self.unconstrained)
        return PointCloud(cloud.points[keep], None if cloud.colors is None else cloud.colors[keep],
                          cloud.primitive_ids[keep], cloud.pixels[keep])


def assess_result(solved: PrimitiveSet, T_ref_view: List[np.ndarray], config: SfMConfig,
                  report: dict, unverified: Optional[Sequence[bool]] = None):
    """Status flags: diverged (non-finite), unverified, low parallax, low overlap.

    A view the features could not pose (``unverified[j]``: too few matches, a
    degenerate pair, not registered) most likely shares little with the
    reference: photometric alignment from identity can then "converge" to a wrong
    pose, so it is ``unverified`` rather than ``ok``.
    """
    finite = all(np.all(np.isfinite(T)) for T in T_ref_view) and np.all(
        np.isfinite(solved.log_scales))
    cam = solved.camera
    w = cam.width
    uv = np.stack([solved.pixels % w, solved.pixels // w], -1).astype(float)
    X = cam.unproject(uv, np.exp(solved.scaled_log_depth()))
    med_depth = float(np.median(X[:, 2])) if finite else np.nan
    view_status, valid_frac = [], []
    for j, T in enumerate(T_ref_view):
        if not finite:
            view_status.append("diverged")
            valid_frac.append(0.0)
            continue
        T_v_r = invert_pose(T)
        Y = X @ T_v_r[:3, :3].T + T_v_r[:3, 3]
        uvv, z = cam.project(Y)
        frac = float(np.mean(cam.in_image(uvv) & (z > 0)))
        valid_frac.append(frac)
        parallax = np.linalg.norm(T[:3, 3]) / max(med_depth, 1e-12)
        if unverified is not None and unverified[j]:
            view_status.append("unverified")
        elif parallax < config.min_parallax:
            view_status.append("low_parallax")
        elif frac < config.min_valid_fraction:
            view_status.append("low_overlap")
        else:
            view_status.append("ok")
    report["parallax"] = [float(np.linalg.norm(T[:3, 3]) / max(med_depth, 1e-12)) if finite
                          else None for T in T_ref_view]
    report["rotation_deg"] = [rotation_angle_deg(T) if finite else None for T in T_ref_view]
    order = ("diverged", "unverified", "low_parallax", "low_overlap")
    status = next((s for s in order if s in view_status), "ok")
    return status, view_status, valid_frac
