"""Monocular VO on long synthetic hand-held sequences (ground truth for everything).

    python -m spgeo.evaluation.vo.synthetic [--frames 150] [--seeds 0 1 2]
        [--runs depth classical classical:planar ...] [--rotation 90:120] [--out DIR]
        [--forward STEP] [--workers N | --address ADDR]

Each seed renders a room (:class:`spgeo.synthetic.SyntheticScene`) and a
hand-held trajectory (:func:`spgeo.synthetic.make_trajectory`) at 160x120
whose translation is frozen on the ``--rotation`` frame range (a rotation-only
part: the hard case for monocular keyframe selection); with ``--forward STEP``
a forward drive of STEP metres per frame through a long hall instead (large
inter-frame motion, :func:`spgeo.synthetic.make_forward_trajectory`).  A run is
``FRONTEND[:MODEL]``: front-end ``depth`` (normals and initial scales from the
rendered depth: oracle) or ``classical`` (monocular, never reads depth), and
an :data:`spgeo.vo.PRIMITIVE_MODELS` ablation (default ``integrated``).
Reported per run and seed: per-frame and keyframe-only Sim(3) ATE RMSE as %
of the trajectory length (frames flagged ``lost`` excluded, their count
shown), keyframes, FPS (tracking + mapping, rendering excluded) and seconds
per stage.  The defaults of :class:`spgeo.vo.OdometryConfig` are what
this script measures; nothing here is tuned to a real data set.

Each (seed, run) is one job (:mod:`spgeo.evaluation.jobs`): sequential in
this process by default, on Ray with ``--workers N`` / ``--address ADDR``;
the table (rows, means per run over the seeds, provenance) is printed and,
with ``--out``, written as ``results.md/.json/.csv``.  A run that fails is
a row with its error (exit status 1).
"""
from __future__ import annotations

import argparse
import functools
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from spgeo import synthetic
from spgeo.evaluation.trajectory import ate_per_frame_and_keyframes
from spgeo.frame import Frame
from spgeo.frontend import FrontEndConfig, make_frontend
from spgeo.apps.vo_run import VORunConfig, blas_threads
from spgeo.configs import apply_overrides, nest, parse_assignments
from spgeo.evaluation.jobs import (EvalTable, Job, add_runner_arguments, provenance,
                                    run_table, runner_config)
from spgeo.evaluation.runner import protocol_parser, run_protocol
from spgeo.vo import Odometry, OdometryConfig

__all__ = ["SyntheticVOConfig", "synthetic_sequence", "run_synthetic_vo", "synthetic_run_row",
           "make_jobs", "TABLE_COLUMNS", "build_parser", "run", "main"]


@dataclass(frozen=True)
class SyntheticVOConfig:
    """A synthetic VO sequence.

    Attributes:
        n_frames: frames (default 150, 5 s at 30 Hz).
        seed: scene and trajectory seed.
        size: (width, height) pixels (default 160x120).
        rotation: frame range ``(start, end)`` with frozen translation
            (default (90, 120)); None for none.
        supersample: anti-aliasing of the renderer (default 2).
        forward_step: None (default) for the hand-held room sequence; metres per
            frame for a forward drive instead (:func:`spgeo.synthetic.make_forward_trajectory`
            in :func:`spgeo.synthetic.forward_scene_config`'s hall; ``rotation`` is
            ignored and the drive is cut at :data:`FORWARD_DRIVE_M` so it stays in
            the hall's free zone).
    """

    n_frames: int = 150
    seed: int = 0
    size: Tuple[int, int] = (160, 120)
    rotation: Optional[Tuple[int, int]] = (90, 120)
    supersample: int = 2
    forward_step: Optional[float] = None


#: Longest forward drive (m) of :class:`SyntheticVOConfig` inside the hall's free zone.
FORWARD_DRIVE_M = 6.4


def synthetic_sequence(config: SyntheticVOConfig = SyntheticVOConfig()) -> List[Frame]:
    """Rendered frames (with depth and ground-truth ``T_world_cam``)."""
    cam = synthetic.default_camera(*config.size)
    if config.forward_step is not None:
        step = float(config.forward_step)
        if not step > 0:
            raise ValueError(f"forward_step must be > 0 metres, got {config.forward_step!r}")
        n = min(config.n_frames, 1 + int(FORWARD_DRIVE_M / step + 1e-9))
        traj = synthetic.make_forward_trajectory(
            n, config.seed, synthetic.ForwardTrajectoryConfig(step=step))
        scene = synthetic.SyntheticScene.generate(config.seed, synthetic.forward_scene_config())
        return synthetic.render_frames(scene, cam, traj, supersample=config.supersample)
    rot = config.rotation
    if rot is not None and not (0 <= rot[0] < rot[1] <= config.n_frames):
        rot = None
    traj = synthetic.make_trajectory(config.n_frames, config.seed,
                                     synthetic.TrajectoryConfig(pure_rotation=rot))
    scene = synthetic.SyntheticScene.generate(config.seed)
    return synthetic.render_frames(scene, cam, traj, supersample=config.supersample)


def run_synthetic_vo(frames: Sequence[Frame], frontend: str = "depth",
                     config: OdometryConfig = OdometryConfig()) -> Dict[str, object]:
    """Run :class:`Odometry` over rendered frames; returns a summary dict
    (ATE per-frame / keyframe-only in % of length and metres, counts, FPS,
    seconds per stage) and the odometry under ``"odometry"``."""
    cam = frames[0].camera
    fe = make_frontend(frontend, FrontEndConfig(working_size=cam.size))
    vo = Odometry(cam, config, fe)
    t0 = time.perf_counter()
    with blas_threads(VORunConfig().blas_threads):  # as the VO runner
        for f in frames:
            depth = f.depth if fe.uses_depth else None
            vo.track(Frame(f.image, cam, f.timestamp, depth))
    secs = time.perf_counter() - t0
    res = vo.result()
    gt = (np.array([f.timestamp for f in frames]), np.array([f.T_world_cam for f in frames]))
    ok = res.tracked
    ates = ate_per_frame_and_keyframes((res.timestamps[ok], res.poses[ok]), gt,
                                       keyframe_mask=res.is_keyframe[ok])
    rep = vo.report()
    out = {"frontend": frontend, "model": config.primitive_model, "frames": len(frames),
           "keyframes": int(res.is_keyframe.sum()), "lost": int((~ok).sum()),
           "segments": rep["n_segments"], "fps": len(frames) / secs,
           "tracking_fps": rep["tracking_fps"],
           "mapping_s_per_kf": rep["mapping_seconds_per_keyframe"],
           "seconds_per_stage": rep["seconds_per_stage"], "odometry": vo}
    for label, a in ates.items():
        out[label] = None if a is None else {"rmse_m": a.rmse, "percent": a.rmse_percent_of_length,
                                             "length_m": a.trajectory_length}
    return out


def parse_overrides(items: Sequence[str]) -> dict:
    """``["field=value", "sub.field=value", ...]`` -> ``{field: value, sub:
    {field: value}}`` with ``value`` a Python literal (``None``, ``0.02``,
    ``(1, 2)``); raises ``ValueError`` or ``SyntaxError``."""
    return nest(parse_assignments(items, strict=True))


def odometry_config(overrides: dict) -> OdometryConfig:
    """``OdometryConfig()`` with :func:`parse_overrides`' result applied
    (:func:`spgeo.configs.apply_overrides`; an unknown field raises a
    ``TypeError``, a value of the wrong type a ``ValueError``)."""
    return apply_overrides(OdometryConfig(), overrides)


@functools.lru_cache(maxsize=1)
def _cached_sequence(config: SyntheticVOConfig) -> Tuple[Frame, ...]:
    """The last rendered sequence of this process (the runs of one seed share it)."""
    return tuple(synthetic_sequence(config))


def synthetic_run_row(config: SyntheticVOConfig, run: str, overrides: Optional[dict] = None,
                      out: Optional[str] = None) -> Dict[str, object]:
    """One job of the protocol: run ``run`` (``FRONTEND[:MODEL]``) on the
    sequence of ``config`` with the :func:`parse_overrides` ``overrides``;
    the JSON-ready summary of :func:`run_synthetic_vo` plus flat ``ate_m``,
    ``ate_pct``, ``kf_ate_m``, ``kf_ate_pct``, ``length_m`` (None when not
    computed).  ``out``: the odometry is saved to
    ``out/seed<seed>_<run>`` (trajectories, no clouds)."""
    fe, _, model = run.partition(":")
    cfg = odometry_config({"primitive_model": model or "integrated", **(overrides or {})})
    r = run_synthetic_vo(_cached_sequence(config), fe, cfg)
    vo = r.pop("odometry")
    if out:
        vo.save(Path(out) / f"seed{config.seed}_{run.replace(':', '_')}", clouds=False)
    for label, key in (("per-frame", "ate"), ("keyframe-only", "kf_ate")):
        a = r[label]
        r[f"{key}_m"] = None if a is None else a["rmse_m"]
        r[f"{key}_pct"] = None if a is None else a["percent"]
    r["length_m"] = None if r["per-frame"] is None else r["per-frame"]["length_m"]
    return r


#: Markdown columns of the table: (header, row key, decimals).
TABLE_COLUMNS = (("run", "run", 0), ("seed", "seed", 0), ("per-frame ATE %", "ate_pct", 2),
                 ("keyframe-only ATE %", "kf_ate_pct", 2), ("per-frame ATE m", "ate_m", 4),
                 ("length m", "length_m", 2), ("KFs", "keyframes", 0), ("lost", "lost", 0),
                 ("segments", "segments", 0), ("FPS", "fps", 2), ("track FPS", "tracking_fps", 1),
                 ("mapping s/KF", "mapping_s_per_kf", 2), ("error", "error", 0))
_NOTE = ("ATE: Sim(3)-aligned RMSE of camera centres (evo), % of the ground-truth path length; "
         "per-frame = every frame not lost, keyframe-only = keyframes.")


def make_jobs(seeds: Sequence[int], runs: Sequence[str], n_frames: int = 150,
              size: Tuple[int, int] = (160, 120), rotation: Optional[Tuple[int, int]] = (90, 120),
              overrides: Optional[dict] = None, out: Optional[str] = None,
              forward_step: Optional[float] = None) -> List[Job]:
    """One :class:`~spgeo.evaluation.jobs.Job` per (seed, run), seed-major."""
    return [Job(f"seed{seed}/{run}", synthetic_run_row,
                (SyntheticVOConfig(n_frames, seed, tuple(size), rotation,
                                   forward_step=forward_step), run, overrides, out),
                meta={"run": run, "seed": seed})
            for seed in seeds for run in runs]


NAME = "vo_synthetic"


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = protocol_parser(None, __doc__, dataset=False, verbose=False)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--runs", nargs="+", default=["depth", "classical", "classical:planar"],
                    help="FRONTEND[:MODEL] (models: integrated, constant_depth, "
                         "constant_normal, planar)")
    ap.add_argument("--size", default="160x120", metavar="WxH",
                    help="rendered (and working) resolution, e.g. 320x240")
    ap.add_argument("--rotation", default="90:120", help="frozen-translation frames A:B or 'none'")
    ap.add_argument("--forward", type=float, default=None, metavar="STEP",
                    help="a forward drive of STEP metres per frame in a long hall instead of the "
                         f"hand-held room (large inter-frame motion; at most {FORWARD_DRIVE_M} m)")
    ap.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                    help="OdometryConfig overrides (Python literals), e.g. "
                         "window=7 render_prior_weight=1e-5")
    ap.add_argument("--out", default=None,
                    help="write results.md/.json/.csv (rewritten after each run) and the "
                         "trajectories here")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_runner_arguments(ap)
    return ap


def _options(args: argparse.Namespace):
    """``(overrides, rotation, size, runner)`` of the command line; ValueError
    naming the bad option."""
    try:
        overrides = parse_overrides(args.set)
        odometry_config(overrides)
    except (ValueError, TypeError, SyntaxError) as exc:
        raise ValueError(f"--set: {exc}") from exc
    rot = None if args.rotation == "none" else tuple(int(x) for x in args.rotation.split(":"))
    try:
        size = tuple(int(x) for x in args.size.lower().split("x"))
        if len(size) != 2 or min(size) < 1:
            raise ValueError
    except ValueError:
        raise ValueError(f"--size: expected WxH, got {args.size!r}") from None
    runner = runner_config(args, desc="vo_synthetic")
    if args.forward is not None and not args.forward > 0:
        raise ValueError(f"--forward: expected a step > 0 metres, got {args.forward}")
    return overrides, rot, size, runner


def run(args: argparse.Namespace) -> int:
    """Run the (seed, run) jobs, print the table (means per run over the seeds) and
    one stderr line per failed job; 1 when a job failed."""
    overrides, rot, size, runner = _options(args)
    prov = provenance({"frames": args.frames, "seeds": args.seeds, "runs": args.runs,
                       "size": list(size), "rotation": rot, "forward": args.forward,
                       "overrides": overrides}, runner)

    def table(rows):
        return EvalTable(rows, TABLE_COLUMNS, group_by=("run",), id_keys=("seed",), provenance=prov, note=_NOTE)

    result = run_table(make_jobs(args.seeds, args.runs, args.frames, size, rot, overrides,
                                 args.out, args.forward), runner, table, Path(args.out) if args.out else None)
    print(result.markdown())
    for r in result.failed:
        print(f"error: {r['job']}: {r['error']}", file=sys.stderr)
    return 1 if result.failed else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    return run_protocol(build_parser(), run, argv, NAME)


if __name__ == "__main__":
    raise SystemExit(main())
