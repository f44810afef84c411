"""Rotations, orientation and local scale of a trajectory judged against a reference trajectory.

7-Scenes' ground truth (KinectFusion on the depth camera) cannot judge rotations at the
degree level (issue 30); COLMAP's offline reconstruction of the same frames
(:mod:`spgeo.evaluation.references.colmap_vo`) can.  These metrics compare an estimate
``A`` with any reference ``B`` (COLMAP, or the ground truth) on the same frames:

* :func:`relative_rotation_error`: over a fixed frame gap ``g`` (default
  :data:`DEFAULT_GAP` = 30 frames), the angle of
  ``(R_A,i^T R_A,i+g)^-1 (R_B,i^T R_B,i+g)``, degrees: mean / median / max.
  Independent of the two world frames and of scale.
* :func:`orientation_error`: absolute orientation after the best constant rotation
  ``R_align`` (the chordal L2 mean of ``R_B,i R_A,i^T``, projected onto SO(3)), then
  per frame the angle between ``R_align R_A,i`` and ``R_B,i``: median / max, degrees.
* :func:`window_scale`: over sliding windows (default :data:`DEFAULT_WINDOW` = 50
  frames), the Sim(3) scale (Umeyama, :func:`spgeo.similarity.umeyama`) that takes A's
  camera centres onto B's; reported relative to the same fit over all frames as
  ``ratio = s_window / s_all`` (1 where the window needs the whole run's scale; > 1
  where A's window is small against B's, i.e. A's scale shrank there), with its
  min / max and the spread max / min.
* :func:`edge_errors`: measured relative poses between two frames (loop edges,
  ``T_i_j = inv(T_world_i) T_world_j``, rigid or Sim(3)) against the reference's
  relative pose of the same two frames: rotation angle and translation direction, degrees.
* :func:`compare_to_reference`: the first three plus the position ATE
  (:func:`~spgeo.evaluation.trajectory.ate_sim3`, Sim(3)) in one
  :class:`ReferenceComparison`.

Inputs are ``(timestamps (n,), poses (n, 4, 4))`` camera-to-world ``T_world_cam``
stacks, a :class:`~spgeo.trajectory.Trajectory` (frames that are not ``tracked``, e.g.
``lost``, count as missing) or any object with ``timestamps`` and ``poses``.  A's
timestamps are the frame timeline: frame gaps and windows count A's entries in time
order, so A should list every frame (NaN poses for frames without one, as VO results
and :meth:`~spgeo.trajectory.Trajectory.load` with a status file do).  Each A frame
takes the B pose of the nearest timestamp within ``max_time_diff`` (default
:func:`~spgeo.evaluation.trajectory.default_max_time_diff` of A's timestamps); frames
missing in either are skipped.  Statistics of nothing are NaN with ``n = 0``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from spgeo.geometry import nearest_rotation
from spgeo.similarity import sim3_parts, umeyama
from spgeo.trajectory import Trajectory

from spgeo.evaluation.pose_metrics import relative_pose_errors, rotation_error_deg
from spgeo.evaluation.tables import MISSING, cell, markdown_table
from spgeo.evaluation.trajectory import AteResult, ate_sim3, default_max_time_diff

__all__ = ["DEFAULT_GAP", "DEFAULT_WINDOW", "AssociatedPoses", "associate_poses",
           "RelativeRotationError", "relative_rotation_error", "OrientationError",
           "orientation_error", "WindowScale", "window_scale", "EdgeErrors", "edge_errors",
           "ReferenceComparison",
           "compare_to_reference"]

#: Frame gap of :func:`relative_rotation_error` (frames).
DEFAULT_GAP = 30
#: Window of :func:`window_scale` (frames).
DEFAULT_WINDOW = 50


def _stats(values: np.ndarray) -> Tuple[float, float, float]:
    """``(mean, median, max)`` of ``values``, NaN for none."""
    if len(values) == 0:
        return float("nan"), float("nan"), float("nan")
    return float(np.mean(values)), float(np.median(values)), float(np.max(values))


def _arrays(traj, name: str) -> Tuple[np.ndarray, np.ndarray]:
    """``(timestamps (n,), poses (n, 4, 4))`` float64 of a trajectory-like input, sorted by
    time (stable), NaN poses where a :class:`Trajectory` frame is not ``tracked``."""
    if isinstance(traj, Trajectory):
        ts, poses = traj.timestamps, traj.poses.copy()
        poses[~traj.tracked] = np.nan
    elif hasattr(traj, "timestamps") and hasattr(traj, "poses"):
        ts, poses = traj.timestamps, traj.poses
    else:
        try:
            ts, poses = traj
        except (TypeError, ValueError):
            raise TypeError(f"{name}: expected (timestamps, poses) or a Trajectory, "
                            f"got {type(traj).__name__}") from None
    ts = np.asarray(ts, dtype=np.float64).reshape(-1)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(ts) != len(poses):
        raise ValueError(f"{name}: {len(ts)} timestamps for {len(poses)} poses")
    order = np.argsort(ts, kind="stable")
    return ts[order], poses[order]


@dataclass
class AssociatedPoses:
    """A and B on A's frame timeline (:func:`associate_poses`).

    Attributes:
        timestamps: (n,) A's timestamps, in time order.
        poses_a: (n, 4, 4) A's ``T_world_cam`` (NaN: no pose).
        poses_b: (n, 4, 4) B's ``T_world_cam`` at the nearest timestamp within the
            tolerance (NaN: none, or B has no pose there).
    """

    timestamps: np.ndarray
    poses_a: np.ndarray
    poses_b: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(n,) bool: frames with a finite pose in both."""
        n = len(self.timestamps)
        return (np.all(np.isfinite(self.poses_a.reshape(n, -1)), axis=1)
                & np.all(np.isfinite(self.poses_b.reshape(n, -1)), axis=1))


def associate_poses(est, ref, max_time_diff: Optional[float] = None) -> AssociatedPoses:
    """B's pose for each of A's frames: the nearest B timestamp within ``max_time_diff``
    (same unit as the timestamps; default
    :func:`~spgeo.evaluation.trajectory.default_max_time_diff` of A's), NaN where none.
    ``est`` = A, ``ref`` = B (module docstring for the accepted types).  Raises
    ``ValueError`` for mismatched lengths or a tolerance <= 0."""
    ts_a, poses_a = _arrays(est, "est")
    ts_b, poses_b = _arrays(ref, "ref")
    tol = default_max_time_diff(ts_a) if max_time_diff is None else float(max_time_diff)
    if not tol > 0:
        raise ValueError(f"associate_poses: max_time_diff must be > 0, got {max_time_diff}")
    out = np.full_like(poses_a, np.nan)
    if len(ts_b) and len(ts_a):
        j = np.searchsorted(ts_b, ts_a)
        lo, hi = np.clip(j - 1, 0, len(ts_b) - 1), np.clip(j, 0, len(ts_b) - 1)
        near = np.where(np.abs(ts_b[lo] - ts_a) <= np.abs(ts_b[hi] - ts_a), lo, hi)
        ok = np.abs(ts_b[near] - ts_a) <= tol
        out[ok] = poses_b[near[ok]]
    return AssociatedPoses(ts_a, poses_a, out)


# ------------------------------------------------------------------ relative rotation
@dataclass
class RelativeRotationError:
    """:func:`relative_rotation_error`: degrees over a gap of ``gap`` frames.

    Attributes:
        gap: frames between the two poses of a pair.
        n: pairs evaluated (both frames posed in A and B).
        mean_deg, median_deg, max_deg: statistics of ``angles_deg`` (NaN when n = 0).
        timestamps: (n,) A's timestamp of each pair's first frame.
        angles_deg: (n,) the angle of each pair.
    """

    gap: int
    n: int
    mean_deg: float
    median_deg: float
    max_deg: float
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    angles_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no per-pair arrays)."""
        return {"gap_frames": self.gap, "n_pairs": self.n, "mean_deg": self.mean_deg,
                "median_deg": self.median_deg, "max_deg": self.max_deg}


def relative_rotation_error(est, ref, gap: int = DEFAULT_GAP,
                            max_time_diff: Optional[float] = None) -> RelativeRotationError:
    """Relative rotation error of A (``est``) against B (``ref``) over ``gap`` frames.

    For every frame ``i`` of A's timeline with ``i`` and ``i + gap`` posed in both, the
    angle (degrees) of ``(R_A,i^T R_A,i+gap)^-1 (R_B,i^T R_B,i+gap)``
    (:func:`~spgeo.evaluation.pose_metrics.rotation_error_deg`): the rotation each
    makes over the gap, in its own first camera's frame, compared; independent of the
    world frames and of scale.  Association: :func:`associate_poses`.
    Raises ``ValueError`` for ``gap`` < 1.
    """
    if int(gap) < 1:
        raise ValueError(f"relative_rotation_error: gap must be >= 1, got {gap}")
    g = int(gap)
    pairs = associate_poses(est, ref, max_time_diff)
    valid = pairs.valid
    starts = np.flatnonzero(valid[:-g] & valid[g:]) if len(valid) > g else np.zeros(0, int)
    Ra, Rb = pairs.poses_a[:, :3, :3], pairs.poses_b[:, :3, :3]
    angles = np.array([rotation_error_deg(Ra[i].T @ Ra[i + g], Rb[i].T @ Rb[i + g])
                       for i in starts], dtype=np.float64)
    mean, median, mx = _stats(angles)
    return RelativeRotationError(g, len(angles), mean, median, mx,
                                 pairs.timestamps[starts], angles)


# ------------------------------------------------------------------ absolute orientation
@dataclass
class OrientationError:
    """:func:`orientation_error`: per-frame orientation after the best constant rotation.

    Attributes:
        n: frames evaluated (posed in A and B).
        mean_deg, median_deg, max_deg: statistics of ``angles_deg`` (NaN when n = 0).
        R_align: 3x3 rotation taking A's world orientation to B's (identity when n = 0).
        timestamps, angles_deg: (n,) each frame's A timestamp and angle in degrees.
    """

    n: int
    mean_deg: float
    median_deg: float
    max_deg: float
    R_align: np.ndarray = field(default_factory=lambda: np.eye(3), repr=False)
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    angles_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no per-frame arrays)."""
        return {"n_frames": self.n, "mean_deg": self.mean_deg, "median_deg": self.median_deg,
                "max_deg": self.max_deg}


def orientation_error(est, ref, max_time_diff: Optional[float] = None) -> OrientationError:
    """Absolute orientation error of A (``est``) against B (``ref``) after the best
    constant rotation.

    ``R_align`` = the rotation nearest (SVD projection,
    :func:`spgeo.geometry.nearest_rotation`) to ``sum_i R_B,i R_A,i^T``: the
    chordal L2 mean, which minimises ``sum_i ||R_align R_A,i - R_B,i||_F^2``.  Then per
    frame the angle (degrees) between ``R_align R_A,i`` and ``R_B,i``.  Only the
    rotation blocks are used (positions and scale do not enter).  Association:
    :func:`associate_poses`; frames missing in either are skipped.
    """
    pairs = associate_poses(est, ref, max_time_diff)
    idx = np.flatnonzero(pairs.valid)
    if len(idx) == 0:
        nan = float("nan")
        return OrientationError(0, nan, nan, nan)
    Ra, Rb = pairs.poses_a[idx, :3, :3], pairs.poses_b[idx, :3, :3]
    R_align = nearest_rotation(np.einsum("nij,nkj->ik", Rb, Ra))
    angles = np.array([rotation_error_deg(R_align @ a, b) for a, b in zip(Ra, Rb)],
                      dtype=np.float64)
    mean, median, mx = _stats(angles)
    return OrientationError(len(idx), mean, median, mx, R_align, pairs.timestamps[idx], angles)


# ------------------------------------------------------------------ window scale
@dataclass
class WindowScale:
    """:func:`window_scale`: A's scale relative to B's over sliding windows.

    Attributes:
        window: frames per window; n_windows: windows with a scale.
        n_degenerate: windows with enough frames whose Umeyama fit failed (e.g. the
            camera centres collinear or coincident).
        global_scale: Umeyama scale of all common frames (B units per A unit; NaN
            when that fit fails).
        min, max: of ``ratios`` (NaN without windows); spread: ``max / min``.
        timestamps: (n_windows,) A's timestamp of each window's first frame.
        scales: (n_windows,) each window's Umeyama scale (B units per A unit).
        ratios: (n_windows,) ``scales / global_scale``: the scale A's window needs
            onto B relative to the whole run's (1 = the run's own scale; > 1: A is
            smaller than B there than on the whole).
    """

    window: int
    n_windows: int
    n_degenerate: int
    global_scale: float
    min: float
    max: float
    spread: float
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    scales: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    ratios: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no per-window arrays)."""
        return {"window_frames": self.window, "n_windows": self.n_windows,
                "n_degenerate": self.n_degenerate, "global_scale": self.global_scale,
                "min": self.min, "max": self.max, "spread": self.spread}


def _scale(src: np.ndarray, dst: np.ndarray) -> Optional[float]:
    """Umeyama Sim(3) scale of ``src`` onto ``dst`` ((N, 3) each), None when degenerate."""
    S = umeyama(src, dst, with_scale=True)
    return None if S is None else sim3_parts(S)[2]


def window_scale(est, ref, window: int = DEFAULT_WINDOW, stride: int = 1,
                 min_frames: Optional[int] = None,
                 max_time_diff: Optional[float] = None) -> WindowScale:
    """A's (``est``) scale against B's (``ref``) over sliding windows of A's timeline.

    Windows start every ``stride`` frames and span ``window`` frames (only full-length
    windows); one with at least ``min_frames`` frames posed in both (default
    ``max(3, window // 2)``) gets the Umeyama Sim(3) scale of A's camera centres onto
    B's (:func:`spgeo.similarity.umeyama`).  Ratios are relative to the fit over all
    common frames (:class:`WindowScale`).  Association: :func:`associate_poses`.
    Raises ``ValueError`` for ``window`` < 3, ``stride`` < 1 or ``min_frames`` < 3.
    """
    window, stride = int(window), int(stride)
    need = max(3, window // 2) if min_frames is None else int(min_frames)
    if window < 3 or stride < 1 or need < 3:
        raise ValueError(f"window_scale: need window >= 3, stride >= 1, min_frames >= 3 "
                         f"(got {window}, {stride}, {need})")
    pairs = associate_poses(est, ref, max_time_diff)
    valid = pairs.valid
    pa, pb = pairs.poses_a[:, :3, 3], pairs.poses_b[:, :3, 3]
    s_all = _scale(pa[valid], pb[valid]) if valid.sum() >= 3 else None
    starts, scales, degenerate = [], [], 0
    for k in range(0, len(valid) - window + 1, stride):
        idx = np.flatnonzero(valid[k:k + window]) + k
        if len(idx) < need:
            continue
        s = _scale(pa[idx], pb[idx])
        if s is None:
            degenerate += 1
            continue
        starts.append(k)
        scales.append(s)
    scales_a = np.asarray(scales, dtype=np.float64)
    g = float("nan") if s_all is None else float(s_all)
    ratios = scales_a / g
    lo, hi = (float(ratios.min()), float(ratios.max())) if len(ratios) else (math.nan, math.nan)
    return WindowScale(window, len(scales_a), degenerate, g, lo, hi, hi / lo,
                       pairs.timestamps[np.asarray(starts, dtype=int)], scales_a, ratios)


# ------------------------------------------------------------------ edges (loop closures)
@dataclass
class EdgeErrors:
    """:func:`edge_errors`: measured relative poses against the reference's.

    Attributes:
        n: edges evaluated (both frames posed in the reference); n_skipped: the others.
        mean_deg, median_deg, max_deg: of ``rotation_deg`` (NaN when n = 0).
        edges: (n, 2) the evaluated edges' timestamps ``(t_i, t_j)``.
        rotation_deg: (n,) angle between measured and reference relative rotation.
        translation_direction_deg: (n,) angle between the translation directions (NaN
            where either translation is zero).
    """

    n: int
    n_skipped: int
    mean_deg: float
    median_deg: float
    max_deg: float
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    rotation_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    translation_direction_deg: np.ndarray = field(default_factory=lambda: np.zeros(0),
                                                  repr=False)


def edge_errors(edges, ref, max_time_diff: Optional[float] = None) -> EdgeErrors:
    """Measured relative poses (e.g. loop edges) against the reference ``ref`` (B).

    Args:
        edges: ``(t_i, t_j, T_i_j)`` triples: two frames' timestamps and the measured
            pose of frame j in frame i's camera (``inv(T_world_i) T_world_j``), a 4x4
            rigid transform or similarity (its scale is dropped; translation compared
            by direction only).
        ref: B (module docstring); each timestamp takes its nearest B pose within
            ``max_time_diff`` (default
            :func:`~spgeo.evaluation.trajectory.default_max_time_diff` of B's).
    Edges with a frame that B does not pose are skipped (``n_skipped``).
    """
    ts_b, poses_b = _arrays(ref, "ref")
    tol = default_max_time_diff(ts_b) if max_time_diff is None else float(max_time_diff)
    done, rot, tdir = [], [], []
    for t_i, t_j, T in edges:
        both = associate_poses((np.array([t_i, t_j], float), np.tile(np.eye(4), (2, 1, 1))),
                               (ts_b, poses_b), tol)
        if not both.valid.all():
            continue
        R, t, _ = sim3_parts(np.asarray(T, dtype=np.float64))
        T_est = np.eye(4)
        T_est[:3, :3], T_est[:3, 3] = R, t
        T_ref = np.linalg.inv(both.poses_b[0]) @ both.poses_b[1]
        e = relative_pose_errors(T_est, T_ref)
        done.append((t_i, t_j))
        rot.append(e["rotation_error_deg"])
        tdir.append(e["translation_direction_error_deg"])
    rot_a = np.asarray(rot, dtype=np.float64)
    mean, median, mx = _stats(rot_a)
    return EdgeErrors(len(rot_a), len(edges) - len(rot_a), mean, median, mx,
                      np.asarray(done, dtype=np.float64).reshape(-1, 2), rot_a,
                      np.asarray(tdir, dtype=np.float64))


# ------------------------------------------------------------------ all of them
@dataclass
class ReferenceComparison:
    """:func:`compare_to_reference`: A against a reference B.

    Attributes:
        reference: the reference's name (e.g. ``"colmap"``, ``"ground truth"``).
        relative_rotation: :class:`RelativeRotationError`.
        orientation: :class:`OrientationError`.
        window_scale: :class:`WindowScale`.
        ate: position ATE after Sim(3) alignment (metres of B), None when not asked
            for or not available (``ate_error`` says why).
    """

    reference: str
    relative_rotation: RelativeRotationError
    orientation: OrientationError
    window_scale: WindowScale
    ate: Optional[AteResult] = None
    ate_error: Optional[str] = None

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary."""
        return {"reference": self.reference,
                "relative_rotation": self.relative_rotation.summary(),
                "orientation": self.orientation.summary(),
                "window_scale": self.window_scale.summary(),
                "ate": None if self.ate is None else self.ate.summary(),
                "ate_error": self.ate_error}

    def table(self) -> str:
        """Markdown: one line per metric."""
        rr, o, w = self.relative_rotation, self.orientation, self.window_scale
        ate = (MISSING if self.ate is None
               else f"{cell(self.ate.rmse, 4)} ({self.ate.n_associated} poses)")
        return "\n".join(markdown_table([f"against {self.reference}", "value"], [
            [f"relative rotation / {rr.gap} frames, mean / median / max [deg]",
             f"{cell(rr.mean_deg)} / {cell(rr.median_deg)} / {cell(rr.max_deg)} ({rr.n} pairs)"],
            ["orientation after best constant rotation, median / max [deg]",
             f"{cell(o.median_deg)} / {cell(o.max_deg)} ({o.n} frames)"],
            [f"scale over {w.window}-frame windows, min - max (spread)",
             f"{cell(w.min, 3)} - {cell(w.max, 3)} ({cell(w.spread, 3)}, {w.n_windows} windows)"],
            ["Sim(3) ATE RMSE", ate]]))


def compare_to_reference(est, ref, reference: str = "reference", gap: int = DEFAULT_GAP,
                         window: int = DEFAULT_WINDOW, max_time_diff: Optional[float] = None,
                         with_ate: bool = True) -> ReferenceComparison:
    """:func:`relative_rotation_error` (``gap`` frames), :func:`orientation_error`,
    :func:`window_scale` (``window`` frames) and, with ``with_ate``, the Sim(3) position
    ATE (:func:`~spgeo.evaluation.trajectory.ate_sim3`, frames without a pose dropped)
    of A (``est``) against B (``ref``, named ``reference``), each with the same
    association tolerance (:func:`associate_poses`)."""
    a, b = _arrays(est, "est"), _arrays(ref, "ref")
    tol = default_max_time_diff(a[0]) if max_time_diff is None else max_time_diff
    out = ReferenceComparison(reference, relative_rotation_error(a, b, gap, tol),
                              orientation_error(a, b, tol),
                              window_scale(a, b, window, max_time_diff=tol))
    if with_ate:
        try:
            out.ate = ate_sim3(a, b, max_time_diff=tol, warn_dropped=False)
        except ValueError as exc:
            out.ate_error = str(exc)
    return out
