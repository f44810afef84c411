"""Landmark bundle adjustment of a few views (few-view SfM, docs/design.md §5).

From the tracks of :func:`spgeo.sfm.tracks.match_views`:

1. **Initial pair**: the verified pair (status ``"ok"``, not left ambiguous by a
   plane: :func:`spgeo.sfm.tracks.planar_alternatives`) whose translation direction
   is best conditioned (least first-order std), posed by its essential matrix with a
   unit baseline; the tracks it sees are triangulated (multi-view linear DLT).
2. **The other views by PnP** (``cv2.solvePnPRansac``) on the tracks already
   triangulated, the view with the most such tracks first, each followed by a new
   triangulation: a view far from the reference is placed through a nearer one.
3. **Bundle adjustment** in GTSAM: ``Pose3`` views and ``Point3`` landmarks joined by
   ``GenericProjectionFactorCal3_S2`` factors (Huber, pixels).  Gauge: a tight prior
   on the reference pose (identity) and a ``RangeFactorPose3`` holding the distance
   from the reference to the farthest view (the unknown monocular scale).
4. **Covariances**: the views' marginal covariances with the projection noise set to
   the robust spread of the reprojection residuals corrected for the degrees of freedom
   the adjustment absorbed (:func:`_noise_sigma`), times ``COVARIANCE_INFLATION``
   (measured: docs/results.md, issue 40).

One track in ``HELDOUT_EVERY`` never enters the adjustment: its matches judge poses
independently of the landmarks and of the photometric term
(:func:`heldout_errors`: median Sampson distance per view).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import cv2
import numpy as np

import gtsam

from ..camera import PinholeCamera
from ..factors.priors import pose_gauge_prior
from ..geometry import invert_pose, transform_points
from ..graph.builders import projection_model
from ..graph.keys import landmark_key, pose_key
from ..triangulation import triangulate
from ..twoview.geometry import sampson_px
from .tracks import ViewTracks

__all__ = ["FeatureBundle", "feature_bundle", "heldout_errors", "triangulate_tracks",
           "add_landmark_factors", "HELDOUT_EVERY", "COVARIANCE_INFLATION"]

log = logging.getLogger(__name__)

#: one track in this many is held out of the adjustment (the acceptance check's)
HELDOUT_EVERY = 5
#: factor on the marginal standard deviations, calibrated on the synthetic rooms and the
#: shared 7-Scenes triplets judged by COLMAP on the whole clip (docs/results.md, issue 40):
#: the model errors the residuals cannot see (intrinsics, distortion, rolling shutter,
#: SIFT's localisation bias)
COVARIANCE_INFLATION = 5.0
#: projection factors: sigma and Huber threshold (pixels); new points' reprojection gate
PIXEL_SIGMA, HUBER_PX, GATE_PX = 1.0, 2.0, 4.0
#: least angle (degrees) between two rays of a triangulated landmark
MIN_RAY_ANGLE_DEG = 0.5
#: least PnP inliers that register a view; least landmarks that scale a pair's baseline
MIN_PNP_INLIERS, MIN_SCALE_POINTS = 20, 3


@dataclass
class FeatureBundle:
    """The landmark bundle of :func:`feature_bundle`.

    Attributes:
        T_ref_view: per view (view 0 the reference, identity), its 4x4 pose in the
            reference camera (camera-to-reference), or None when not registered.
            Translations in units of the reference's distance to the farthest view
            (1.0).
        view_status: per view, ``"ok"`` or why it is not registered
            (``"no_initial_pair"``: no pair has an essential matrix;
            ``"unregistered"``: too few PnP inliers and no verified pair with a
            registered view; ``"low_parallax"``: only a rotation, from the view's
            pair with the reference, and a zero translation).
        track_rows: (L,) rows of ``ViewTracks.tracks`` that are landmarks.
        points: (L, 3) landmark positions in the reference camera.
        heldout_rows: rows of ``ViewTracks.tracks`` held out of the adjustment.
        covariances: per view, the 6x6 marginal covariance of its pose (rotation
            first, gtsam ``Pose3`` tangent, radians and translation units), None
            for the reference and unregistered views.
        pixel_sigma: robust std of the reprojection residuals (pixels).
        report: the initial pair, counts, costs.
    """

    T_ref_view: List[Optional[np.ndarray]]
    view_status: List[str]
    track_rows: np.ndarray
    points: np.ndarray
    heldout_rows: np.ndarray
    covariances: List[Optional[np.ndarray]]
    pixel_sigma: float = float("nan")
    report: Dict[str, object] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when the reference and some other view are registered with landmarks."""
        return len(self.points) > 0 and any(s == "ok" for s in self.view_status[1:])


def triangulate_tracks(vt: ViewTracks, rows: np.ndarray, poses: Dict[int, np.ndarray],
                       camera: PinholeCamera) -> np.ndarray:
    """(len(rows), 3) points of tracks ``rows`` by linear DLT over their pixels in the
    views of ``poses`` (view -> camera-to-world 4x4), :func:`spgeo.triangulation.triangulate`;
    NaN for a track seen by fewer than two of them, behind a camera, reprojecting
    beyond ``GATE_PX`` or with rays less than ``MIN_RAY_ANGLE_DEG`` apart."""
    views = sorted(poses)
    pixels = np.stack([vt.track_pixels(v, rows) for v in views], axis=1)
    return triangulate(camera, [poses[v] for v in views], pixels, GATE_PX, MIN_RAY_ANGLE_DEG)


def _initial_pair(vt: ViewTracks):
    """The best-conditioned verified pair ``(a, b)`` (least translation-direction
    std, then most inliers), or None."""
    ok = [(r.translation_std_deg, -r.num_inliers, k) for k, r in vt.pairs.items()
          if r.ok and k not in vt.alternatives]
    return min(ok)[2] if ok else None


def _register(vt: ViewTracks, v: int, rows: np.ndarray, X: np.ndarray,
              camera: PinholeCamera) -> Optional[np.ndarray]:
    """Camera-to-world pose of view ``v`` by PnP RANSAC on the points ``X`` of tracks
    ``rows`` it sees, or None with fewer than ``MIN_PNP_INLIERS`` inliers."""
    x = vt.track_pixels(v, rows)
    use = np.isfinite(x[:, 0]) & np.all(np.isfinite(X), axis=1)
    if use.sum() < MIN_PNP_INLIERS:
        return None
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        X[use].astype(np.float64), x[use].astype(np.float64), camera.K, None,
        iterationsCount=2000, reprojectionError=2.0, confidence=0.999,
        flags=cv2.SOLVEPNP_SQPNP)
    if not ok or inl is None or len(inl) < MIN_PNP_INLIERS:
        return None
    ok, rvec, tvec = cv2.solvePnP(X[use][inl[:, 0]], x[use][inl[:, 0]], camera.K, None,
                                  rvec, tvec, useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    T_cam_world = np.eye(4)
    T_cam_world[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_cam_world[:3, 3] = tvec.ravel()
    return invert_pose(T_cam_world)


def _pair_poses(vt: ViewTracks, u: int, v: int) -> List[np.ndarray]:
    """The candidate ``T_u_v`` (unit translation) of the verified pair of views ``u``,
    ``v``: its pose and, for a plane, the alternatives; empty if not verified."""
    key = (min(u, v), max(u, v))
    res = vt.pairs[key]
    if not res.ok:
        return []
    cands = [res.T_ref_tgt] + vt.alternatives.get(key, [])
    return [T.copy() if u < v else invert_pose(T) for T in cands]


def _register_by_pair(vt: ViewTracks, v: int, rows: np.ndarray, X: np.ndarray,
                      poses: Dict[int, np.ndarray], camera: PinholeCamera
                      ) -> Optional[np.ndarray]:
    """Camera-to-world pose of view ``v`` from its verified pair with a registered view
    ``u`` (the one sharing the most landmarks ``X`` of tracks ``rows``): the pair's
    rotation and translation direction (of a plane's candidates, the one whose
    landmarks reproject best into ``v``), the baseline from the median depth ratio
    of at least ``MIN_SCALE_POINTS`` shared landmarks; None when no pair qualifies
    or the median reprojection error exceeds ``GATE_PX``."""
    best = None
    for u in poses:
        common = np.isfinite(X[:, 0]) & vt.observed([u, v])[rows]
        cands = _pair_poses(vt, u, v)
        if cands and common.sum() >= MIN_SCALE_POINTS and (
                best is None or common.sum() > best[1].sum()):
            best = (u, common, cands)
    if best is None:
        return None
    u, common, cands = best
    scored = [c for c in (_scaled_candidate(vt, T_uv, u, poses[u], rows[common], X[common], v,
                                            camera) for T_uv in cands) if c is not None]
    err, T_world_v = min(scored, key=lambda c: c[0], default=(np.inf, None))
    return T_world_v if err <= GATE_PX else None


def _scaled_candidate(vt: ViewTracks, T_uv: np.ndarray, u: int, T_world_u: np.ndarray,
                      rows: np.ndarray, X: np.ndarray, v: int, camera: PinholeCamera):
    """``(median reprojection error in v (px), camera-to-world pose of v)`` of the
    candidate ``T_uv`` with its baseline scaled to the landmarks ``X`` of tracks
    ``rows`` (seen by ``u`` and ``v``), or None with too few usable points."""
    z_map = transform_points(invert_pose(T_world_u), X)[:, 2]
    Z = triangulate_tracks(vt, rows, {u: np.eye(4), v: T_uv}, camera)
    ratio = z_map / Z[:, 2]
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    if ratio.size < MIN_SCALE_POINTS:
        return None
    T = T_uv.copy()
    T[:3, 3] *= float(np.median(ratio))
    T_world_v = T_world_u @ T
    uv, z = camera.project(transform_points(invert_pose(T_world_v), X))
    err = np.where(z > 0, np.linalg.norm(uv - vt.track_pixels(v, rows), axis=1), np.inf)
    return float(np.median(err)), T_world_v


def _incremental_poses(vt: ViewTracks, train: np.ndarray, camera: PinholeCamera,
                       report: dict) -> Dict[int, np.ndarray]:
    """Camera-to-world poses (the initial pair's first view at identity) of the views
    registered by the initial pair and PnP (module docstring, steps 1-2)."""
    pair = _initial_pair(vt)
    report["initial_pair"] = pair
    if pair is None:
        return {}
    a, b = pair
    poses = {a: np.eye(4), b: vt.pairs[pair].T_ref_tgt.copy()}
    X = triangulate_tracks(vt, train, poses, camera)
    left = [v for v in range(vt.n_views) if v not in poses]
    while left:
        seen = {v: int(np.sum(np.isfinite(X[:, 0]) & (vt.tracks[train, v] >= 0))) for v in left}
        v = max(left, key=lambda u: (seen[u], -u))
        left.remove(v)
        T = _register(vt, v, train, X, camera)
        if T is None:
            T = _register_by_pair(vt, v, train, X, poses, camera)
        if T is None:
            log.info("few-view SfM: view %d not registered (%d landmarks seen)", v, seen[v])
            continue
        poses[v] = T
        X = triangulate_tracks(vt, train, poses, camera)
    return poses


def add_landmark_factors(graph: gtsam.NonlinearFactorGraph, vt: ViewTracks,
                         bundle: "FeatureBundle", camera: PinholeCamera,
                         pixel_sigma: float = PIXEL_SIGMA) -> int:
    """Projection factors of ``bundle``'s landmarks (keys
    :func:`~spgeo.graph.keys.landmark_key` of their index) in the registered views
    (keys :func:`~spgeo.graph.keys.pose_key` of the view index; the reference is 0),
    Huber at ``HUBER_PX``, and the scale gauge (``RangeFactorPose3`` from the
    reference to the farthest registered view at its current distance).  Returns
    the number of projection factors."""
    cal, noise = projection_model(camera.K, pixel_sigma, HUBER_PX)
    n = 0
    for v, T in enumerate(bundle.T_ref_view):
        if T is None:
            continue
        x = vt.track_pixels(v, bundle.track_rows)
        for i in np.flatnonzero(np.isfinite(x[:, 0])):
            graph.add(gtsam.GenericProjectionFactorCal3_S2(x[i], noise, pose_key(v),
                                                           landmark_key(int(i)), cal))
            n += 1
    far = max((v for v, T in enumerate(bundle.T_ref_view) if T is not None and v > 0),
              key=lambda v: np.linalg.norm(bundle.T_ref_view[v][:3, 3]))
    dist = float(np.linalg.norm(bundle.T_ref_view[far][:3, 3]))
    graph.add(gtsam.RangeFactorPose3(pose_key(0), pose_key(far), dist,
                                     gtsam.noiseModel.Isotropic.Sigma(1, 1e-4 * dist)))
    return n


def _bundle_graph(vt: ViewTracks, bundle: FeatureBundle, camera: PinholeCamera,
                  pixel_sigma: float = PIXEL_SIGMA):
    """``(graph, values)`` of the landmark bundle adjustment (module docstring, step 3)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(pose_gauge_prior(pose_key(0)))
    for v, T in enumerate(bundle.T_ref_view):
        if T is not None:
            values.insert(pose_key(v), gtsam.Pose3(T))
    for i, P in enumerate(bundle.points):
        values.insert(landmark_key(i), gtsam.Point3(*P))
    add_landmark_factors(graph, vt, bundle, camera, pixel_sigma)
    return graph, values


def _residuals(vt: ViewTracks, bundle: FeatureBundle, camera: PinholeCamera) -> np.ndarray:
    """(R,) reprojection residual components (pixels) of every landmark observation."""
    out = []
    for v, T in enumerate(bundle.T_ref_view):
        if T is None:
            continue
        x = vt.track_pixels(v, bundle.track_rows)
        seen = np.isfinite(x[:, 0])
        uv, _ = camera.project(transform_points(invert_pose(T), bundle.points[seen]))
        out.append((uv - x[seen]).ravel())
    return np.concatenate(out) if out else np.zeros(0)


def _to_reference(poses: Dict[int, np.ndarray], n_views: int) -> List[Optional[np.ndarray]]:
    """Poses relative to view 0 (camera-to-reference), scaled so that the farthest
    view is at distance 1; None for views not in ``poses``."""
    T_ref_world = invert_pose(poses[0])
    rel = [None if v not in poses else T_ref_world @ poses[v] for v in range(n_views)]
    far = max(float(np.linalg.norm(T[:3, 3])) for T in rel if T is not None)
    for T in rel:
        if T is not None:
            T[:3, 3] /= max(far, 1e-12)
    return rel


def _noise_sigma(res: np.ndarray, bundle: FeatureBundle) -> float:
    """The keypoints' noise (pixels) from the adjusted residual components ``res``: their
    robust (MAD) spread corrected for the degrees of freedom the adjustment absorbed,
    ``sqrt(m / (m - n))`` for ``m`` residuals and ``n`` free parameters (3 per landmark,
    6 per view, less the 7 of the gauge); a two-view track keeps 1 of its 4 residuals'
    degrees of freedom, so its spread alone would halve the noise.  At least 0.05 px."""
    if res.size == 0:
        return PIXEL_SIGMA
    n_views = sum(T is not None for T in bundle.T_ref_view)
    n = 3 * len(bundle.points) + 6 * n_views - 7
    mad = 1.4826 * float(np.median(np.abs(res)))
    return max(mad * float(np.sqrt(res.size / max(res.size - n, 1))), 0.05)


def _adjust(vt: ViewTracks, bundle: FeatureBundle, camera: PinholeCamera) -> FeatureBundle:
    """Bundle adjustment of ``bundle`` in place (poses, points), then the residuals'
    robust spread and the views' marginal covariances (module docstring, 3-4)."""
    graph, values = _bundle_graph(vt, bundle, camera)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-6)
    err0 = graph.error(values)
    values = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    bundle.report.update(cost_initial=float(err0), cost_final=float(graph.error(values)))
    bundle.T_ref_view = [None if T is None else values.atPose3(pose_key(v)).matrix()
                         for v, T in enumerate(bundle.T_ref_view)]
    bundle.points = np.array([values.atPoint3(landmark_key(i))
                              for i in range(len(bundle.points))]).reshape(-1, 3)
    bundle.pixel_sigma = _noise_sigma(_residuals(vt, bundle, camera), bundle)
    try:
        graph, _ = _bundle_graph(vt, bundle, camera, bundle.pixel_sigma)
        marg = gtsam.Marginals(graph, values)
        bundle.covariances = [None if (T is None or v == 0) else
                              marg.marginalCovariance(pose_key(v)) * COVARIANCE_INFLATION ** 2
                              for v, T in enumerate(bundle.T_ref_view)]
    except RuntimeError as exc:
        bundle.report["marginals_error"] = str(exc).split("\n")[0]
    return _unit_scale(bundle)


def _unit_scale(bundle: FeatureBundle) -> FeatureBundle:
    """``bundle`` (in place) at the scale where the farthest view is at distance 1
    from the reference: translations, points and the covariances' translation parts."""
    far = max(float(np.linalg.norm(T[:3, 3])) for T in bundle.T_ref_view[1:] if T is not None)
    s = 1.0 / max(far, 1e-12)
    for T in bundle.T_ref_view:
        if T is not None:
            T[:3, 3] *= s
    bundle.points = bundle.points * s
    D = np.diag([1.0, 1.0, 1.0, s, s, s])
    bundle.covariances = [None if C is None else D @ C @ D for C in bundle.covariances]
    return bundle


def _unregistered(vt: ViewTracks, held: np.ndarray, report: dict) -> FeatureBundle:
    """The bundle when the reference is not registered: a view whose pair with the
    reference is ``"low_parallax"`` keeps that pair's rotation (zero translation,
    status ``"low_parallax"``); the others are ``"no_initial_pair"`` (no verified
    pair at all) or ``"unregistered"``."""
    n = vt.n_views
    why = "no_initial_pair" if report["initial_pair"] is None else "unregistered"
    poses: List[Optional[np.ndarray]] = [np.eye(4)] + [None] * (n - 1)
    status = ["ok"] + [why] * (n - 1)
    for v in range(1, n):
        if vt.pairs[(0, v)].status == "low_parallax":
            poses[v], status[v] = vt.pairs[(0, v)].T_ref_tgt.copy(), "low_parallax"
    return FeatureBundle(poses, status, np.zeros(0, np.int64), np.zeros((0, 3)), held,
                         [None] * n, report=report)


def feature_bundle(vt: ViewTracks, camera: PinholeCamera) -> FeatureBundle:
    """The landmark bundle of the views of ``vt`` (module docstring).

    Args:
        vt: tracks of the views (view 0 the reference), :func:`~spgeo.sfm.tracks.match_views`.
        camera: the images' intrinsics (undistorted).
    Returns:
        :class:`FeatureBundle`; when the reference is not registered (no verified
        pair, or PnP failed for it) every view is flagged and no pose is given.
    """
    n = vt.n_views
    rows = np.arange(len(vt.tracks))
    held = rows[rows % HELDOUT_EVERY == HELDOUT_EVERY // 2]
    train = np.setdiff1d(rows, held)
    report: Dict[str, object] = {"tracks": int(len(rows)), "heldout_tracks": int(len(held))}
    poses = _incremental_poses(vt, train, camera, report)
    if 0 not in poses or len(poses) < 2:
        return _unregistered(vt, held, report)
    rel = _to_reference(poses, n)
    X = triangulate_tracks(vt, train, {v: T for v, T in enumerate(rel) if T is not None}, camera)
    keep = np.all(np.isfinite(X), axis=1)
    status = ["ok" if T is not None else "unregistered" for T in rel]
    bundle = FeatureBundle(rel, status, train[keep], X[keep], held, [None] * n, report=report)
    report["landmarks"] = int(keep.sum())
    return _adjust(vt, bundle, camera)


def heldout_errors(vt: ViewTracks, rows: np.ndarray, T_ref_view: Sequence[Optional[np.ndarray]],
                   camera: PinholeCamera) -> np.ndarray:
    """(n,) per view, the median absolute Sampson distance (pixels) of the matches of
    tracks ``rows`` between it and every other posed view under the poses
    ``T_ref_view`` (None: not posed); NaN for an unposed view or one with no such
    match.  It needs neither the landmarks nor the primitives."""
    n = len(T_ref_view)
    errs: List[List[np.ndarray]] = [[] for _ in range(n)]
    for a in range(n):
        for b in range(a + 1, n):
            if T_ref_view[a] is None or T_ref_view[b] is None:
                continue
            both = rows[vt.observed([a, b])[rows]]
            if not len(both):
                continue
            T_b_a = invert_pose(T_ref_view[b]) @ T_ref_view[a]
            e = np.abs(sampson_px(camera, T_b_a[:3, :3], T_b_a[:3, 3],
                                  vt.track_pixels(a, both), vt.track_pixels(b, both)))
            errs[a].append(e)
            errs[b].append(e)
    return np.array([float(np.median(np.concatenate(e))) if e else np.nan for e in errs])
