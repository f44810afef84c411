"""TUM RGB-D fr1 monocular-VO protocol (SuperPrimitive paper, Table: TUM fr1).

For users who have the eight fr1 sequences under one root folder::

    ROOT/rgbd_dataset_freiburg1_360
    ROOT/rgbd_dataset_freiburg1_desk
    ...  (desk2, plant, room, rpy, teddy, xyz)

Protocol (as in the paper): RGB only (no depth is read), images undistorted
with the fr1 calibration (the TUM reader's ``undistort=True``), cropped by
16 px at the top and bottom and 32 px at the left and right (640x480 ->
576x448; :func:`crop_frame` shifts the principal point by the crop offsets),
then resized to 160x120 (``cv2.INTER_AREA``; anisotropic: fx and fy scale
differently, the camera follows).  Every method runs on the same prepared
frames (:func:`spgeo.evaluation.vo.compare.compare_vo`): spgeo with the
classical front-end (default), the OpenCV feature baseline and, optionally,
the COLMAP reference.  The metric is the per-frame ATE RMSE in metres after
Sim(3) alignment (evo), averaged over the sequences that ran.

Missing sequences are reported as skipped (never an error).  The paper's
mean ATE over the eight sequences is printed as a reference
(:data:`PAPER_MEAN_ATE_M`); its per-sequence numbers are not reproduced here.

Command line::

    python -m spgeo.evaluation.vo.tum_fr1 --root ROOT [--sequences desk xyz] \
        [--methods spgeo-classical feature colmap] [--max-frames N] [--out DIR] \
        [--workers N | --address ADDR]

Each present sequence is one job (:mod:`spgeo.evaluation.jobs`):
sequentially here by default, on Ray with ``--workers`` / ``--address``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from spgeo.camera import PinholeCamera
from spgeo.frame import Frame, resize_frame
from spgeo.jsonio import json_default

from spgeo.evaluation.jobs import (EvalTable, Job, RunnerConfig, add_runner_arguments, provenance,
                                   run_jobs, runner_config)
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.evaluation.tables import MISSING, cell, markdown_table

from .compare import (METHODS, ORACLE_METHODS, VOCompareConfig, VOCompareRow, compare_vo,
                      write_results)

__all__ = ["FR1_SEQUENCES", "PAPER_MEAN_ATE_M", "FR1_METHODS", "FR1Config", "FR1SequenceResult",
           "FR1Report", "sequence_folder", "crop_camera", "crop_frame", "protocol_frames",
           "run_fr1_sequence", "run_fr1", "fr1_table", "format_fr1_table", "build_parser", "run",
           "main"]

logger = logging.getLogger(__name__)

#: The eight TUM fr1 sequences of the protocol (folder ``rgbd_dataset_freiburg1_<name>``).
FR1_SEQUENCES = ("360", "desk", "desk2", "plant", "room", "rpy", "teddy", "xyz")
#: Mean per-frame ATE (m, Sim(3)-aligned) over the eight sequences reported in the
#: SuperPrimitive paper (monocular, 160x120); reference only.
PAPER_MEAN_ATE_M = {"SuperPrimitive": 0.153, "DepthCov": 0.167, "TartanVO": 0.188,
                    "DeepV2D": 0.215, "DeepFactors": 0.241}
#: Methods allowed under the protocol (RGB only: no oracle-depth method).
FR1_METHODS = tuple(m for m in METHODS if m not in ORACLE_METHODS)


def sequence_folder(root: Union[str, Path], name: str) -> Path:
    """``root/rgbd_dataset_freiburg1_<name>``."""
    return Path(root) / f"rgbd_dataset_freiburg1_{name}"


# ================================================================== config
@dataclass
class FR1Config:
    """Options of :func:`run_fr1` / :func:`run_fr1_sequence`.

    Attributes:
        crop: ``(left, top, right, bottom)`` pixels removed from the
            undistorted 640x480 images, default (32, 16, 32, 16) -> 576x448.
        resolution: ``(width, height)`` the cropped images are resized to,
            default (160, 120).
        methods: from :data:`FR1_METHODS`, default ``("spgeo-classical",
            "feature")``; add ``"colmap"`` for the (slow) SfM reference.
        max_frames: use only the first ``max_frames`` frames of each sequence;
            None (default) = all (the protocol).
        undistort: undistort with the fr1 calibration, default True (protocol).
        compare: options of the methods (:class:`~.compare.VOCompareConfig`;
            its ``resolution`` is replaced by ``resolution``).
    """

    crop: Tuple[int, int, int, int] = (32, 16, 32, 16)
    resolution: Tuple[int, int] = (160, 120)
    methods: Tuple[str, ...] = ("spgeo-classical", "feature")
    max_frames: Optional[int] = None
    undistort: bool = True
    compare: VOCompareConfig = field(default_factory=VOCompareConfig)

    def __post_init__(self) -> None:
        crop = tuple(int(c) for c in self.crop)
        if len(crop) != 4 or min(crop) < 0:
            raise ValueError(f"FR1Config.crop must be 4 non-negative pixel counts, got {self.crop}")
        self.crop = crop  # type: ignore[assignment]
        self.methods = tuple(self.methods)
        bad = [m for m in self.methods if m not in FR1_METHODS]
        if bad:
            raise ValueError(f"FR1Config.methods: {bad} not allowed under the RGB-only protocol; "
                             f"expected some of {list(FR1_METHODS)}")
        if not self.methods:
            raise ValueError("FR1Config.methods is empty")
        if self.max_frames is not None and int(self.max_frames) < 3:
            raise ValueError(f"FR1Config.max_frames must be >= 3, got {self.max_frames}")


# =================================================================== crop
def crop_camera(camera: PinholeCamera, left: int, top: int, right: int,
                bottom: int) -> PinholeCamera:
    """Camera of an image cropped by ``left``/``top``/``right``/``bottom`` pixels:
    same focal lengths, ``cx - left``, ``cy - top``, size reduced.  The camera
    must have no distortion (crop after undistorting).  Raises ``ValueError``."""
    if camera.distortion is not None:
        raise ValueError("crop_camera: undistort first (the camera has distortion)")
    left, top, right, bottom = (int(v) for v in (left, top, right, bottom))
    if min(left, top, right, bottom) < 0:
        raise ValueError("crop_camera: crop offsets must be >= 0")
    w, h = camera.width - left - right, camera.height - top - bottom
    if w <= 0 or h <= 0:
        raise ValueError(f"crop_camera: crop ({left}, {top}, {right}, {bottom}) leaves nothing "
                         f"of a {camera.width}x{camera.height} image")
    return dataclasses.replace(camera, cx=camera.cx - left, cy=camera.cy - top, width=w, height=h)


def crop_frame(frame: Frame, crop: Tuple[int, int, int, int] = (32, 16, 32, 16)) -> Frame:
    """``frame`` cropped by ``crop = (left, top, right, bottom)`` pixels (image
    and depth; camera via :func:`crop_camera`); pose, timestamp, name kept."""
    left, top, right, bottom = (int(v) for v in crop)
    cam = crop_camera(frame.camera, left, top, right, bottom)
    rows = slice(top, top + cam.height)
    cols = slice(left, left + cam.width)
    image = np.ascontiguousarray(np.asarray(frame.image)[rows, cols])
    depth = None if frame.depth is None else np.ascontiguousarray(frame.depth[rows, cols])
    return Frame(image=image, camera=cam, timestamp=frame.timestamp, depth=depth,
                 T_world_cam=frame.T_world_cam, name=frame.name,
                 meta={**frame.meta, "crop_ltrb": (left, top, right, bottom)})


def protocol_frames(frames, config: Optional[FR1Config] = None) -> Iterator[Frame]:
    """Frames -> undistorted -> cropped (``config.crop``) -> resized
    (``config.resolution``), one at a time; depth is dropped (RGB only).

    Frames whose camera still has distortion are undistorted here when
    ``config.undistort`` (the TUM reader normally did it already); with
    ``undistort=False`` the distortion coefficients are ignored."""
    config = config or FR1Config()
    for f in frames:
        if f.depth is not None:
            f = dataclasses.replace(f, depth=None)
        if f.camera.distortion is not None:
            if config.undistort:
                f = resize_frame(f, None)  # undistort only
            else:
                f = dataclasses.replace(f, camera=f.camera.undistorted())
        yield resize_frame(crop_frame(f, config.crop), config.resolution)


# ================================================================= running
@dataclass
class FR1SequenceResult:
    """One sequence: ``rows`` from :func:`~.compare.compare_vo`, or
    ``skipped`` with the reason (missing folder, unreadable data...)."""

    name: str
    path: str
    rows: List[VOCompareRow] = field(default_factory=list)
    skipped: Optional[str] = None
    n_frames: int = 0
    wall_s: float = 0.0

    def ate(self, method: str) -> float:
        """Per-frame ATE RMSE (m) of ``method``, NaN if not run or failed."""
        for r in self.rows:
            if r.method == method:
                return r.ate_rmse_m
        return float("nan")

    def to_dict(self) -> Dict[str, object]:
        return {"name": self.name, "path": self.path, "skipped": self.skipped,
                "n_frames": self.n_frames, "wall_s": self.wall_s,
                "rows": [r.to_dict() for r in self.rows]}


@dataclass
class FR1Report:
    """Output of :func:`run_fr1`: per-sequence results (skipped ones included),
    the methods and the configuration."""

    sequences: List[FR1SequenceResult]
    methods: Tuple[str, ...]
    config: FR1Config

    @property
    def skipped(self) -> Dict[str, str]:
        """Skipped sequence -> reason."""
        return {s.name: s.skipped for s in self.sequences if s.skipped}

    @property
    def evaluated(self) -> List[FR1SequenceResult]:
        return [s for s in self.sequences if not s.skipped]

    def mean_ate(self, method: str) -> Tuple[float, int]:
        """(mean per-frame ATE RMSE in m over the sequences where ``method``
        has a finite ATE, number of those sequences)."""
        vals = [s.ate(method) for s in self.evaluated]
        vals = [v for v in vals if math.isfinite(v)]
        return (float(np.mean(vals)) if vals else float("nan")), len(vals)

    def to_dict(self) -> Dict[str, object]:
        return {"protocol": {"crop_ltrb": list(self.config.crop),
                             "resolution": list(self.config.resolution),
                             "undistort": self.config.undistort,
                             "max_frames": self.config.max_frames, "rgb_only": True},
                "methods": list(self.methods),
                "mean_ate_m": {m: self.mean_ate(m)[0] for m in self.methods},
                "n_sequences_in_mean": {m: self.mean_ate(m)[1] for m in self.methods},
                "paper_mean_ate_m": dict(PAPER_MEAN_ATE_M), "skipped": self.skipped,
                "sequences": [s.to_dict() for s in self.sequences]}


def run_fr1_sequence(path: Union[str, Path], config: Optional[FR1Config] = None,
                     name: Optional[str] = None) -> FR1SequenceResult:
    """Run the protocol on one fr1 sequence folder.

    A missing folder or unreadable data gives a result with ``skipped`` set
    (logged), never an exception; method failures are in the rows' ``error``.
    """
    from spgeo.datasets import TUMSequence

    config = config or FR1Config()
    path = Path(path)
    name = name or path.name
    res = FR1SequenceResult(name=name, path=str(path))
    if not (path / "rgb.txt").is_file():
        res.skipped = "not found" if not path.exists() else "no rgb.txt"
        logger.info("fr1 %s: skipped (%s: %s)", name, res.skipped, path)
        return res
    t0 = time.perf_counter()
    try:
        frames_sel = None if config.max_frames is None else f"0:{int(config.max_frames)}"
        # calibration: camera.json if present, else fr1 from the folder name
        seq = TUMSequence(path, undistort=config.undistort, load_depth=False, frames=frames_sel)
        frames = list(protocol_frames(seq, config))
        res.n_frames = len(frames)
        res.rows = compare_vo(frames, config.methods, config.resolution, config.compare)
    except (ValueError, FileNotFoundError, OSError) as exc:
        res.skipped = f"unreadable: {type(exc).__name__}: {exc}"
        logger.warning("fr1 %s: skipped (%s)", name, res.skipped)
    res.wall_s = time.perf_counter() - t0
    return res


def _fr1_job(path: str, config: FR1Config, name: str) -> Dict[str, object]:
    """Job of :func:`run_fr1`: ``{"result": FR1SequenceResult}``."""
    return {"result": run_fr1_sequence(path, config, name=name)}


def run_fr1(root: Union[str, Path], sequences: Sequence[str] = FR1_SEQUENCES,
            config: Optional[FR1Config] = None,
            out_dir: Optional[Union[str, Path]] = None,
            runner: Optional[RunnerConfig] = None) -> FR1Report:
    """Run the protocol on every requested sequence under ``root``.

    Args:
        root: folder holding ``rgbd_dataset_freiburg1_<name>`` folders.
        sequences: names from :data:`FR1_SEQUENCES` (default all eight).
        config: :class:`FR1Config`.
        out_dir: when given, each evaluated sequence's trajectories and
            ``results.json`` go to ``out_dir/<name>/``, the report to
            ``out_dir/fr1_report.json`` and the merged table (rows, means,
            provenance) to ``out_dir/fr1_table.md/.json/.csv``.
        runner: how the present sequences run (one job each,
            :mod:`spgeo.evaluation.jobs`; default sequentially here, no
            progress bar); missing ones are skipped without a job.  A
            sequence whose job fails is skipped with ``"failed: <error>"``.
    Raises ``ValueError`` for an unknown sequence name.
    """
    config = config or FR1Config()
    unknown = [s for s in sequences if s not in FR1_SEQUENCES]
    if unknown:
        raise ValueError(f"run_fr1: unknown fr1 sequence(s) {unknown}; expected some of "
                         f"{list(FR1_SEQUENCES)}")
    runner = runner or RunnerConfig(progress=False)
    results: Dict[str, FR1SequenceResult] = {}
    jobs = []
    for name in sequences:
        path = sequence_folder(root, name)
        if (path / "rgb.txt").is_file():
            jobs.append(Job(name, _fr1_job, (str(path), config, name), meta={"path": str(path)}))
        else:
            results[name] = run_fr1_sequence(path, config, name=name)  # skipped, no job
    for row in (run_jobs(jobs, dataclasses.replace(runner, desc="tum_fr1")) if jobs else []):
        r = row.get("result")
        if row["error"] or r is None:
            r = FR1SequenceResult(name=row["job"], path=row["path"],
                                  skipped=f"failed: {row['error']}")
        results[row["job"]] = r
        if out_dir is not None and not r.skipped:
            write_results(r.rows, Path(out_dir) / r.name,
                          {"sequence": r.name, "path": r.path, "protocol": "tum_fr1"})
    report = FR1Report(sequences=[results[n] for n in sequences], methods=tuple(config.methods),
                       config=config)
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        with open(Path(out_dir) / "fr1_report.json", "w", encoding="utf-8") as fh:
            json.dump(report.to_dict(), fh, indent=2, default=json_default)
        fr1_table(report, provenance(report.to_dict()["protocol"], runner)).write(
            Path(out_dir), "fr1_table")
    return report


def fr1_table(report: FR1Report, prov: Optional[dict] = None) -> EvalTable:
    """The report as an :class:`~spgeo.evaluation.jobs.EvalTable`: one row per
    sequence (``ate_<method>`` m and ``tracked_<method>`` fraction, None when
    not run or failed; ``skipped``; ``error`` for a failed job), means over
    the rows without error."""
    rows = []
    for s in report.sequences:
        row: Dict[str, object] = {"sequence": s.name, "frames": s.n_frames or None,
                                  "skipped": s.skipped, "wall_s": s.wall_s,
                                  "error": s.skipped if (s.skipped or "").startswith("failed")
                                  else None}
        for m in report.methods:
            r = next((r for r in s.rows if r.method == m), None)
            ate = None if r is None or not math.isfinite(r.ate_rmse_m) else r.ate_rmse_m
            row[f"ate_{m}"] = ate
            row[f"tracked_{m}"] = None if r is None else r.tracked_fraction
        rows.append(row)
    cols = ([("sequence", "sequence", 0), ("frames", "frames", 0)]
            + [c for m in report.methods for c in ((f"{m} ATE m", f"ate_{m}", 3),
                                                   (f"{m} tracked", f"tracked_{m}", 2))]
            + [("skipped", "skipped", 0), ("error", "error", 0)])
    return EvalTable(rows, cols, id_keys=("frames",), provenance=dict(prov or {}),
                     csv_columns=[k for _, k, _ in cols] + ["wall_s"],
                     note="Per-frame ATE RMSE in metres after Sim(3) alignment (evo); "
                          "tracked = fraction of frames posed.")


def _fr1_row(s: FR1SequenceResult, methods: Sequence[str]) -> List[str]:
    """A sequence's cells of :func:`format_fr1_table` before the paper columns:
    name, frames and per method ``ATE (tracked %)`` (``failed (..%)`` without an
    ATE, ``-`` where the method did not run, ``skipped`` for a skipped sequence)."""
    if s.skipped:
        return [f"fr1/{s.name}", MISSING] + ["skipped"] * len(methods)
    cells = [f"fr1/{s.name}", cell(s.n_frames)]
    for m in methods:
        row = next((r for r in s.rows if r.method == m), None)
        if row is None:
            cells.append(MISSING)
            continue
        ate = cell(row.ate_rmse_m, 3) if math.isfinite(row.ate_rmse_m) else "failed"
        cells.append(f"{ate} ({cell(100 * row.tracked_fraction, '{:.0f}%')})")
    return cells


def format_fr1_table(report: FR1Report) -> str:
    """Markdown table: one row per sequence (per-frame Sim(3) ATE RMSE in m per
    method, tracked fraction in brackets), a mean row, and the paper's means
    as reference columns (per-sequence paper numbers: 'n/a')."""
    ours = list(report.methods)
    paper = list(PAPER_MEAN_ATE_M)
    rows = [_fr1_row(s, ours) + ["n/a"] * len(paper) for s in report.sequences]
    means = [f"{cell(v, 3)} ({k}/{len(FR1_SEQUENCES)} seq)" for v, k in map(report.mean_ate, ours)]
    rows.append(["**mean**", ""] + means
                + [f"{cell(PAPER_MEAN_ATE_M[p], 3)} (8 seq)" for p in paper])
    lines = markdown_table(["sequence", "frames"] + ours + [f"paper: {p}" for p in paper], rows,
                           "l" + "r" * (1 + len(ours) + len(paper)))
    c = report.config
    lines += ["",
              "Per-frame ATE RMSE in metres after Sim(3) alignment (evo Umeyama, scale "
              "corrected) over the posed frames; (x%) = frames posed. Protocol: RGB only, "
              f"undistorted={c.undistort}, crop l/t/r/b={list(c.crop)} px, resized to "
              f"{c.resolution[0]}x{c.resolution[1]}"
              + (f", first {c.max_frames} frames per sequence (NOT the full protocol)"
                 if c.max_frames else ", full sequences") + ". "
              "Paper columns: mean over the 8 sequences from the SuperPrimitive paper "
              "(per-sequence values not reproduced here); our means are over the sequences "
              "evaluated, so compare them only when all 8 ran."]
    if report.skipped:
        lines.append("Skipped: " + ", ".join(f"fr1/{k} ({v})" for k, v in report.skipped.items()))
    return "\n".join(lines)


# ===================================================================== CLI
NAME = "tum_fr1"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m spgeo.evaluation.vo.tum_fr1``."""
    parser = protocol_parser(
        "python -m spgeo.evaluation.vo.tum_fr1",
        "TUM RGB-D fr1 monocular VO protocol (undistort, crop 16/32 px, "
        "160x120, RGB only): per-frame Sim(3) ATE per sequence and mean.", dataset=False)
    parser.add_argument("--root", required=True,
                        help="folder with rgbd_dataset_freiburg1_<name> sequence folders")
    parser.add_argument("--sequences", nargs="+", default=list(FR1_SEQUENCES),
                        choices=FR1_SEQUENCES, help="sequences (default: all eight)")
    parser.add_argument("--methods", nargs="+", default=["spgeo-classical", "feature"],
                        choices=FR1_METHODS,
                        help="methods (default: spgeo-classical feature; colmap is slow)")
    parser.add_argument("--max-frames", type=int, default=None,
                        help="first N frames per sequence only (default: all = the protocol)")
    parser.add_argument("--out", default=None, help="write trajectories and JSON here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_runner_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the fr1 protocol (:func:`run_fr1`) and print :func:`format_fr1_table`.
    Returns 0 when at least one sequence was evaluated, 1 when all were skipped."""
    runner = runner_config(args, desc="tum_fr1")
    # one bar across the sequences when they run on Ray, else one per method
    config = FR1Config(methods=tuple(args.methods), max_frames=args.max_frames,
                       compare=VOCompareConfig(progress=runner.progress
                                               and runner.backend == "local"))
    if not Path(args.root).is_dir():
        raise FileNotFoundError(f"root folder not found: {args.root}")
    report = run_fr1(args.root, args.sequences, config, out_dir=args.out,
                     runner=dataclasses.replace(runner, progress=runner.progress
                                                and runner.backend != "local"))
    print(format_fr1_table(report))
    if args.out:
        print(f"wrote {Path(args.out) / 'fr1_report.json'} and "
              f"{Path(args.out) / 'fr1_table.md'} (.json, .csv)")
    return 0 if report.evaluated else 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m spgeo.evaluation.vo.tum_fr1``: run the fr1 protocol and print the
    table.  Returns 0 when at least one sequence was evaluated, 1 when all were
    skipped, 2 for bad arguments."""
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
