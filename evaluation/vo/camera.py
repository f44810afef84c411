"""The camera benchmark: the VO fed by a paced camera played from recorded frames.

    spgeo eval vo_camera --dataset 7scenes PATH [--frames 0:300] [--rates 15,30]
        [--buffers 2,4] [--repeats 2] [--ring 8] [--out DIR]
    spgeo eval vo_camera --synthetic 200 [...]

``--synthetic N``: N frames of the synthetic room (320x240, seed 0, with its pure
rotation; :func:`spgeo.evaluation.vo.synthetic.synthetic_sequence`) instead of
``--dataset``.

A :class:`PacedCamera` gives frame ``n`` of the clip ``n / rate`` seconds after its
first frame, through a driver ring of ``buffers`` frames (OpenCV's V4L2 capture
keeps 4): a frame that arrives while the driver ring is full is dropped, as a
camera driver drops it.  The VO runs as ``spgeo vo --dataset camera`` runs it
(:func:`spgeo.apps.vo_run.run_live`: a capture thread reading the camera into a
ring of ``--ring`` frames, the ``"ready"`` mapping schedule, default settings,
classical front-end).  Frames are stamped ``n / rate`` (the camera's clock) and
keep their ground truth for the ATE.

Per run (one rate, one driver ring, one repeat): frames dropped (by the driver or
the capture ring) over the whole run and after initialisation (frames that arrived
after the VO returned keyframe 1, i.e. after the map started: the drops of the
initialisation's own stall are start-up drops), the longest run of consecutive
drops after initialisation, the Sim(3) ATE of the processed frames and its ratio to the ATE of
every frame processed (recorded input, fixed schedule, run once at the start),
latency from a frame's arrival to its result (median, 95th percentile, max, ms),
frames lost, keyframes, keyframe decisions deferred and seconds the tracker
waited for the back end.  ``--out DIR`` writes ``camera.json`` (rows, the
every-frame reference, provenance) and ``camera.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from typing import Dict, Iterator, List, Optional, Sequence

import numpy as np

from spgeo.evaluation import tables
from spgeo.evaluation.runner import open_sequence, protocol_parser, run_protocol, write_json

__all__ = ["PacedCamera", "CameraRun", "camera_run", "every_frame_run", "drop_summary",
           "markdown_table", "build_parser", "run", "main"]

log = logging.getLogger(__name__)


class PacedCamera:
    """A camera played from recorded frames (module docstring).

    Args:
        frames: the recorded :class:`~spgeo.frame.Frame` objects (a list).
        rate: frames per second (> 0).
        buffers: the driver ring (>= 1).

    Attributes:
        camera: the frames' camera.
        start: ``time.perf_counter()`` when the first frame arrived (None before).
        dropped: numbers of the frames the driver dropped.

    Iterating gives the frames in arrival order, restamped ``n / rate`` (each
    waits for its arrival); iterated once.
    """

    def __init__(self, frames: Sequence, rate: float, buffers: int) -> None:
        if not rate > 0 or int(buffers) < 1:
            raise ValueError(f"PacedCamera: rate must be > 0 and buffers >= 1, got "
                             f"{rate!r}, {buffers!r}")
        self.frames, self.rate, self.buffers = list(frames), float(rate), int(buffers)
        self.camera = self.frames[0].camera
        self.start: Optional[float] = None
        self.dropped: List[int] = []

    def arrival(self, number: int) -> float:
        """``time.perf_counter()`` time at which frame ``number`` arrives."""
        return float(self.start) + number / self.rate

    def __iter__(self) -> Iterator:
        self.start = time.perf_counter()
        waiting: List[int] = []
        arrived = 0
        while arrived < len(self.frames) or waiting:
            now = time.perf_counter() - self.start
            while arrived < len(self.frames) and arrived / self.rate <= now:
                (waiting if len(waiting) < self.buffers else self.dropped).append(arrived)
                arrived += 1
            if not waiting:
                time.sleep(max(arrived / self.rate - now, 0.0))
                continue
            n = waiting.pop(0)
            yield dataclasses.replace(self.frames[n], timestamp=n / self.rate,
                                      name=f"{n:06d}")


@dataclasses.dataclass
class CameraRun:
    """One paced run's numbers (module docstring); ``row()`` is JSON-ready."""

    rate: float
    buffers: int
    ring: int
    repeat: int
    frames: int
    dropped: List[int]
    init_frame: Optional[int]
    ate_m: Optional[float]
    latency_ms: List[float]
    lost: int
    keyframes: int
    deferred: int
    wait_s: float
    wall_s: float

    def row(self, reference_ate: Optional[float] = None) -> dict:
        """The run's table row; ``reference_ate``: every frame processed (m)."""
        out = {"rate_hz": self.rate, "buffers": self.buffers, "ring": self.ring,
               "repeat": self.repeat, "frames": self.frames,
               **drop_summary(self.dropped, self.frames, self.init_frame),
               "ate_m": self.ate_m, "lost": self.lost, "keyframes": self.keyframes,
               "keyframes_deferred": self.deferred, "tracker_wait_s": self.wait_s,
               "wall_s": self.wall_s}
        out["ate_ratio"] = (self.ate_m / reference_ate
                            if self.ate_m is not None and reference_ate else None)
        lat = np.asarray(self.latency_ms, dtype=float)
        for key, q in (("latency_ms_median", 50), ("latency_ms_p95", 95),
                       ("latency_ms_max", 100)):
            out[key] = float(np.percentile(lat, q)) if lat.size else None
        return out


def drop_summary(dropped: Sequence[int], frames: int, init_frame: Optional[int]) -> dict:
    """Dropped frame numbers summarised: ``dropped`` (all), ``dropped_after_init``
    (numbers above ``init_frame``, the last frame arrived when the map started;
    all when None: no map), its percentage of the frames after ``init_frame``,
    the longest run of consecutive drops after it and the first dropped numbers
    (at most 40)."""
    from spgeo.datasets.capture import longest_run

    after = [n for n in sorted(dropped) if init_frame is None or n > init_frame]
    n_after = frames - (0 if init_frame is None else init_frame + 1)
    return {"dropped": len(dropped), "dropped_after_init": len(after),
            "dropped_after_init_percent": 100.0 * len(after) / max(n_after, 1),
            "longest_drop_run_after_init": longest_run(after), "init_frame": init_frame,
            "dropped_frames": sorted(dropped)[:40]}


def camera_run(frames: Sequence, rate: float, buffers: int, ring: int, repeat: int = 0,
               odometry=None) -> CameraRun:
    """One paced run (module docstring) of ``frames`` at ``rate`` Hz through a
    driver ring of ``buffers`` and a capture ring of ``ring`` frames
    (``odometry``: an :class:`~spgeo.vo.OdometryConfig`, default the defaults)."""
    from spgeo.apps.vo_run import run_live

    config = dataclasses.replace(_run_config(odometry), capture_ring=ring)
    cam = PacedCamera(frames, rate, buffers)
    latency: List[float] = []
    started: List[int] = []     # the last frame arrived when keyframe 1 came back

    def on_frame(frame, result, odometry) -> None:
        now = time.perf_counter()
        latency.append(1000.0 * (now - cam.arrival(int(round(result.timestamp * rate)))))
        if not started and odometry.n_keyframes >= 2:
            started.append(int(np.floor((now - cam.start) * rate)))

    t = time.perf_counter()
    run = run_live(cam, config, on_frame=on_frame)
    wall = time.perf_counter() - t
    try:
        report = run.odometry.report()
        ate = run.ate()
        kept = {int(round(ts * rate)) for ts in run.timestamps}
        dropped = sorted(set(range(len(frames))) - kept)
        waits = sum(f.timings.get("mapping", 0.0) for f in run.odometry.frames)
        worker = report.get("mapping_worker") or {}
        return CameraRun(rate, buffers, ring, repeat, len(frames), dropped,
                         min(started[0], len(frames) - 1) if started else None,
                         None if ate is None else float(ate["per-frame"].rmse),
                         latency, int(run.status_counts().get("lost", 0)),
                         int(report["n_keyframes"]), int(worker.get("keyframes_deferred", 0)),
                         float(waits), wall)
    finally:
        run.odometry.close()


def _run_config(odometry=None):
    """The runs' :class:`~spgeo.apps.vo_run.VORunConfig`: no progress bar,
    ``odometry`` (default the defaults)."""
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.vo import OdometryConfig

    return VORunConfig(progress=False,
                       odometry=OdometryConfig() if odometry is None else odometry)


def every_frame_run(frames: Sequence, rate: float, odometry=None) -> dict:
    """The reference: every frame processed (recorded input, fixed schedule),
    stamped ``n / rate``: ``{"ate_m", "fps", "keyframes"}`` (``odometry`` as
    :func:`camera_run`)."""
    from spgeo.apps.vo_run import run_odometry

    stamped = [dataclasses.replace(f, timestamp=n / rate, name=f"{n:06d}")
               for n, f in enumerate(frames)]
    run = run_odometry(stamped, _run_config(odometry))
    try:
        ate = run.ate()
        return {"ate_m": None if ate is None else float(ate["per-frame"].rmse),
                "fps": float(run.fps), "keyframes": int(run.odometry.n_keyframes)}
    finally:
        run.odometry.close()


_COLUMNS = (("rate_hz", "Hz", "{:g}"), ("buffers", "buffers", "{}"), ("ring", "ring", "{}"),
            ("repeat", "run", "{}"), ("dropped", "dropped", "{}"),
            ("dropped_after_init", "after init", "{}"),
            ("dropped_after_init_percent", "after init %", "{:.1f}"),
            ("longest_drop_run_after_init", "longest run", "{}"),
            ("init_frame", "map at frame", "{}"), ("ate_m", "ATE m", "{:.3f}"),
            ("ate_ratio", "ATE / every frame", "{:.2f}"), ("lost", "lost", "{}"),
            ("keyframes", "keyframes", "{}"), ("keyframes_deferred", "deferred", "{}"),
            ("tracker_wait_s", "waits s", "{:.2f}"),
            ("latency_ms_median", "latency ms median", "{:.0f}"),
            ("latency_ms_p95", "p95", "{:.0f}"), ("latency_ms_max", "max", "{:.0f}"))


def markdown_table(rows: Sequence[dict]) -> str:
    """The rows as a markdown table (:func:`~spgeo.evaluation.tables.cell`: ``-``
    for missing values)."""
    return "\n".join(tables.markdown_table([head for _, head, _ in _COLUMNS],
                                            [[tables.cell(r.get(k), fmt) for k, _, fmt in _COLUMNS]
                                             for r in rows]))


def build_parser(prog: Optional[str] = None) -> argparse.ArgumentParser:
    p = protocol_parser(prog, __doc__.splitlines()[0], dataset=False)
    p.add_argument("--dataset", nargs=2, metavar=("KIND", "PATH"), default=None,
                   help="the recorded clip (spgeo.datasets.open_dataset)")
    p.add_argument("--frames", default=None, help="frame selection A:B[:S] (default all)")
    p.add_argument("--rates", default="15,30", help="camera rates, Hz (comma-separated)")
    p.add_argument("--buffers", default="2,4", help="driver rings (comma-separated)")
    p.add_argument("--ring", type=int, default=None,
                   help="capture ring (default: VORunConfig.capture_ring)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--out", default=None, help="folder for camera.json and camera.md")
    p.add_argument("--synthetic", type=int, default=None, metavar="N",
                   help="N frames of the synthetic room instead of --dataset")
    return p


def _frames(args: argparse.Namespace) -> list:
    """The clip: ``--synthetic`` frames or ``--dataset``'s (``ValueError`` with neither)."""
    if args.synthetic is not None:
        from spgeo.evaluation.vo.synthetic import SyntheticVOConfig, synthetic_sequence

        n = int(args.synthetic)
        return synthetic_sequence(SyntheticVOConfig(n_frames=n, size=(320, 240),
                                                    rotation=(int(0.6 * n), int(0.8 * n))))
    if not getattr(args, "dataset", None):
        raise ValueError("vo_camera: give --dataset KIND PATH or --synthetic N")
    return list(open_sequence(args))


def run(args: argparse.Namespace) -> int:
    from spgeo.apps.vo_run import VORunConfig
    from spgeo.evaluation.jobs import provenance

    frames = _frames(args)
    rates = [float(x) for x in str(args.rates).split(",")]
    buffers = [int(x) for x in str(args.buffers).split(",")]
    ring = VORunConfig().capture_ring if args.ring is None else int(args.ring)
    reference = every_frame_run(frames, rates[-1])
    log.info("every frame processed: ATE %s m, %.1f FPS", reference["ate_m"], reference["fps"])
    rows: List[Dict] = []
    for rep in range(int(args.repeats)):
        for rate in rates:
            for buf in buffers:
                rows.append(camera_run(frames, rate, buf, ring, rep).row(reference["ate_m"]))
                log.info("%s", {k: rows[-1][k] for k in ("rate_hz", "buffers", "dropped",
                                                         "dropped_after_init", "ate_ratio")})
    table = markdown_table(rows)
    print(f"every frame processed: ATE {reference['ate_m']:.3f} m, {reference['fps']:.1f} FPS "
          f"(recorded input, fixed schedule)")
    print(table)
    if args.out:
        from pathlib import Path

        from spgeo.io.outputs import write_bytes_atomic

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "camera.json", {"rows": rows, "every_frame": reference,
                                         "provenance": provenance()})
        write_bytes_atomic(out / "camera.md", (table + "\n").encode("utf-8"), "camera table")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, name="vo_camera")


if __name__ == "__main__":
    raise SystemExit(main())
