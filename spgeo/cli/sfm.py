"""``spgeo sfm``: argument wiring for :func:`spgeo.sfm.few_view_sfm`.

    spgeo sfm --ref IMG --views IMG [IMG ...] --intrinsics fx,fy,cx,cy --out DIR
              [--frontend classical|manhattan|onnx|onnx-depth] [--sam-family NAME]
              [--normal-model NAME|PATH] [--depth-model NAME|PATH] [--shape-model scaled|planar]
              [--init features|twoview|identity] [--export-colmap DIR]
              [--config FILE] [--set FIELD=VALUE ...]
              [--rerun spawn | save FILE.rrd | connect [ADDR]]

Writes ``DIR/poses.txt`` (one line per image: ``name tx ty tz qx qy qz qw``,
camera-to-reference, the reference at identity, translation in the
reconstruction's unknown scale), ``DIR/depth.npy`` (float32 reference depth at
the reference image's size), ``DIR/cloud.ply`` and ``DIR/report.json`` (the
effective ``SfMConfig`` under ``"config"``); with ``--export-colmap DIR`` a
COLMAP model (:func:`spgeo.io.colmap_export.export_sfm_result`).  The folder is
staged (:class:`spgeo.io.outputs.StagedFolder`): checked before the run, replaced
as a whole.  A flagged run (status not ok) writes NaN depth for unsupported
primitives and no ``cloud.ply`` when no point is supported.  Exit code 0 when
the SfM status is ok, 3 otherwise (:mod:`spgeo.cli.exit_codes`).  The front-end
(primitives at :data:`spgeo.sfm.SFM_WORKING_SIZE`) is built by
:func:`spgeo.frontend.build_frontend` before any image is read: a missing model or
one that breaks its preset's contract is exit code 2, nothing written
(:mod:`spgeo.cli.model_args` for the model options).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..jsonio import json_default
from ..frontend import MONOCULAR_FRONTENDS
from ..validation import InputError
from ..apps.args import parse_intrinsics
from .exit_codes import EXIT_FLAGGED, EXIT_OK
from ..configs import apply_overrides, config_to_dict, resolve_config
from .config_args import add_config_arguments
from .model_args import add_model_arguments, check_depth_model_flag
from .rerun_args import add_rerun_argument, open_rerun

__all__ = ["add_sfm_cli"]


def _default_sfm_config():
    from ..sfm import SfMConfig

    return SfMConfig()


def _sfm_config(args: argparse.Namespace):
    """The effective ``SfMConfig``: defaults < --config < explicit options < --set."""
    from ..sfm import SfMConfig

    cfg = resolve_config(SfMConfig(), args.config_file)
    explicit = {k: v for k, v in (("shape_model", args.shape_model), ("init", args.init))
                if v is not None}
    if explicit:
        cfg = apply_overrides(cfg, explicit)
    return resolve_config(cfg, sets=args.set)


#: what the files of ``spgeo sfm`` are (the manifest's ``"files"``: what, units)
_SFM_FILES = {
    "poses.txt": ("per image (reference first, identity): name and its pose in the "
                  "reference camera, 'name tx ty tz qx qy qz qw', camera-to-reference",
                  "translations in the map's unit (unknown scale: monocular)"),
    "depth.npy": ("the reference image's depth (float32, (H, W) at the reference size), NaN "
                  "where no supported primitive covers the pixel", "the map's unit"),
    "cloud.ply": ("the supported primitives' points in the reference camera, coloured, PLY",
                  "the map's unit"),
    "report.json": ("status, per-view status, pose covariances, solver report and the "
                    "SfMConfig (JSON)", "as each key says; translations in the map's unit"),
}


def _described(out: Path) -> dict:
    """:data:`_SFM_FILES` of the files written in ``out`` (``StagedFolder.commit``)."""
    from ..io.outputs import FileInfo

    return {out / n: FileInfo(*info) for n, info in _SFM_FILES.items() if (out / n).is_file()}


def _write_outputs(out: Path, res, ref: np.ndarray, cam, names, cfg) -> int:
    """``poses.txt``, ``depth.npy``, ``cloud.ply`` (the supported primitives'
    finite points; no file when there are none) and ``report.json`` (last) into
    ``out``; returns the number of cloud points."""
    import cv2

    from ..frame import Frame, resize_frame
    from ..geometry import pose_to_tum

    with open(out / "poses.txt", "w") as fh:
        for name, T in zip(names, [np.eye(4)] + res.T_ref_view):
            fh.write(name + " " + " ".join(f"{x:.9f}" for x in pose_to_tum(T)) + "\n")
    depth = res.depth
    if depth.shape != ref.shape[:2]:    # back to the reference size, nearest neighbour
        depth = cv2.resize(depth.astype(np.float32), cam.size, interpolation=cv2.INTER_NEAREST)
    np.save(out / "depth.npy", depth.astype(np.float32))
    colours = resize_frame(Frame(ref, cam, 0.0), res.camera.size).image
    cloud = res.point_cloud(colours)
    if len(cloud.points):
        cloud.save_ply(out / "cloud.ply")
    report = {"status": res.status, "view_status": res.view_status,
              "log_scale_std_median": float(np.nanmedian(res.log_scale_std))
              if np.any(np.isfinite(res.log_scale_std)) else None,
              "pose_covariances": [None if c is None else c.tolist() for c in res.pose_covariances],
              "cloud_points": int(len(cloud.points)),
              **{k: v for k, v in res.report.items()}, "config": config_to_dict(cfg)}
    with open(out / "report.json", "w") as fh:
        json.dump(report, fh, indent=2, default=json_default)
    return int(len(cloud.points))


def _run(args: argparse.Namespace) -> int:
    from ..camera import PinholeCamera
    from ..images import load_image
    from ..io.outputs import StagedFolder
    from ..frontend import build_frontend
    from ..sfm import SFM_WORKING_SIZE, few_view_sfm

    cfg = _sfm_config(args)
    check_depth_model_flag(args.depth_model, args.frontend)
    staged = StagedFolder(args.out, "--out", "spgeo sfm")   # checked before the run
    if args.export_colmap:
        from ..io.colmap_export import check_export_directory

        check_export_directory(args.export_colmap, args.out)
    frontend = build_frontend(args.frontend, SFM_WORKING_SIZE, sam_family=args.sam_family,
                              normal_model=args.normal_model, depth_model=args.depth_model)
    ref = load_image(args.ref)
    views = [load_image(p) for p in args.views]
    fx, fy, cx, cy = parse_intrinsics(args.intrinsics)
    cam = PinholeCamera(fx, fy, cx, cy, ref.shape[1], ref.shape[0])
    for p, v in zip(args.views, views):
        if v.shape[:2] != ref.shape[:2]:
            raise InputError(f"{p} is {v.shape[1]}x{v.shape[0]}, the reference is "
                             f"{ref.shape[1]}x{ref.shape[0]}: all images must share one camera")
    res = few_view_sfm(ref, views, cam, frontend, cfg)
    with open_rerun(args) as viewer:
        if viewer is not None:
            viewer.log_sfm(res, ref, views)
    names = [Path(args.ref).name] + [Path(p).name for p in args.views]
    with staged:
        n_points = _write_outputs(staged.path, res, ref, cam, names, cfg)
        staged.commit("complete" if res.ok else "flagged", described=_described(staged.path),
                      sfm_status=res.status)
    print(f"status: {res.status}  ({', '.join(res.view_status)})")
    cloud = f"cloud.ply ({n_points} points)" if n_points else "no cloud.ply (no supported depth)"
    print(f"wrote poses.txt, depth.npy, {cloud}, report.json in {args.out}")
    if args.export_colmap:
        from ..io.colmap_export import export_sfm_result
        model = export_sfm_result(args.export_colmap, res, [ref] + views, names)
        print(f"wrote the COLMAP model {model} (images in {Path(args.export_colmap) / 'images'})")
    if not res.ok:
        print(f"flagged: SfM status {res.status} (views: {', '.join(res.view_status)}); the "
              "depth of unsupported primitives is NaN", file=sys.stderr)
        return EXIT_FLAGGED
    return EXIT_OK


def add_sfm_cli(subparsers) -> argparse.ArgumentParser:
    """Register ``spgeo sfm`` on an argparse sub-parser collection."""
    p = subparsers.add_parser("sfm", help="few-view SfM: reference + unposed views -> poses, depth")
    p.add_argument("--ref", required=True, help="reference image")
    p.add_argument("--views", required=True, nargs="+", help="supporting images (same camera)")
    p.add_argument("--intrinsics", required=True, help="fx,fy,cx,cy in pixels (undistorted)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--frontend", default="classical", choices=MONOCULAR_FRONTENDS,
                   help="front-end (default classical; onnx and onnx-depth need "
                        "`spgeo models fetch`)")
    add_model_arguments(p)
    p.add_argument("--shape-model", default=None, choices=["scaled", "planar"],
                   help="SfMConfig.shape_model (default scaled)")
    p.add_argument("--init", default=None, choices=["features", "twoview", "identity"],
                   help="SfMConfig.init (default features)")
    p.add_argument("--export-colmap", default=None, metavar="DIR",
                   help="also write a COLMAP model: DIR/images/*.png (working resolution) and "
                        "DIR/sparse/0/{cameras,images,points3D}.bin")
    add_rerun_argument(p, "the reference camera, views, depth and cloud")
    add_config_arguments(p, "SfMConfig", _default_sfm_config)
    p.set_defaults(func=_run)
    return p
