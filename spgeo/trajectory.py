"""One trajectory type for every estimator (spgeo VO, feature VO, COLMAP).

:class:`Trajectory` holds per-frame timestamps, camera-to-world poses
``T_world_cam`` (NaN for a frame without a pose of its own), a
:class:`FrameStatus` per frame, keyframe flags, map segments and optional extra
per-frame columns.  :meth:`Trajectory.save` writes the TUM file plus the status
file of :mod:`spgeo.tum_files`; :meth:`Trajectory.load` reads them back.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from .tum_files import read_status, read_tum_arrays, status_path_for, write_status, write_tum

__all__ = ["FrameStatus", "Trajectory", "STATUSES", "VO_UNITS", "METRES"]

#: :attr:`Trajectory.units` of a monocular VO's poses: one unknown global scale
VO_UNITS = "VO units (unknown scale)"
#: :attr:`Trajectory.units` of metric poses (ground truth, a metric VO)
METRES = "metres"


class FrameStatus(str, Enum):
    """Per-frame status, shared by every trajectory estimator.

    ``INIT``: before a map exists (pose provisional or absent); ``OK``: tracked
    (or registered); ``KEYFRAME``: tracked and made a keyframe; ``LOST``: no
    pose of its own; ``RELOCALISED``: first tracked frame after a loss, or
    tracked against an older keyframe; ``REINIT``: started a new map segment;
    ``SKIPPED``: the frame's file could not be read, so no estimator saw it (no
    pose; recorded by the batch runner, :mod:`spgeo.apps.vo_run`).
    Members compare equal to their string values.
    """

    INIT = "init"
    OK = "ok"
    KEYFRAME = "keyframe"
    LOST = "lost"
    RELOCALISED = "relocalised"
    REINIT = "reinit"
    SKIPPED = "skipped"

    def __str__(self) -> str:
        return self.value

    @property
    def has_pose(self) -> bool:
        """Whether a frame with this status carries a pose of its own (not
        ``LOST``, not ``SKIPPED``)."""
        return self not in (FrameStatus.LOST, FrameStatus.SKIPPED)


#: Every status value, in enum order.
STATUSES = tuple(s.value for s in FrameStatus)


def _as_status(value: Union[str, FrameStatus]) -> FrameStatus:
    try:
        return FrameStatus(value)
    except ValueError:
        raise ValueError(f"unknown frame status {value!r}; expected one of {STATUSES}") from None


@dataclass
class Trajectory:
    """Per-frame poses and statuses of one run.

    Attributes:
        timestamps: (n,) float64 seconds (frame numbers for data without time).
        poses: (n, 4, 4) float64 ``T_world_cam`` (camera-to-world); NaN rows
            mark frames without a pose.
        status: n :class:`FrameStatus` (default: all ``OK``); strings are
            converted, an unknown one raises ``ValueError``.
        is_keyframe: (n,) bool (default all False).
        segment: (n,) int map segment (default 0; -1 for frames without a pose
            where the estimator says so).
        columns: extra per-frame columns written into the status file
            (name -> n values), e.g. ``{"inliers": ...}``.
        units: the unit of the positions, as words (:data:`VO_UNITS` for a
            monocular VO, :data:`METRES`), or None where nobody said (a file
            read back: TUM files do not say); kept by :meth:`subset` and
            :meth:`with_skipped`, shown by the repr.
    """

    timestamps: np.ndarray
    poses: np.ndarray
    status: Optional[Sequence[Union[str, FrameStatus]]] = None
    is_keyframe: Optional[np.ndarray] = None
    segment: Optional[np.ndarray] = None
    columns: Dict[str, Sequence[object]] = field(default_factory=dict)
    units: Optional[str] = None

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        n = len(self.timestamps)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(self.poses) != n:
            raise ValueError(f"trajectory: {n} timestamps for {len(self.poses)} poses")
        self.status = ([FrameStatus.OK] * n if self.status is None
                       else [_as_status(s) for s in self.status])
        self.is_keyframe = (np.zeros(n, dtype=bool) if self.is_keyframe is None
                            else np.asarray(self.is_keyframe, dtype=bool).reshape(-1))
        self.segment = (np.zeros(n, dtype=int) if self.segment is None
                        else np.asarray(self.segment, dtype=int).reshape(-1))
        for name, arr in (("status", self.status), ("is_keyframe", self.is_keyframe),
                          ("segment", self.segment), *self.columns.items()):
            if len(arr) != n:
                raise ValueError(f"trajectory: {name!r} has {len(arr)} values for {n} frames")

    def __len__(self) -> int:
        return len(self.timestamps)

    def overview(self) -> Dict[str, str]:
        """The key numbers as text, for :meth:`__repr__` and :meth:`_repr_html_`:
        frames, keyframes, time span, the statuses that occur, segments, the
        length of the posed path and the positions' :attr:`units`."""
        n = len(self)
        c = self.poses[self.finite][:, :3, 3]
        path = float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0
        return {"frames": str(n), "keyframes": str(int(self.is_keyframe.sum())),
                "t": f"{self.timestamps[0]:.3f}-{self.timestamps[-1]:.3f}" if n else "-",
                "status": ", ".join(f"{k}={v}" for k, v in self.status_counts().items() if v),
                "segments": str(len(set(self.segment.tolist()))), "path": f"{path:.3f}",
                "units": self.units or "not stated"}

    def __repr__(self) -> str:
        """One line: :meth:`overview`."""
        o = self.overview()
        return (f"Trajectory({o['frames']} frames, {o['keyframes']} keyframes, t {o['t']}, "
                f"status {{{o['status']}}}, {o['segments']} segment(s), path {o['path']} "
                f"{o['units']})")

    def _repr_html_(self) -> str:
        """:meth:`overview` as a table (notebooks)."""
        from .html_table import html_table

        o = self.overview()
        names = {"t": "time span (s, or frame numbers)", "status": "frames per status",
                 "path": "path length", "units": "units of the positions"}
        return html_table("Trajectory", [(names.get(k, k), v) for k, v in o.items()])

    @property
    def statuses(self) -> List[FrameStatus]:
        """Alias of :attr:`status`."""
        return self.status

    @property
    def segments(self) -> np.ndarray:
        """Alias of :attr:`segment`."""
        return self.segment

    @property
    def finite(self) -> np.ndarray:
        """(n,) bool: frames whose pose is finite."""
        return np.all(np.isfinite(self.poses.reshape(len(self), 16)), axis=1)

    @property
    def tracked(self) -> np.ndarray:
        """(n,) bool: frames with a pose of their own (finite, status neither
        ``LOST`` nor ``SKIPPED``)."""
        return self.finite & np.array([s.has_pose for s in self.status], dtype=bool)

    @property
    def keyframe_timestamps(self) -> np.ndarray:
        return self.timestamps[self.is_keyframe]

    @property
    def keyframe_poses(self) -> np.ndarray:
        return self.poses[self.is_keyframe]

    def subset(self, mask_or_indices) -> "Trajectory":
        """The frames selected by a boolean mask or an index array."""
        idx = np.asarray(mask_or_indices)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        return Trajectory(self.timestamps[idx], self.poses[idx],
                          [self.status[i] for i in idx], self.is_keyframe[idx],
                          self.segment[idx],
                          {k: [v[i] for i in idx] for k, v in self.columns.items()}, self.units)

    def with_skipped(self, timestamps: Sequence[float]) -> "Trajectory":
        """This trajectory with one ``SKIPPED`` frame per timestamp inserted in
        time order: NaN pose (no TUM line), not a keyframe, segment -1, extra
        columns ``"nan"``.  Without timestamps, ``self`` itself.  Raises
        ``ValueError`` when a timestamp is not finite or is already a frame's."""
        stamps = np.asarray(list(timestamps), dtype=np.float64).reshape(-1)
        if stamps.size == 0:
            return self
        if not np.all(np.isfinite(stamps)) or np.isin(stamps, self.timestamps).any():
            raise ValueError("Trajectory.with_skipped: skipped timestamps must be finite and "
                             "differ from the frames' timestamps")
        k = len(stamps)
        all_t = np.concatenate([self.timestamps, stamps])
        order = np.argsort(all_t, kind="stable")
        poses = np.concatenate([self.poses, np.full((k, 4, 4), np.nan)])[order]
        all_status = list(self.status) + [FrameStatus.SKIPPED] * k
        status = [all_status[i] for i in order]
        is_kf = np.concatenate([self.is_keyframe, np.zeros(k, dtype=bool)])[order]
        seg = np.concatenate([self.segment, np.full(k, -1, dtype=int)])[order]
        cols = {}
        for name, v in self.columns.items():
            values = list(v) + ["nan"] * k
            cols[name] = [values[i] for i in order]
        return Trajectory(all_t[order], poses, status, is_kf, seg, cols, self.units)

    def status_counts(self) -> Dict[str, int]:
        """Frames per status value (every :class:`FrameStatus`, zeros included)."""
        return {s.value: sum(1 for x in self.status if x is s) for s in FrameStatus}

    def save(self, path: Union[str, Path], keyframes_only: bool = False,
             header: Optional[Sequence[str]] = None, status_file: bool = True) -> Path:
        """Write the posed frames (or keyframes) as a TUM file: the :attr:`tracked`
        ones, so a ``LOST`` frame (which holds the last good pose) or a frame
        without a pose has no line, as in ORB-SLAM's files (issue 53); and, with
        ``status_file``, every frame's status, keyframe flag, segment and
        :attr:`columns` into ``<stem>.status.txt`` beside it.  Returns ``path``."""
        path = Path(path)
        mask = self.tracked & (self.is_keyframe if keyframes_only else True)
        write_tum(path, self.timestamps[mask], list(self.poses[mask]), header=header)
        if status_file:
            extra = {"keyframe": self.is_keyframe.astype(int).tolist(),
                     "segment": self.segment.tolist()}
            extra.update({k: list(v) for k, v in self.columns.items()})
            write_status(status_path_for(path), self.timestamps,
                         [s.value for s in self.status], extra)
        return path

    @classmethod
    def load(cls, path: Union[str, Path]) -> "Trajectory":
        """Read a TUM file and, when present, its ``<stem>.status.txt``.

        With a status file the trajectory has one entry per status line (frames
        missing from the TUM file get NaN poses) and its keyframe / segment
        columns; without one, every pose line is an ``OK`` frame.
        """
        traj = Trajectory(*read_tum_arrays(path))
        spath = status_path_for(path)
        if not spath.is_file():
            return traj
        stamps, status, extra = read_status(spath, with_columns=True)
        poses = np.full((len(stamps), 4, 4), np.nan)
        lookup = {float(t): i for i, t in enumerate(np.round(traj.timestamps, 6))}
        for i, t in enumerate(np.round(stamps, 6)):
            j = lookup.get(float(t))
            if j is not None:
                poses[i] = traj.poses[j]
        kf = extra.pop("keyframe", None)
        seg = extra.pop("segment", None)
        return cls(stamps, poses, status,
                   None if kf is None else np.array(kf, dtype=int).astype(bool),
                   None if seg is None else np.array(seg, dtype=int), extra)

    @classmethod
    def from_ground_truth(cls, source, poses: Optional[Sequence[Optional[np.ndarray]]] = None
                          ) -> "Trajectory":
        """The ground truth of a frame sequence as a trajectory (status ``OK``).

        Args:
            source: a data-set reader (:func:`spgeo.datasets.open_dataset`, any
                object with ``timestamps`` and ``ground_truth()``: read without
                images), or, with ``poses``, the (n,) timestamps (seconds, or
                frame numbers for data sets without times).
            poses: with timestamps as ``source``, per frame its 4x4 camera-to-world
                ``T_world_cam`` (the data set's world and unit, metres) or None.

        The trajectory's :attr:`units` are :data:`METRES` (every reader's ground truth is).

        Frames whose pose is None (no ground truth) are left out; a pose with
        non-finite entries stays as a frame without a pose (NaN row: no line in
        :meth:`save`'s file).  Raises ``ValueError`` when the counts differ or
        a pose is not 4x4, ``TypeError`` for a ``source`` without ground truth.
        """
        if poses is None:
            if not (hasattr(source, "timestamps") and callable(getattr(source, "ground_truth",
                                                                       None))):
                raise TypeError("Trajectory.from_ground_truth: expected a data-set reader "
                                f"(timestamps, ground_truth()) or timestamps and poses, got "
                                f"{type(source).__name__}")
            stamps, poses = source.timestamps, source.ground_truth()
        else:
            stamps = source
        stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
        poses = list(poses)
        if len(stamps) != len(poses):
            raise ValueError(f"Trajectory.from_ground_truth: {len(stamps)} timestamps for "
                             f"{len(poses)} poses")
        keep = [i for i, T in enumerate(poses) if T is not None]
        arr = np.zeros((len(keep), 4, 4))
        for j, i in enumerate(keep):
            T = np.asarray(poses[i], dtype=np.float64)
            if T.shape != (4, 4):
                raise ValueError(f"Trajectory.from_ground_truth: pose {i} has shape {T.shape}, "
                                 "expected (4, 4)")
            arr[j] = T if np.all(np.isfinite(T)) else np.nan
        return cls(stamps[keep], arr, units=METRES)
