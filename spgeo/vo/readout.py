"""What a caller reads of a VO run (:class:`OdometryReadout`, owned by
:class:`spgeo.vo.Odometry` as ``readout``, which hands it the parts it reads): the
trajectory, the keyframes, the run's report and its files, the window smoother where
it is in this process.  Every read applies the mapping port's pending update first
(the ``sync`` it is given), so it sees the map as it will be.  :func:`read_side`
makes the odometry's own members that forward to it.
"""
from __future__ import annotations

import dataclasses
import functools
import inspect
from pathlib import Path
from typing import Callable, Dict, Iterable, Iterator, List, Optional, Tuple, Union

import numpy as np

import gtsam

from ..trajectory import METRES, VO_UNITS
from ..camera import PinholeCamera
from ..frontend import PrimitiveFrontEnd
from .config import OdometryConfig
from .initialisation import Initialiser
from .keyframe_builder import KeyframeBuilder
from .map import KeyframeMap
from .mapping_port import MappingPort
from .result import FrameResult, OdometryResult, frame_records, save_run, timing_statistics
from .saved_map import SavedMap
from .tracking import Keyframe

__all__ = ["OdometryReadout", "ReadSide", "read_side"]


class OdometryReadout:
    """The read side of :class:`spgeo.vo.Odometry` (module docstring).

    Args:
        camera, config, frontend: the odometry's processing camera, config and
            front-end.
        frames: the odometry's list of :class:`FrameResult` (it appends; this reads).
        kmap, port, initialiser, builder: its map, mapping port, initialiser and
            keyframe builder (their reports and state are read, never changed).
        sync: applies the pending update (waiting for it) before a read.
        name: the class name its repr shows.
    """

    def __init__(self, camera: PinholeCamera, config: OdometryConfig,
                 frontend: PrimitiveFrontEnd, frames: List[FrameResult], kmap: KeyframeMap,
                 port: MappingPort, initialiser: Initialiser, builder: KeyframeBuilder,
                 sync: Callable[[], object], name: str = "Odometry") -> None:
        self.camera, self.config, self.frontend = camera, config, frontend
        self._frames, self._map, self._port = frames, kmap, port
        self._initialiser, self._builder, self._sync = initialiser, builder, sync
        self._name = name

    def __repr__(self) -> str:
        """One line: working size, frames, keyframes, segments, the last frame's
        status, mapping mode and window (no wait for the back end)."""
        cam = self.camera
        last = self._frames[-1].status if self._frames else "no frame yet"
        segments = len({f.segment for f in self._frames})
        return (f"{self._name}({cam.width}x{cam.height}, {len(self._frames)} frames, "
                f"{len(self._map.order)} keyframes, {segments} segment(s), last {last}, "
                f"mapping {self.config.mapping.mode}, window {self.config.window})")

    def result(self) -> OdometryResult:
        """Per-frame trajectory (docs/design.md §5.1, *Trajectory*;
        :meth:`spgeo.vo.map.KeyframeMap.frame_poses`), after the pending window
        update (waits for it); in VO units (metres when the front-end reads the
        sensor depth)."""
        self._sync()
        poses, is_kf = self._map.frame_poses(self._frames)
        return OdometryResult(np.array([f.timestamp for f in self._frames], dtype=float),
                              poses, [f.status for f in self._frames], is_kf,
                              np.array([f.segment for f in self._frames], dtype=int),
                              units=self.units)

    @property
    def units(self) -> str:
        """The unit of the positions read out (:attr:`Trajectory.units
        <spgeo.trajectory.Trajectory>`): :data:`~spgeo.trajectory.METRES` when the
        front-end reads the sensor depth, else :data:`~spgeo.trajectory.VO_UNITS`."""
        return METRES if self.frontend.uses_depth else VO_UNITS

    def smoother_estimate(self) -> gtsam.Values:
        """The smoother's current estimate (only the keys inside the window;
        ``RuntimeError`` when the back end is in the worker process)."""
        return self._port.backend.mapper.estimate()

    @property
    def smoother(self) -> gtsam.BatchFixedLagSmoother:
        """The window's ``gtsam.BatchFixedLagSmoother`` (:class:`WindowMapper`;
        ``OdometryConfig.mapping.mode="inline"`` only: live, it is in the worker
        process, and this raises ``RuntimeError``)."""
        return self._port.backend.mapper.smoother

    @smoother.setter
    def smoother(self, value) -> None:
        self._port.backend.mapper.smoother = value

    @property
    def keyframes(self) -> List[Keyframe]:
        """All keyframes in creation order (the window's at their smoothed state).

        Keyframes that left the window are built again from the store at every
        call (new objects, equal to the ones they were): for their poses use
        :meth:`result`, for the window :meth:`window_keyframes`."""
        self._sync()
        return [self.keyframe(k) for k in self._map.order]

    @property
    def n_keyframes(self) -> int:
        """Number of keyframes so far (indices ``0 .. n_keyframes - 1``)."""
        return len(self._map.order)

    def keyframe(self, k: int) -> Keyframe:
        """Keyframe ``k`` (:attr:`keyframes`; one read from the store if retired)."""
        self._sync()
        return self._map.restore(k)[1]

    def keyframe_image(self, k: int) -> np.ndarray:
        """The input image keyframe ``k`` was made from (as given to :meth:`track`)."""
        return self._map.kfs[k].input_image(self._map.store)

    def iter_keyframes(self, indices: Optional[Iterable[int]] = None
                       ) -> Iterator[Tuple[int, np.ndarray, Keyframe]]:
        """``(k, input image, Keyframe)`` of keyframes ``indices`` (default: all),
        in the order given, at their current state: keyframes that left the
        window are read back from the store one at a time (a consumer that
        keeps none holds one in memory)."""
        self._sync()
        return self._map.iter_keyframes(indices)

    def window_keyframes(self) -> Dict[int, Keyframe]:
        """Keyframe index -> :class:`Keyframe` of the keyframes not retired (the
        window's: the only ones that can still change), in creation order."""
        self._sync()
        return {k: self._map.kfs[k].keyframe for k in self._map.live}

    @property
    def frames(self) -> List[FrameResult]:
        """The :class:`FrameResult` of every frame so far."""
        return list(self._frames)

    @property
    def initialised(self) -> bool:
        """Whether frames of the current map segment are tracked against its map:
        it has its keyframe pair (keyframes 0 and 1), or its keyframe 0 came with
        its scale (a saved map's keyframe).  Until then no frame is tracked against
        a map and, with a monocular front-end, keyframe 0 has no depth."""
        return self._map.tracking

    @property
    def init_failure(self) -> Optional[str]:
        """Why the current segment is not initialised (None when it is, or
        before its second frame)."""
        init = self._initialiser
        return None if self.initialised else (init.failure or init.wait_note)

    def keyframes_with_depth(self) -> List[int]:
        """Indices (as in :attr:`keyframes`) of the keyframes whose primitives
        carry depth: all with a depth-using front-end; monocular, those of map
        segments that were initialised (a segment's lone keyframe 0 has only
        its unscaled shapes: its cloud would be a surface at an arbitrary depth)."""
        return self._map.keyframes_with_depth(bool(self.frontend.uses_depth))

    def report(self) -> dict:
        """Run statistics (JSON-ready): counts, per-stage seconds, mapping and
        initialisation reports (``initialised``: :attr:`initialised`;
        ``init_failure``: :attr:`init_failure`), loop closures, landmarks,
        configuration (after the pending update)."""
        self._sync()
        rec = self._port.record
        maps = [m["seconds"] for m in rec.reports if "seconds" in m]
        loops = rec.loops
        if loops is None and self.config.loop_closure.enabled:
            loops = {"accepted": [], "rejected": 0, "seconds": 0.0}
        return {
            "n_frames": len(self._frames), "n_keyframes": len(self._map.order),
            "n_segments": self._map.segment + 1,
            "initialised": self.initialised, "init_failure": self.init_failure,
            "status_counts": self.result().status_counts(),
            **timing_statistics(self._frames),
            "mapping_seconds_per_keyframe": float(np.mean(maps)) if maps else None,
            "config": dataclasses.asdict(self.config),
            "frontend": getattr(self.frontend, "name", str(self.frontend)),
            "sfm": self._initialiser.reports,
            "scale_checks": self._builder.scale_checks,
            "mapping": list(rec.reports),
            "mapping_mode": self.config.mapping.mode,
            **self._port.report(),
            "loop_closures": loops,
            **({} if rec.landmarks is None else {"landmarks": rec.landmarks}),
            "frames": frame_records(self._frames),
        }

    def saved_map(self) -> SavedMap:
        """The map to keep (:class:`~spgeo.vo.saved_map.SavedMap`; ``spgeo vo
        --save-map``): the keyframes that carry depth (:meth:`keyframes_with_depth`)
        at their current state, in creation order, and the current segment's
        landmarks, after the pending update.  Save it with :meth:`SavedMap.save`."""
        self._sync()
        kfs = self._map.kfs
        keep = self.keyframes_with_depth()
        return SavedMap.of(self.camera, self.units, self.config.primitive_model,
                           ((k, kfs[k].frame, kfs[k].segment, image, kf)
                            for k, image, kf in self._map.iter_keyframes(keep)),
                           self._map.landmarks)

    def save(self, directory: Union[str, Path], clouds: bool = True,
             extra_report: Optional[dict] = None,
             trajectory: Optional[OdometryResult] = None) -> Dict[str, object]:
        """:func:`spgeo.vo.result.save_run` of ``trajectory`` (default
        :meth:`result`; a caller may pass it with frames the VO never saw, e.g.
        :meth:`Trajectory.with_skipped`), :meth:`report` updated with
        ``extra_report`` and, with ``clouds``, the keyframes that carry depth
        (:meth:`keyframes_with_depth`; keyframes that left the window are read
        back from the keyframe store one at a time)."""
        kfs = self.iter_keyframes(self.keyframes_with_depth())
        traj = self.result() if trajectory is None else trajectory
        return save_run(directory, traj, {**self.report(), **(extra_report or {})},
                        kfs if clouds else None)


def read_side(name: str):
    """A member of :class:`spgeo.vo.Odometry` that forwards to its ``readout``'s
    member ``name`` of :class:`OdometryReadout`: a property (with its setter) for a
    property, else a method with the same signature and docstring."""
    member = inspect.getattr_static(OdometryReadout, name)
    if isinstance(member, property):
        def set_value(self, value) -> None:
            setattr(self.readout, name, value)
        return property(lambda self: getattr(self.readout, name),
                        set_value if member.fset is not None else None, doc=member.__doc__)

    @functools.wraps(member)
    def forward(self, *args, **kwargs):
        return getattr(self.readout, name)(*args, **kwargs)
    return forward


class ReadSide:
    """The read side of :class:`spgeo.vo.Odometry`: members that forward to its
    ``readout`` (:func:`read_side`)."""

    readout: OdometryReadout
    __repr__, result, report, save, frames, units = map(read_side, (
        "__repr__", "result", "report", "save", "frames", "units"))
    keyframes, keyframe, n_keyframes, keyframe_image, iter_keyframes = map(read_side, (
        "keyframes", "keyframe", "n_keyframes", "keyframe_image", "iter_keyframes"))
    window_keyframes, keyframes_with_depth, initialised, init_failure = map(read_side, (
        "window_keyframes", "keyframes_with_depth", "initialised", "init_failure"))
    smoother, smoother_estimate, saved_map = map(read_side, (
        "smoother", "smoother_estimate", "saved_map"))
