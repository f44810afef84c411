"""evo-like trajectory plots (matplotlib, Agg canvas, no pyplot state):

* :func:`write_trajectory_plots`: from an aligned ATE result
  (:class:`spgeo.metrics.ate.AteResult`), ``trajectory_topview.png``
  (estimate after the Sim(3) / SE(3) alignment against the ground truth, seen
  along the ground truth's axis of least spread) and ``trajectory_error.png``
  (translation error over time, with its RMSE and median).
* :func:`write_reconstruction_topview`: keyframe point clouds, the trajectory
  and the ground truth in one 3-D view (pictures for documentation).

Every PNG is written atomically (a temporary file in the same folder, then
``os.replace``).  matplotlib is imported inside the functions; without it
they raise ``ImportError`` naming it.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from ..io.outputs import write_bytes_atomic

__all__ = ["TrajectoryPlots", "write_trajectory_plots", "write_reconstruction_topview",
           "TOPVIEW_NAME", "ERROR_NAME"]

TOPVIEW_NAME = "trajectory_topview.png"
ERROR_NAME = "trajectory_error.png"
_AXES = "xyz"


@dataclass
class TrajectoryPlots:
    """Outcome of :func:`write_trajectory_plots`.

    Attributes:
        topview, error: paths of the two PNGs.
        timestamps: (n,) timestamps of the evaluated poses (the error curve's x
            is ``timestamps - timestamps[0]``).
        errors: (n,) the plotted translation errors (ground-truth units).
        plane: the two ground-truth axes of the top view, e.g. ``(0, 2)`` (x, z).
    """

    topview: Path
    error: Path
    timestamps: np.ndarray
    errors: np.ndarray
    plane: Tuple[int, int]


def _figure(size_px: Tuple[int, int], dpi: int):
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(f"trajectory plots need matplotlib (pip install matplotlib): {exc}") \
            from None
    w, h = size_px
    if w <= 0 or h <= 0 or dpi <= 0:
        raise ValueError(f"plot size must be positive pixels and dpi, got {size_px!r}, {dpi!r}")
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _save_atomic(fig, path: Path) -> Path:
    """``fig`` as PNG at ``path`` (folder created), atomically
    (:func:`spgeo.io.outputs.write_bytes_atomic`)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    write_bytes_atomic(path, buf.getvalue(), "plot")
    return Path(path)


def _top_plane(positions: np.ndarray) -> Tuple[int, int]:
    """The two axes of largest spread (ascending order)."""
    spread = np.ptp(positions, axis=0) if len(positions) else np.ones(3)
    a, b = sorted(np.argsort(spread)[1:].tolist())
    return int(a), int(b)


def write_trajectory_plots(ate, directory: Union[str, Path], title: str = "",
                           alignment: str = "Sim(3)", size_px: Tuple[int, int] = (640, 480),
                           dpi: int = 100) -> TrajectoryPlots:
    """Top view and error-over-time PNGs of an aligned trajectory in ``directory``.

    Args:
        ate: an :class:`~spgeo.metrics.ate.AteResult` (or any object
            with ``timestamps`` (n,), ``errors`` (n,), ``aligned_positions``
            and ``gt_positions`` (n, 3), ``rmse``, ``median``).
        directory: output folder (created).
        title: prefix of the plot titles (e.g. the sequence name).
        alignment: alignment named in the titles (``"Sim(3)"`` or ``"SE(3)"``).
        size_px: ``(width, height)`` of each PNG in pixels.
        dpi: rendering resolution (pixels per inch).

    Raises ``ValueError`` for fewer than 2 poses or mismatched shapes.
    """
    t = np.asarray(ate.timestamps, dtype=np.float64).reshape(-1)
    err = np.asarray(ate.errors, dtype=np.float64).reshape(-1)
    est = np.asarray(ate.aligned_positions, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(ate.gt_positions, dtype=np.float64).reshape(-1, 3)
    n = len(t)
    if n < 2 or not (len(err) == len(est) == len(gt) == n):
        raise ValueError(f"write_trajectory_plots: need >= 2 poses with matching timestamps, "
                         f"errors and positions, got {len(t)}, {len(err)}, {len(est)}, {len(gt)}")
    out = Path(directory)
    head = f"{title}: " if title else ""
    a, b = _top_plane(gt)

    fig = _figure(size_px, dpi)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(gt[:, a], gt[:, b], "-", color="0.35", lw=1.5, label="ground truth")
    ax.plot(est[:, a], est[:, b], "-", color="tab:blue", lw=1.2, label=f"estimate ({alignment})")
    ax.plot(gt[0, a], gt[0, b], "o", color="0.35", ms=5, label="start")
    ax.set_xlabel(f"{_AXES[a]} [m]")
    ax.set_ylabel(f"{_AXES[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{head}trajectory, {alignment}-aligned (ATE RMSE {float(ate.rmse):.3f} m)",
                 fontsize=10)
    fig.tight_layout()
    top = _save_atomic(fig, out / TOPVIEW_NAME)

    fig = _figure(size_px, dpi)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(t - t[0], err, "-", color="tab:red", lw=1.2, label="translation error")
    ax.axhline(float(ate.rmse), color="k", ls="--", lw=1, label=f"RMSE {float(ate.rmse):.3f} m")
    ax.axhline(float(ate.median), color="0.5", ls=":", lw=1,
               label=f"median {float(ate.median):.3f} m")
    ax.set_xlabel("time since the first pose [s; frames for frame-numbered data sets]")
    ax.set_ylabel("ATE [m]")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{head}absolute trajectory error ({alignment})", fontsize=10)
    fig.tight_layout()
    erp = _save_atomic(fig, out / ERROR_NAME)
    return TrajectoryPlots(top, erp, t.copy(), err.copy(), (a, b))


def write_reconstruction_topview(path: Union[str, Path],
                                 clouds: Sequence[Tuple[np.ndarray, Optional[np.ndarray]]],
                                 trajectory: np.ndarray,
                                 ground_truth: Optional[np.ndarray] = None, title: str = "",
                                 size_px: Tuple[int, int] = (960, 540), dpi: int = 100,
                                 max_points: int = 60000, elevation: float = 30.0,
                                 azimuth: float = -65.0, clip_percentile: float = 2.0) -> Path:
    """A 3-D picture of a reconstruction: coloured point clouds, the camera
    centres and the ground truth, written as PNG at ``path``.

    Args:
        clouds: ``(points (n, 3), colours (n, 3) float [0, 1] or None)`` in one
            world frame whose y axis points down (the VO's world, keyframe 0's
            camera), e.g. keyframe clouds transformed by ``T_world_kf``.
        trajectory: (m, 3) estimated camera centres, same frame.
        ground_truth: (m', 3) ground-truth centres already in that frame, or None.
        max_points: points drawn in all, evenly subsampled.
        elevation, azimuth: matplotlib view angles in degrees; the picture's
            vertical axis is the world's -y (up).
        clip_percentile: points outside the ``[p, 100 - p]`` percentiles of any
            axis (widened to hold the trajectory) are not drawn (outliers).
    """
    def show(p: np.ndarray) -> np.ndarray:      # (x, y down, z) -> (x, z, up)
        return np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)

    fig = _figure(size_px, dpi)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    traj = show(np.asarray(trajectory, np.float64).reshape(-1, 3))
    lines = [traj]
    if ground_truth is not None:
        lines.append(show(np.asarray(ground_truth, np.float64).reshape(-1, 3)))
    pts = [np.asarray(p, np.float64).reshape(-1, 3) for p, _ in clouds]
    cols = [np.full((len(p), 3), 0.5) if c is None else np.asarray(c, np.float64).reshape(-1, 3)
            for p, (_, c) in zip(pts, clouds)]
    everything = np.concatenate(lines)
    if pts:
        P, C = show(np.concatenate(pts)), np.clip(np.concatenate(cols), 0, 1)
        ok = np.all(np.isfinite(P), axis=1)
        P, C = P[ok], C[ok]
        if len(P) and clip_percentile > 0:
            lo = np.minimum(np.percentile(P, clip_percentile, axis=0), everything.min(0))
            hi = np.maximum(np.percentile(P, 100 - clip_percentile, axis=0), everything.max(0))
            ok = np.all((P >= lo) & (P <= hi), axis=1)
            P, C = P[ok], C[ok]
        if len(P) > max_points:
            keep = np.linspace(0, len(P) - 1, max_points).round().astype(np.int64)
            P, C = P[keep], C[keep]
        ax.scatter(P[:, 0], P[:, 1], P[:, 2], c=C, s=0.8, linewidths=0, depthshade=False)
        everything = np.concatenate([everything, P])
    ax.plot(traj[:, 0], traj[:, 1], traj[:, 2], "-", color="tab:orange", lw=2.5,
            label="estimate")
    if ground_truth is not None:
        g = lines[1]
        ax.plot(g[:, 0], g[:, 1], g[:, 2], "--", color="tab:green", lw=2,
                label="ground truth (aligned)")
    ax.set_box_aspect(np.maximum(np.ptp(everything, axis=0), 1e-6))
    ax.view_init(elev=elevation, azim=azimuth)
    ax.set_xlabel("x")
    ax.set_ylabel("z (forward)")
    ax.set_zlabel("-y (up)")
    ax.legend(loc="upper right", fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return _save_atomic(fig, Path(path))
