"""Resident memory of a long VO run: RSS every few hundred frames and its growth per 1000 frames.

    python -m spgeo.evaluation.vo.memory synthetic [--frames 3000] [--unique 300]
        [--size 160 120] [--every 300] [--out FILE.json]
    python -m spgeo.evaluation.vo.memory 7scenes PATH [--clip 0:300] [--frames 1200] ...

Issue 23 (whole recordings) asks that, once the window is full, the VO's peak RSS
grow by at most 50 MB per 1000 frames.  A long sequence is made by playing a short
one back and forth (a palindrome: 0 .. N-1 .. 0 .. N-1 ...): ``synthetic`` renders
``--unique`` poses of :func:`spgeo.synthetic.make_trajectory` one frame at a time
(each frame rendered again when the palindrome comes back to it), ``7scenes`` reads
the ``--clip`` frames of a 7-Scenes sequence from disk one at a time; in both,
frame ``i`` gets timestamp ``i`` and no ground truth, and no image is held beyond
the frame being tracked.  The VO runs through :func:`spgeo.apps.vo_run.run_odometry`
(front-end ``--frontend``, default ``classical``; resolution ``--size``, default
the input's) with default settings.

Prints one row per checkpoint (frames processed, current RSS, peak RSS, in MiB)
and the growth of the current and the peak RSS per 1000 frames from the first
checkpoint at or after ``--warmup`` frames (default 300: the window has filled)
to the last one; ``--out`` writes the same as JSON.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import dataclass, replace
from typing import Dict, Iterator, List, Optional, Sequence

from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import cell, markdown_table

__all__ = ["palindrome", "synthetic_frames", "clip_frames", "measure", "growth_per_1000",
           "memory_report", "MemoryReport", "build_parser", "run", "main"]

log = logging.getLogger(__name__)


def palindrome(n_unique: int, n_frames: int) -> Iterator[int]:
    """Indices ``0 .. n_unique-1 .. 0 .. n_unique-1 ...`` (the ends not repeated),
    ``n_frames`` of them."""
    if n_unique < 2:
        raise ValueError("palindrome: n_unique must be >= 2")
    period = 2 * (n_unique - 1)
    for i in range(int(n_frames)):
        p = i % period
        yield p if p < n_unique else period - p


def synthetic_frames(n_frames: int, n_unique: int = 300, size=(160, 120), seed: int = 0):
    """Rendered frames of a palindrome over ``n_unique`` poses of the synthetic
    trajectory (:mod:`spgeo.synthetic`), rendered lazily; frame ``i`` has
    timestamp ``i``, no depth, no ground truth."""
    from spgeo import synthetic
    from spgeo.frame import Frame

    cam = synthetic.default_camera(*size)
    poses = synthetic.make_trajectory(n_unique, seed)
    scene = synthetic.SyntheticScene.generate(seed)
    for i, j in enumerate(palindrome(n_unique, n_frames)):
        view = scene.render(cam, poses[j])
        yield Frame(image=view.rgb, camera=cam, timestamp=float(i), name=f"{i:06d}")


def clip_frames(kind: str, path: str, clip: str, n_frames: int):
    """Frames of a palindrome over a data set's ``clip`` selection (read from
    disk one at a time, without depth); frame ``i`` has timestamp ``i`` and no
    ground truth."""
    from spgeo.datasets import open_dataset

    seq = open_dataset(kind, path, frames=clip, load_depth=False)
    for i, j in enumerate(palindrome(len(seq), n_frames)):
        yield replace(seq[j], timestamp=float(i), name=f"{i:06d}", T_world_cam=None, depth=None)


def _rss() -> Dict[str, Optional[float]]:
    """Current and peak RSS (MiB) of this process (:mod:`spgeo.apps.memory`)."""
    from spgeo.apps.memory import current_rss_mb, peak_rss_mb

    return {"rss_mb": current_rss_mb(), "peak_rss_mb": peak_rss_mb()}


def measure(frames, n_frames: int, every: int = 300, frontend: str = "classical",
            size: Optional[Sequence[int]] = None) -> List[Dict[str, object]]:
    """Run the VO over ``frames``; ``[{"frames", "rss_mb", "peak_rss_mb"}, ...]``
    after every ``every`` frames (and after the last)."""
    from spgeo.apps.vo_run import VORunConfig, run_odometry

    rows: List[Dict[str, object]] = []

    def hook(frame, result, odometry) -> None:
        n = int(result.index) + 1
        if n % every == 0 or n == n_frames:
            rows.append({"frames": n, **_rss()})
            log.info("%d frames: RSS %.1f MiB, peak %.1f MiB", n, rows[-1]["rss_mb"],
                     rows[-1]["peak_rss_mb"])

    cfg = VORunConfig(frontend=frontend, progress=False)
    if size is not None:
        cfg = replace(cfg, odometry=replace(cfg.odometry, resolution=tuple(int(v) for v in size)))
    run_odometry(frames, cfg, n_frames=n_frames, on_frame=hook)
    return rows


def growth_per_1000(rows: Sequence[Dict[str, object]], key: str,
                    warmup: int = 300) -> Optional[float]:
    """Growth of ``key`` (MiB) per 1000 frames from the first row at or after
    ``warmup`` frames to the last row (None with fewer than two such rows)."""
    after = [r for r in rows if r["frames"] >= warmup and r[key] is not None]
    if len(after) < 2 or after[-1]["frames"] == after[0]["frames"]:
        return None
    return 1000.0 * (after[-1][key] - after[0][key]) / (after[-1]["frames"] - after[0]["frames"])


def memory_report(source: str, path: Optional[str], frames, n: int, every: int = 300,
                  frontend: str = "classical", size: Optional[Sequence[int]] = None,
                  warmup: int = 300) -> "MemoryReport":
    """:func:`measure` over ``frames`` (``n`` of them, from ``source`` / ``path``)
    and the growth per 1000 frames after ``warmup`` frames."""
    rows = measure(frames, n, every, frontend, size)
    return MemoryReport({"source": source, "path": path, "frames": n, "checkpoints": rows,
                         "warmup": warmup,
                         "rss_growth_mb_per_1000_frames": growth_per_1000(rows, "rss_mb", warmup),
                         "peak_growth_mb_per_1000_frames": growth_per_1000(rows, "peak_rss_mb",
                                                                           warmup)})


@dataclass
class MemoryReport:
    """The checkpoints and growth of a run, as written to ``--out`` (``data``:
    ``source``, ``path``, ``frames``, ``checkpoints``, ``warmup``,
    ``rss_growth_mb_per_1000_frames``, ``peak_growth_mb_per_1000_frames``)."""

    data: Dict[str, object]

    def table(self) -> str:
        """Markdown rows (frames, RSS, peak RSS in MiB) and the two growth lines."""
        lines = markdown_table(["frames", "RSS MiB", "peak RSS MiB"],
                               [[cell(r["frames"]), cell(r["rss_mb"], 1), cell(r["peak_rss_mb"], 1)]
                                for r in self.data["checkpoints"]])
        for key in ("rss_growth_mb_per_1000_frames", "peak_growth_mb_per_1000_frames"):
            v = self.data[key]
            lines.append(f"{key}: {'n/a' if v is None else f'{v:.1f}'}")
        return "\n".join(lines)


NAME = "vo_memory"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("source", choices=("synthetic", "7scenes", "tum", "icl", "folder"))
    ap.add_argument("path", nargs="?", help="data-set folder (not for synthetic)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames to run (default 3000 synthetic, 1200 otherwise)")
    ap.add_argument("--unique", type=int, default=300, help="synthetic: distinct poses")
    ap.add_argument("--clip", default="0:300", help="data set: frame selection played back")
    ap.add_argument("--size", type=int, nargs=2, default=None, metavar=("W", "H"),
                    help="resolution (synthetic: rendered at it; default 160 120 synthetic, "
                         "the runner's 320 240 otherwise)")
    ap.add_argument("--frontend", default="classical")
    ap.add_argument("--every", type=int, default=300, help="frames between checkpoints")
    ap.add_argument("--warmup", type=int, default=300, help="frames before the growth is read")
    ap.add_argument("--out", default=None, help="JSON file of the checkpoints and growth")
    return ap


def run(args: argparse.Namespace) -> int:
    """Measure, print the :class:`MemoryReport` table, write ``--out``; progress is
    logged (INFO) always."""
    logging.basicConfig(level=logging.INFO, format="%(message)s", force=True)
    if args.source == "synthetic":
        n = args.frames or 3000
        size = tuple(args.size or (160, 120))
        frames = synthetic_frames(n, args.unique, size)
    else:
        if not args.path:
            raise ValueError(f"{args.source} needs a PATH")
        n = args.frames or 1200
        size = args.size
        frames = clip_frames(args.source, args.path, args.clip, n)
    report = memory_report(args.source, args.path, frames, n, args.every, args.frontend, size,
                           args.warmup)
    print(report.table())
    if args.out:
        from spgeo.io.outputs import write_bytes_atomic

        write_bytes_atomic(args.out, json.dumps(report.data, indent=1).encode("utf-8"), "--out")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    sys.exit(main())
