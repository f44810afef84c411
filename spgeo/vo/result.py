"""Per-frame and per-run results of the VO.

:class:`FrameResult` is the online (causal) outcome of one
:meth:`spgeo.vo.Odometry.track` call; the per-run result is a
:class:`spgeo.trajectory.Trajectory` (:data:`OdometryResult` is its alias).
"""
from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from ..io.tum import status_path_for
from ..jsonio import json_default
from ..trajectory import STATUSES, FrameStatus, Trajectory
from .tracking import Keyframe, TrackResult

__all__ = ["FrameResult", "FrameLog", "OdometryResult", "STATUSES", "FrameStatus",
           "timing_statistics",
           "frame_result", "timed", "add_seconds",
           "frame_records", "save_run", "write_keyframe_clouds"]

#: the per-frame stages whose seconds :func:`timing_statistics` adds up
STAGES = ("track", "frontend", "scale_check", "landmarks", "mapping", "init", "loop")

#: The per-run result of :meth:`spgeo.vo.Odometry.result` (alias of
#: :class:`~spgeo.trajectory.Trajectory`: ``statuses``, ``segments``,
#: ``is_keyframe``, ``keyframe_poses``, ``tracked``, ``save``).
OdometryResult = Trajectory


@dataclass
class FrameResult:
    """Outcome of :meth:`spgeo.vo.Odometry.track` for one frame.

    Attributes:
        index: frame number (0-based, in call order).
        timestamp: the frame's timestamp.
        T_world_cam: 4x4 camera-to-world online pose (world = the first
            keyframe's camera); the last good pose for a ``LOST`` frame.
        status: a :class:`~spgeo.trajectory.FrameStatus` (equal to its
            string): ``INIT`` (before keyframe 1 of a map segment; with
            ``T_world_cam`` rewritten, or turned ``LOST``, once that keyframe
            exists: :meth:`spgeo.vo.Odometry.track`), ``OK``, ``KEYFRAME``, ``LOST``,
            ``RELOCALISED`` (first tracked frame after a loss, or tracked
            against an older keyframe), ``REINIT`` (started a new map segment).
        keyframe_index: the keyframe's index if this frame became one.
        segment: map segment (0, then +1 at each re-initialisation).
        track: the :class:`~spgeo.vo.tracking.TrackResult` of the final
            tracking attempt (None for a frame that started a segment).
        timings: seconds per stage (``track``, ``frontend``, ``mapping``,
            ``init``, ``total``).
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: FrameStatus
    keyframe_index: Optional[int] = None
    segment: int = 0
    track: Optional[TrackResult] = None
    timings: Dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.status = FrameStatus(self.status)

    def __repr__(self) -> str:
        """One line: frame, time, status, keyframe, segment, position (the map's
        units), the tracking's summary and the frame's time."""
        x, y, z = self.T_world_cam[:3, 3]
        kf = "" if self.keyframe_index is None else f", keyframe {self.keyframe_index}"
        track = "" if self.track is None else f", {self.track!r}"
        total = 1e3 * self.timings.get("total", 0.0)
        return (f"FrameResult(#{self.index}, t={self.timestamp:.3f}, {self.status}{kf}, "
                f"segment {self.segment}, position [{x:.3f}, {y:.3f}, {z:.3f}]{track}, "
                f"{total:.1f} ms)")

    def rewrite(self, status: FrameStatus, T_world_cam: np.ndarray,
                track: Optional[TrackResult] = None, keyframe_index: Optional[int] = None) -> None:
        """Rewritten in place (an initialisation's frames, once:
        :meth:`spgeo.vo.Odometry.track`)."""
        self.status, self.T_world_cam = FrameStatus(status), np.array(T_world_cam, dtype=float)
        self.track, self.keyframe_index = track, keyframe_index

    def take(self, other: "FrameResult") -> None:
        """Rewritten in place as ``other``, the same frame processed again (the
        frames a late keyframe 1 catches up); its timings stay."""
        self.rewrite(other.status, other.T_world_cam, other.track, other.keyframe_index)
        self.segment = other.segment


class FrameLog(List[FrameResult]):
    """The :class:`FrameResult` of every frame of a run, in frame order (a list:
    :class:`spgeo.vo.Odometry` appends one per frame).  Its rewrites are the
    initialisation's (:meth:`spgeo.vo.Odometry.track`).

    Attributes:
        steps: frames processed so far, a frame processed again counted again (the
            frames a late keyframe 1 catches up): the mapping port's clock.  Equals
            ``len(self)`` on a run without a late keyframe 1.
    """

    def __init__(self) -> None:
        super().__init__()
        self.steps = 0

    def rewrite_retracked(self, retracked: Iterable, status: FrameStatus) -> None:
        """Frames tracked again (:class:`~spgeo.vo.frame_tracker.RetrackedFrame`)
        take their new pose and ``status``, ``LOST`` where not tracked."""
        for r in retracked:
            res = self[r.frame]
            res.rewrite(status if r.ok else FrameStatus.LOST, r.T_world_frame, res.track,
                        res.keyframe_index)


@contextlib.contextmanager
def timed(timings: Dict[str, float], key: str) -> Iterator[None]:
    """Adds the seconds of the ``with`` block to ``timings[key]``."""
    t = time.perf_counter()
    try:
        yield
    finally:
        add_seconds(timings, {key: time.perf_counter() - t})


def add_seconds(timings: Dict[str, float], seconds: Dict[str, float]) -> None:
    """Adds ``seconds`` (stage -> seconds) to ``timings``."""
    for key, sec in seconds.items():
        timings[key] = timings.get(key, 0.0) + float(sec)


def frame_result(frame, idx: int, T_world_cam: np.ndarray, status: FrameStatus,
                 **kwargs) -> FrameResult:
    """The :class:`FrameResult` of frame ``idx`` (a :class:`~spgeo.frame.Frame`)
    at a copy of ``T_world_cam``; ``kwargs``: its other fields."""
    return FrameResult(idx, float(frame.timestamp), np.array(T_world_cam, dtype=float), status,
                       **kwargs)


def timing_statistics(frames: Sequence[FrameResult]) -> Dict[str, object]:
    """Run-time statistics of ``frames`` (JSON-ready): ``seconds_total`` (the sum of
    each frame's ``timings["total"]``), ``fps`` (frames per second of it),
    ``seconds_per_stage`` (the sum of each of :data:`STAGES`) and ``tracking_fps``
    (tracked frames per second of tracking time)."""
    tot = [f.timings.get("total", 0.0) for f in frames]
    n_track = [f.timings["track"] for f in frames if "track" in f.timings]
    return {
        "seconds_total": float(np.sum(tot)),
        "fps": float(len(tot) / max(np.sum(tot), 1e-9)),
        "seconds_per_stage": {k: float(sum(f.timings.get(k, 0.0) for f in frames))
                              for k in STAGES},
        "tracking_fps": float(len(n_track) / max(np.sum(n_track), 1e-9)),
    }


def frame_records(frames: Sequence[FrameResult]) -> List[dict]:
    """One JSON-ready record per frame: index, timestamp, status, keyframe index,
    segment and the stage seconds."""
    return [{"index": f.index, "timestamp": f.timestamp, "status": f.status,
             "keyframe": f.keyframe_index, "segment": f.segment, "timings": f.timings}
            for f in frames]


def save_run(directory: Union[str, Path], result: Trajectory, report: dict,
             keyframes: Optional[Iterable[Tuple[int, np.ndarray, Keyframe]]] = None
             ) -> Dict[str, object]:
    """Write a VO run into ``directory`` (created): ``trajectory.txt`` (every
    frame of ``result``, TUM, camera-to-world) with ``trajectory.status.txt``
    (status, keyframe flag, segment), ``keyframes.txt``, ``report.json`` and,
    when ``keyframes`` ``(index, input image, Keyframe)`` are given, one PLY
    per keyframe in ``clouds/`` (world frame, VO units, coloured).  Returns
    the paths (``"clouds"``: a list)."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    traj = result.save(out / "trajectory.txt", header=["spgeo.odometry per-frame"])
    kfs = result.save(out / "keyframes.txt", keyframes_only=True,
                      header=["spgeo.odometry keyframes"], status_file=False)
    rep = out / "report.json"
    rep.write_text(json.dumps(report, indent=1, default=json_default), encoding="utf-8")
    paths: Dict[str, object] = {"trajectory": traj, "keyframes": kfs,
                                "status": status_path_for(traj), "report": rep}
    if keyframes is not None:
        paths["clouds"] = write_keyframe_clouds(out / "clouds", keyframes)
    return paths


def write_keyframe_clouds(folder: Union[str, Path],
                          keyframes: Iterable[Tuple[int, np.ndarray, Keyframe]]) -> List[Path]:
    """One PLY ``keyframe_<index:04d>.ply`` per keyframe ``(index, colour
    image for :meth:`PrimitiveSet.point_cloud`, Keyframe)`` in ``folder``
    (created): the primitives' points in the world frame (VO units).
    ``keyframes`` is read once, in order (a generator that reads each keyframe
    back from disk keeps one in memory at a time)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: List[Path] = []
    for k, image, kf in keyframes:
        cloud = kf.primitives.point_cloud(image).transformed(kf.T_world_kf)
        path = folder / f"keyframe_{k:04d}.ply"
        cloud.save_ply(path)
        written.append(path)
    return written
