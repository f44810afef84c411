"""TUM trajectory files and Sim(3)-aligned absolute trajectory error (ATE).

TUM format (one pose per line, camera-to-world ``T_world_cam``)::

    # comment lines start with '#'
    timestamp tx ty tz qx qy qz qw

Quaternions are Hamilton ``(qx, qy, qz, qw)`` (:mod:`spgeo.geometry`).  Files
written here contain exactly 8 space-separated columns per pose line so that
``evo_ape tum gt.txt est.txt -as`` reads them unchanged.  Per-frame status
flags (``tracked``, ``lost``, ...) are **not** written as trailing comments
(evo rejects rows with more than 8 columns) but in a separate two-column
status file, by default ``<stem>.status.txt`` beside the trajectory
(:func:`status_path_for`, :func:`write_status`, :func:`read_status`).  Frames
without a pose (tracking lost) are omitted from the trajectory file and appear
only in the status file.

ATE (:func:`ate_sim3`) uses evo's library API: nearest-timestamp association
(:func:`evo.core.sync.associate_trajectories`), Umeyama Sim(3) alignment of
the estimate onto the ground truth (``correct_scale=True``; the equivalent of
``evo_ape -as``) and :class:`evo.core.metrics.APE` on the translation part.

*Per-frame* ATE evaluates every frame that has a pose; *keyframe-only* ATE
evaluates (and aligns on) the keyframes only.  They are different numbers:
every table must say which one it reports.  :func:`ate_sim3` on any subset of
the estimated poses gives the subset's ATE; :func:`ate_per_frame_and_keyframes`
returns both.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.geometry import pose_from_tum, pose_to_tum

__all__ = [
    "TumTrajectory", "read_tum", "write_tum", "status_path_for", "write_status", "read_status",
    "AteResult", "ate_sim3", "ate_per_frame_and_keyframes", "path_length", "umeyama_sim3",
]

logger = logging.getLogger(__name__)

PathLike = Union[str, Path]
#: ``(timestamps (n,), poses (n, 4, 4))`` or a :class:`TumTrajectory`.
TrajectoryLike = Union[Tuple[Sequence[float], Sequence[np.ndarray]], "TumTrajectory"]


# ============================================================== file I/O
@dataclass
class TumTrajectory:
    """A trajectory: timestamps (n,) float64 and camera-to-world poses (n, 4, 4)."""

    timestamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(self.timestamps) != len(self.poses):
            raise ValueError(f"trajectory: {len(self.timestamps)} timestamps for "
                             f"{len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.timestamps)

    def subset(self, mask_or_indices) -> "TumTrajectory":
        """The poses selected by a boolean mask or an index array."""
        idx = np.asarray(mask_or_indices)
        return TumTrajectory(self.timestamps[idx], self.poses[idx])


def _as_trajectory(traj: TrajectoryLike, name: str) -> TumTrajectory:
    if isinstance(traj, TumTrajectory):
        return traj
    if hasattr(traj, "timestamps") and hasattr(traj, "poses"):
        return TumTrajectory(traj.timestamps, traj.poses)  # e.g. a VO result
    try:
        stamps, poses = traj
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected (timestamps, poses) or a TumTrajectory, "
                        f"got {type(traj).__name__}") from None
    return TumTrajectory(stamps, np.stack([np.asarray(p, dtype=np.float64) for p in poses])
                         if len(poses) else np.zeros((0, 4, 4)))


def read_tum(path: PathLike) -> TumTrajectory:
    """Read a TUM trajectory file.

    Skips blank lines and lines starting with ``#``; text after a ``#`` on a
    pose line is ignored too (files written by other tools).  Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` (naming the file
    and line) for a line without 8 finite numbers or an invalid quaternion.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trajectory file not found: {path}")
    stamps: List[float] = []
    poses: List[np.ndarray] = []
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise ValueError(f"{path}:{lineno}: expected 8 columns "
                             f"'timestamp tx ty tz qx qy qz qw', got {len(parts)}")
        try:
            values = np.array([float(p) for p in parts])
            pose = pose_from_tum(values[1:])
        except ValueError as exc:
            raise ValueError(f"{path}:{lineno}: {exc}") from None
        if not math.isfinite(values[0]):
            raise ValueError(f"{path}:{lineno}: non-finite timestamp")
        stamps.append(float(values[0]))
        poses.append(pose)
    return TumTrajectory(np.array(stamps), np.array(poses).reshape(-1, 4, 4))


def write_tum(path: PathLike, timestamps: Sequence[float], poses: Sequence[np.ndarray],
              header: Optional[Sequence[str]] = None) -> int:
    """Write a TUM trajectory file (8 columns, camera-to-world).

    Poses that are ``None`` or contain non-finite values are skipped (a frame
    without a pose has no line).  ``header`` lines are written as ``# ``
    comments first.  Creates the parent folder.  Returns the number of pose
    lines written.
    """
    path = Path(path)
    timestamps = list(timestamps)
    poses = list(poses)
    if len(timestamps) != len(poses):
        raise ValueError(f"write_tum: {len(timestamps)} timestamps for {len(poses)} poses")
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    lines = [f"# {h}" for h in (header or [])]
    lines.append("# timestamp tx ty tz qx qy qz qw (camera-to-world)")
    for ts, T in zip(timestamps, poses):
        if T is None:
            continue
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            continue
        v = pose_to_tum(T)
        lines.append(f"{float(ts):.6f} " + " ".join(f"{x:.9f}" for x in v))
        n += 1
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return n


def status_path_for(trajectory_path: PathLike) -> Path:
    """``DIR/stem.status.txt`` beside ``DIR/stem.txt``."""
    p = Path(trajectory_path)
    return p.with_name(p.stem + ".status.txt")


def write_status(path: PathLike, timestamps: Sequence[float], status: Sequence[str],
                 extra: Optional[Dict[str, Sequence[object]]] = None) -> None:
    """Write ``timestamp status [extra columns...]`` per frame (``#`` header).

    Status strings must not contain whitespace.  ``extra`` maps column names to
    per-frame values (e.g. ``{"keyframe": [0, 1, ...]}``).
    """
    timestamps, status = list(timestamps), list(status)
    if len(timestamps) != len(status):
        raise ValueError(f"write_status: {len(timestamps)} timestamps for {len(status)} flags")
    extra = dict(extra or {})
    for k, v in extra.items():
        if len(v) != len(status):
            raise ValueError(f"write_status: column {k!r} has {len(v)} values for "
                             f"{len(status)} frames")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# timestamp status " + " ".join(extra)]
    for i, (ts, s) in enumerate(zip(timestamps, status)):
        s = str(s)
        if not s or any(c.isspace() for c in s):
            raise ValueError(f"write_status: invalid status {s!r}")
        cols = [f"{float(ts):.6f}", s] + [str(v[i]) for v in extra.values()]
        lines.append(" ".join(cols))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_status(path: PathLike) -> Tuple[np.ndarray, List[str]]:
    """Read a status file written by :func:`write_status`: ``(timestamps, statuses)``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"status file not found: {path}")
    stamps, status = [], []
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 2:
            raise ValueError(f"{path}:{lineno}: expected 'timestamp status'")
        try:
            stamps.append(float(parts[0]))
        except ValueError:
            raise ValueError(f"{path}:{lineno}: bad timestamp {parts[0]!r}") from None
        status.append(parts[1])
    return np.array(stamps), status


# ================================================================== ATE
def path_length(positions: np.ndarray) -> float:
    """Sum of the distances between consecutive positions (n, 3)."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def umeyama_sim3(src: np.ndarray, dst: np.ndarray,
                 with_scale: bool = True) -> Tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``(R, t, s)`` with ``dst ≈ s R src + t`` (Umeyama 1991).

    A plain numpy reference (evo implements the same); ``src``, ``dst`` are (n, 3).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = np.mean(np.sum(xs ** 2, axis=1))
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


@dataclass
class AteResult:
    """Absolute trajectory error after Sim(3) (or SE(3)) alignment.

    Attributes:
        rmse, mean, median, max, std: statistics of the per-pose translation
            errors (metres, in the ground truth's unit) after alignment.
        scale: Sim(3) scale that maps the estimate onto the ground truth (1 when
            ``correct_scale`` was False).
        rotation, translation: the alignment ``x_gt ≈ scale * R x_est + t``.
        n_associated: poses matched by timestamp (and evaluated).
        n_estimated, n_groundtruth: poses given (finite estimated poses only).
        trajectory_length: ground-truth path length over the associated poses (m).
        label: what was evaluated, e.g. ``"per-frame"`` or ``"keyframe-only"``.
        timestamps: (n_associated,) estimate timestamps of the evaluated poses.
        errors: (n_associated,) translation errors (m).
        aligned_positions, gt_positions: (n_associated, 3) after alignment.
    """

    rmse: float
    mean: float
    median: float
    max: float
    std: float
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    n_associated: int
    n_estimated: int
    n_groundtruth: int
    trajectory_length: float
    label: str = "per-frame"
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    aligned_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gt_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def rmse_percent_of_length(self) -> float:
        """RMSE as % of the ground-truth path length (NaN for a zero-length path)."""
        if self.trajectory_length <= 0:
            return float("nan")
        return 100.0 * self.rmse / self.trajectory_length

    def summary(self) -> Dict[str, object]:
        """JSON-friendly summary (no per-pose arrays)."""
        return {
            "label": self.label, "rmse_m": self.rmse, "mean_m": self.mean,
            "median_m": self.median, "max_m": self.max, "std_m": self.std,
            "scale": self.scale, "n_associated": self.n_associated,
            "n_estimated": self.n_estimated, "n_groundtruth": self.n_groundtruth,
            "trajectory_length_m": self.trajectory_length,
            "rmse_percent_of_length": self.rmse_percent_of_length,
        }

    def __str__(self) -> str:
        return (f"ATE ({self.label}, Sim(3)-aligned): RMSE {self.rmse:.4f} m "
                f"({self.rmse_percent_of_length:.2f}% of {self.trajectory_length:.2f} m), "
                f"median {self.median:.4f} m, max {self.max:.4f} m, scale {self.scale:.4g}, "
                f"{self.n_associated} poses")


def _to_evo(traj: TumTrajectory):
    from evo.core.trajectory import PoseTrajectory3D

    order = np.argsort(traj.timestamps, kind="stable")
    return PoseTrajectory3D(poses_se3=[p for p in traj.poses[order]],
                            timestamps=traj.timestamps[order].copy())


def ate_sim3(est: TrajectoryLike, gt: TrajectoryLike, max_time_diff: float = 0.02,
             correct_scale: bool = True, label: str = "per-frame",
             min_poses: int = 3) -> AteResult:
    """Sim(3)-aligned ATE of ``est`` against ``gt`` with evo (``evo_ape -as``).

    Args:
        est, gt: ``(timestamps, poses)`` (camera-to-world 4x4) or
            :class:`TumTrajectory` (or any object with ``timestamps`` and ``poses``).
            Estimated poses that are ``NaN`` (frames without a pose) are dropped;
            so are ground-truth poses that are non-finite.
        max_time_diff: largest timestamp difference for a nearest-time match
            (default 0.02 s; use < 0.5 for frame-number timestamps).
        correct_scale: Sim(3) (default) or SE(3) alignment.
        label: recorded in the result (``"per-frame"`` / ``"keyframe-only"``).
        min_poses: fewest associated poses to evaluate (default 3).

    To evaluate a subset (e.g. keyframes), pass only those poses: the alignment
    is then fitted on the subset too.  Raises ``ValueError`` when fewer than
    ``min_poses`` poses associate or the alignment is degenerate (e.g. all
    estimated positions identical).
    """
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException

    e = _as_trajectory(est, "est")
    g = _as_trajectory(gt, "gt")
    e = e.subset(np.all(np.isfinite(e.poses.reshape(len(e), -1)), axis=1)
                 & np.isfinite(e.timestamps))
    g = g.subset(np.all(np.isfinite(g.poses.reshape(len(g), -1)), axis=1)
                 & np.isfinite(g.timestamps))
    if len(e) < min_poses or len(g) < min_poses:
        raise ValueError(f"ate_sim3: need at least {min_poses} finite poses "
                         f"(estimate has {len(e)}, ground truth {len(g)})")
    try:
        ref_sync, est_sync = sync.associate_trajectories(_to_evo(g), _to_evo(e),
                                                         max_diff=float(max_time_diff))
    except sync.SyncException as exc:
        raise ValueError(f"ate_sim3: no timestamps associate within {max_time_diff}: "
                         f"{exc}") from None
    n = est_sync.num_poses
    if n < min_poses:
        raise ValueError(f"ate_sim3: only {n} poses associate within {max_time_diff} "
                         f"(need {min_poses})")
    try:
        R, t, s = est_sync.align(ref_sync, correct_scale=correct_scale)
    except GeometryException as exc:
        raise ValueError(f"ate_sim3: degenerate alignment: {exc}") from None
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"ate_sim3: degenerate alignment (scale {s})")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_sync, est_sync))
    stats = ape.get_all_statistics()
    return AteResult(
        rmse=float(stats["rmse"]), mean=float(stats["mean"]), median=float(stats["median"]),
        max=float(stats["max"]), std=float(stats["std"]), scale=float(s),
        rotation=np.asarray(R, float), translation=np.asarray(t, float).reshape(3),
        n_associated=int(n), n_estimated=len(e), n_groundtruth=len(g),
        trajectory_length=path_length(ref_sync.positions_xyz), label=label,
        timestamps=np.asarray(est_sync.timestamps, float).copy(),
        errors=np.asarray(ape.error, float).copy(),
        aligned_positions=np.asarray(est_sync.positions_xyz, float).copy(),
        gt_positions=np.asarray(ref_sync.positions_xyz, float).copy())


def ate_per_frame_and_keyframes(est: TrajectoryLike, gt: TrajectoryLike,
                                keyframe_mask: Optional[Sequence[bool]] = None,
                                max_time_diff: float = 0.02,
                                correct_scale: bool = True) -> Dict[str, Optional[AteResult]]:
    """Both ATE variants: ``{"per-frame": ..., "keyframe-only": ...}``.

    The keyframe-only entry is None when no mask is given or when fewer than 3
    keyframes associate (logged).
    """
    e = _as_trajectory(est, "est")
    out: Dict[str, Optional[AteResult]] = {
        "per-frame": ate_sim3(e, gt, max_time_diff, correct_scale, label="per-frame"),
        "keyframe-only": None,
    }
    if keyframe_mask is not None:
        mask = np.asarray(keyframe_mask, dtype=bool)
        if mask.shape != (len(e),):
            raise ValueError(f"keyframe_mask has shape {mask.shape}, expected ({len(e)},)")
        try:
            out["keyframe-only"] = ate_sim3(e.subset(mask), gt, max_time_diff, correct_scale,
                                            label="keyframe-only")
        except ValueError as exc:
            logger.warning("keyframe-only ATE not available: %s", exc)
    return out
