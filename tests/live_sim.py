"""A live camera and a slow back end simulated in frames, not in seconds
(issue 52): a test of the live path that fails on a bug and never on the
machine's load.

:class:`DelayedPort` is the back end in this process on the ``"ready"`` schedule
(the tracker never waits, keyframes are deferred) whose updates are ready
``update_frames`` processed frames after their job and whose keyframe-1 solve
lands ``init_frames`` frames after it was sent: the worker process of a loaded
machine, on any machine.  :func:`simulated_live_run` feeds the frames a consumer
that keeps up with one camera frame in ``stride`` would see, and drops ``stall``
more after the call in which the map started (the stall of the frames it caught
up).
"""
from typing import List, Sequence

from spgeo.frame import Frame
from spgeo.vo import Odometry
from spgeo.vo.mapping_port import InProcessPort


class DelayedPort(InProcessPort):
    """:class:`InProcessPort` on the ``"ready"`` schedule with a latency in
    processed frames (module docstring)."""

    def __init__(self, camera, config, update_frames: int, init_frames: int) -> None:
        super().__init__(camera, config, lead=0, schedule="ready")
        self.update_frames, self.init_frames = int(update_frames), int(init_frames)
        self.clock = self._job_at = self._init_at = 0

    def note_frame(self) -> None:
        super().note_frame()
        self.clock += 1

    def _submit(self, job) -> None:
        super()._submit(job)
        self._job_at = self.clock

    def _ready(self) -> bool:
        return self.clock - self._job_at >= self.update_frames

    def _submit_init(self, job) -> None:
        super()._submit_init(job)
        self._init_at = self.clock

    def _init_result(self):
        if self._init_job is None or self.clock - self._init_at < self.init_frames:
            return None
        return super()._init_result()


def simulated_live_run(vo: Odometry, frames: Sequence[Frame], stride: int, stall: int
                       ) -> List[int]:
    """Frame numbers of ``frames`` given to ``vo`` (module docstring): every
    ``stride``-th, and after the first call that returns a map (a result that is
    neither ``init`` nor ``lost`` after an ``init`` one) ``stall`` frames skipped."""
    given: List[int] = []
    n, waiting = 0, True
    while n < len(frames):
        res = vo.track(frames[n])
        given.append(n)
        n += stride
        if waiting and given[1:] and str(res.status) not in ("init", "lost"):
            waiting = False
            n += stall
    return given
