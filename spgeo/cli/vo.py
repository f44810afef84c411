"""``spgeo vo``: argument wiring for :func:`spgeo.apps.vo_run.run_dataset`.

    spgeo vo --dataset {tum,7scenes,icl,folder,kitti,euroc,video,camera} PATH
             [--frames A:B[:STEP]]
             [--intrinsics fx,fy,cx,cy | --fov DEGREES | --calibration FILE[:ID]]
             [--depth-scale UNITS_PER_METRE] [--image-dir NAME]
             [--resolution WxH] [--strict]
             [--frontend classical|manhattan|depth|onnx|onnx-depth]
             [--sam-family NAME] [--normal-model NAME|PATH] [--depth-model NAME|PATH]
             [--config FILE] [--set FIELD=VALUE ...] --out DIR
             [--rerun spawn | save FILE.rrd | connect [ADDR]]
             [--mesh] [--export-colmap DIR] [--export-nerfstudio DIR] [--all-frames]
             [--metric-scale NAME|PATH] [--save-map DIR] [--load-map DIR]

``--config`` / ``--set`` reach the ``VORunConfig`` fields and, for any other
name, the ``OdometryConfig`` fields (``window=7`` is ``odometry.window=7``);
explicit options (``--resolution``, ``--strict``, ``--frontend``, ...) override
``--config``, and ``--set`` overrides both.  Without ``--resolution`` the
processing size keeps the input's aspect ratio at about 320x240 pixels
(:func:`spgeo.vo.processing.processing_size`).  A frame whose file cannot be read
is skipped (status ``skipped``, listed in report.json) unless ``--strict``,
which stops with exit code 2 naming the file.  ``--intrinsics`` / ``--fov`` /
``--calibration`` (a COLMAP, ORB-SLAM or Kalibr file,
:mod:`spgeo.datasets.calibration_files`) replace the input's camera
(:class:`spgeo.datasets.CameraSpec`); without them an
input with no calibration (a video, a camera, a folder without intrinsics) gets
guessed intrinsics, with a warning; ``report.json``'s ``intrinsics`` says which.
``--depth-scale`` sets the raw depth-PNG units per metre of the readers of depth
PNGs (tum, 7scenes, icl, folder; their ``depth_scale``), e.g. 5000 for TUM's
PNGs in a plain folder; a non-positive or non-finite value, or a kind without
depth PNGs, is an input error (exit code 2).
``--mesh`` fuses the keyframes'
depth maps (:func:`spgeo.io.fusion.fuse_odometry`) into OUT/mesh.ply and
OUT/cloud.ply (and the rerun recording's ``world/mesh``); ``--export-colmap`` /
``--export-nerfstudio`` write the keyframes (or, with ``--all-frames``, every
frame not lost) as a COLMAP model / a nerfstudio ``transforms.json`` data set.
``--metric-scale`` estimates one output scale from a metric-depth network
(``VORunConfig.metric_scale``, :mod:`spgeo.vo.metric_scale`) and writes every
output in metres; a missing or non-metric model is an input error (exit code 2)
before the first frame.  ``--save-map DIR`` writes the run's map (keyframes,
scales, landmarks: :mod:`spgeo.vo.saved_map`) after the run; ``--load-map DIR``
relocalises the first frames into a saved map and continues in its frame and
units (:mod:`spgeo.vo.map_entry`); a folder that is not a saved map, or one
saved at another processing camera, is an input error (exit code 2).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..frontend import FRONTENDS
from ..validation import FOV_RANGE_DEG, InputError
from ..apps.args import DATASET_KINDS, parse_intrinsics, parse_resolution
from ..configs import apply_overrides, resolve_config
from .config_args import add_config_arguments
from .model_args import add_model_arguments, check_depth_model_flag
from .rerun_args import add_rerun_argument, open_rerun
from .exit_codes import EXIT_FLAGGED, EXIT_INTERRUPTED

__all__ = ["add_vo_cli"]


_DESCRIPTION = """Monocular visual odometry (SuperPrimitives) on a data set.

Writes OUT/trajectory.txt (every processed frame, TUM 'timestamp tx ty tz qx qy
qz qw', camera-to-world; timestamps are frame numbers for data sets without
timestamps such as 7-Scenes), OUT/keyframes.txt, OUT/trajectory.status.txt,
OUT/report.json (with the per-frame and keyframe-only Sim(3) ATE under "ate"
when the data set has ground truth, the OdometryConfig under "config" and the
rest of the run config under "run_config", the input camera under
"intrinsics" with "source": "file", "given" (--intrinsics / --fov /
--calibration) or
"guessed" (no calibration: EXIF focal length, else a default field of view;
also a warning on stderr)) and keyframe point clouds in OUT/clouds/; with --mesh,
the fused OUT/mesh.ply and OUT/cloud.ply (TSDF of the keyframes' depth maps;
its parameters under "fusion", settings --set fusion.voxel_size=...).  With
ground truth, OUT/groundtruth.txt (TUM, the frames the ATE evaluates): `evo_ape
tum groundtruth.txt trajectory.txt -as` gives the report's ATE.  Positions are
in VO units (unknown scale; report.json "units"), metres with --metric-scale or
the depth front-end.
OUT/.spgeo-output.json lists every file with what it is and its units.  The
classical and onnx front-ends never read depth; 'depth' uses the sensor depth
(RGB-D / oracle).  A frame whose image (or depth) file cannot
be read is skipped with a warning: status 'skipped' in
OUT/trajectory.status.txt, no pose, not in the ATE, listed under "skipped" in
OUT/report.json; --strict stops instead (exit code 2)."""


_DEPTH_SCALE = ("raw depth-PNG units per metre (tum, 7scenes, icl, folder; default the "
                "reader's: 5000 for TUM and ICL, 1000 = millimetres otherwise), e.g. 5000 for "
                "TUM depth PNGs in a plain folder")


def _default_run_config():
    from ..apps.vo_run import VORunConfig

    return VORunConfig()


def _run_config(args: argparse.Namespace):
    """The effective ``VORunConfig``: defaults < --config < explicit options < --set."""
    from ..apps.vo_run import VORunConfig

    cfg = resolve_config(VORunConfig(), args.config_file, route="odometry")
    explicit = {}
    if args.resolution is not None:
        explicit["odometry.resolution"] = parse_resolution(args.resolution)
    if args.frontend is not None:
        explicit["frontend"] = args.frontend
    if args.no_progress:
        explicit["progress"] = False
    if args.strict:
        explicit["strict"] = True
    if args.sam_family is not None:
        explicit["sam_family"] = args.sam_family
    if args.normal_model is not None:
        explicit["normal_model"] = args.normal_model
    if args.depth_model is not None:
        explicit["depth_model"] = args.depth_model
    if args.metric_scale is not None:
        explicit["metric_scale"] = args.metric_scale
    if explicit:
        cfg = apply_overrides(cfg, explicit)
    cfg = resolve_config(cfg, sets=args.set, route="odometry")
    check_depth_model_flag(cfg.depth_model, cfg.frontend)
    return cfg


def _given_camera(args: argparse.Namespace):
    """The :class:`~spgeo.datasets.CameraSpec` of ``--intrinsics`` / ``--fov`` /
    ``--calibration`` (None without any; the calibration file read now);
    :class:`InputError` naming a bad value, or more than one given."""
    from ..datasets import CameraSpec

    given = [o for o, v in (("--intrinsics", args.intrinsics), ("--fov", args.fov),
                            ("--calibration", args.calibration)) if v is not None]
    if len(given) > 1:
        raise InputError(f"give one of --intrinsics, --fov and --calibration, not both "
                         f"({' and '.join(given)} given)")
    values = None if args.intrinsics is None else parse_intrinsics(args.intrinsics)
    return CameraSpec.from_options(values, args.fov, args.calibration)


def _reader_options(args: argparse.Namespace, kind: str) -> dict:
    """The reader options of ``--depth-scale`` (``depth_scale``, checked:
    :func:`spgeo.datasets.check_depth_scale`) and ``--image-dir`` (``image_dir``);
    :class:`InputError` for a kind whose reader has no such option."""
    from ..datasets import check_depth_scale, reader_options

    given = {"depth_scale": (args.depth_scale, "--depth-scale", check_depth_scale),
             "image_dir": (args.image_dir, "--image-dir", str)}
    options = {}
    for field, (value, flag, check) in given.items():
        if value is None:
            continue
        if field not in reader_options(kind):
            takes = [k for k in DATASET_KINDS if field in reader_options(k)]
            raise InputError(f"{flag}: the {kind!r} reader has no such option (kinds that "
                             f"take it: {', '.join(takes)})")
        options[field] = check(value)
    return options


def _run(args: argparse.Namespace) -> int:
    from ..apps.vo_run import run_dataset
    from ..io.outputs import StagedFolder

    kind, path = args.dataset
    if kind.lower() not in DATASET_KINDS:
        raise InputError(f"--dataset KIND must be one of {', '.join(DATASET_KINDS)}, "
                         f"got {kind!r}")
    cfg = _run_config(args)
    given = _given_camera(args)
    options = _reader_options(args, kind.lower())
    staged = StagedFolder(args.out, "--out", "spgeo vo")   # checked before the run
    _check_exports(args)
    saved = _saved_map(args)
    if args.all_frames and kind.lower() == "camera":
        raise InputError("--all-frames cannot re-read a live camera")
    with open_rerun(args) as viewer:
        run = run_dataset(kind.lower(), path, frames=args.frames, config=cfg, on_frame=viewer,
                          given_camera=given, saved_map=saved, **options)
        if viewer is not None:
            viewer.finish(run.odometry)
        fused = _fuse(run, viewer) if args.mesh else None
    ate = run.ate()
    with staged:
        paths = run.save(staged.path, ate=ate, title=staged.target.name, fusion=fused)
        staged.commit(run.status, described=run.describe_files(paths), frames=run.n_frames)
    for line in run.summary_lines(ate):
        print(line)
    n_clouds = len(paths.get("clouds") or [])
    print(f"wrote trajectory.txt, keyframes.txt, report.json"
          f"{', groundtruth.txt' if 'groundtruth' in paths else ''}"
          f"{f', {n_clouds} keyframe clouds' if n_clouds else ''}"
          f"{', mesh.ply, cloud.ply' if fused is not None else ''} in {args.out}")
    if run.interrupted:
        print(f"interrupted after {run.n_frames} frames: {args.out} holds them, marked "
              "interrupted in report.json", file=sys.stderr)
        return EXIT_INTERRUPTED
    if run.status != "ok":
        print(f"no map was initialised: {run.odometry.init_failure or 'no keyframe pair'}; "
              "the poses are provisional", file=sys.stderr)
        return EXIT_FLAGGED
    _export(args, run, given)
    if args.save_map:
        kept = run.odometry.saved_map()
        kept.save(args.save_map)
        print(f"wrote the map ({len(kept.keyframes)} keyframes with depth) to {args.save_map}")
    return 0


def _saved_map(args: argparse.Namespace):
    """The map of ``--load-map`` (None without), after checking that ``--save-map``
    can be written (:class:`InputError`, exit code 2, before the run)."""
    from ..vo.saved_map import SavedMap

    if args.save_map:
        SavedMap.check_target(args.save_map)
        if Path(args.save_map).resolve() == Path(args.out).resolve():
            raise InputError("--save-map needs a folder other than --out")
    return None if args.load_map is None else SavedMap.load(args.load_map)


def _check_exports(args: argparse.Namespace) -> None:
    """Check the export folders before the run (:class:`InputError`, exit code 2)."""
    if args.export_colmap:
        from ..io.colmap_export import check_export_directory

        check_export_directory(args.export_colmap, args.out)
    if args.export_nerfstudio:
        from ..io.nerfstudio_export import check_nerfstudio_directory

        check_nerfstudio_directory(args.export_nerfstudio, args.out)
        if args.export_colmap and (Path(args.export_colmap).resolve()
                                   == Path(args.export_nerfstudio).resolve()):
            raise InputError("--export-colmap and --export-nerfstudio need different folders")
    if args.all_frames and not (args.export_colmap or args.export_nerfstudio):
        raise InputError("--all-frames needs --export-colmap DIR or --export-nerfstudio DIR")


def _fuse(run, viewer):
    """The TSDF fusion of the run's keyframes (``VORunConfig.fusion``, ``--set
    fusion.FIELD=VALUE``; logged to ``viewer`` when given; ``run.save`` writes it
    and its parameters), or None with a warning on stderr when no keyframe
    carries depth."""
    try:
        fused = run.fuse()
    except ValueError as exc:
        print(f"no mesh: {exc}", file=sys.stderr)
        return None
    if viewer is not None:
        import numpy as np

        mesh = fused.mesh
        viewer.log_mesh("world/mesh", fused.vertices, fused.triangles,
                        np.asarray(mesh.vertex_colors), np.asarray(mesh.vertex_normals))
    return fused


def _export(args: argparse.Namespace, run, given) -> None:
    """The COLMAP and nerfstudio exports asked for (keyframes, or every frame not
    lost with ``--all-frames``: the frames are read again, the run keeps only
    the keyframes' images, with the camera ``given`` by --intrinsics / --fov /
    --calibration)."""
    kind, path = args.dataset

    def frames():
        if not args.all_frames:
            return None
        from ..datasets import open_dataset

        return open_dataset(kind.lower(), path, frames=args.frames, load_depth=False,
                            given_camera=given)

    what = "all frames not lost" if args.all_frames else "keyframes"
    if args.export_colmap:
        model = run.export_colmap(args.export_colmap, frames())
        print(f"wrote the COLMAP model {model} ({what}, images in {args.export_colmap}/images)")
    if args.export_nerfstudio:
        tf = run.export_nerfstudio(args.export_nerfstudio, frames())
        print(f"wrote the nerfstudio data set {tf} ({what}, images in "
              f"{args.export_nerfstudio}/images)")


def _add_output_arguments(p: argparse.ArgumentParser) -> None:
    """The options of what a run writes beside OUT: exports, mesh, its map."""
    p.add_argument("--export-colmap", default=None, metavar="DIR",
                   help="also write a COLMAP model of the keyframes: DIR/images/*.png (processing "
                        "resolution), DIR/sparse/0/{cameras,images,points3D}.bin")
    p.add_argument("--export-nerfstudio", default=None, metavar="DIR",
                   help="also write a nerfstudio data set of the keyframes: DIR/transforms.json "
                        "(PINHOLE intrinsics, camera-to-world transform_matrix in nerfstudio's "
                        "OpenGL camera axes) and DIR/images/*.png (processing resolution)")
    p.add_argument("--all-frames", action="store_true",
                   help="--export-colmap / --export-nerfstudio: every frame not lost, not only "
                        "the keyframes")
    p.add_argument("--mesh", action="store_true",
                   help="fuse the keyframes' depth maps at their final poses (TSDF) into "
                        "OUT/mesh.ply and OUT/cloud.ply (VO world and units; metres with "
                        "--metric-scale)")
    p.add_argument("--save-map", default=None, metavar="DIR",
                   help="write the run's map after the run: DIR/map.json, the keyframes' "
                        "images and scaled primitives, the landmarks (a later run continues "
                        "in it with --load-map)")
    p.add_argument("--load-map", default=None, metavar="DIR",
                   help="relocalise into a map written by --save-map and continue in its "
                        "frame and units (same input camera and resolution); if no frame is "
                        "placed within max_lost_frames, a map of the run's own starts")


def _add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """``--intrinsics`` / ``--fov`` / ``--calibration``: the input's camera
    (:func:`_given_camera`)."""
    p.add_argument("--intrinsics", default=None, metavar="fx,fy,cx,cy",
                   help="camera intrinsics in pixels of the input images (replace the "
                        "data set's calibration; no distortion)")
    p.add_argument("--fov", default=None, metavar="DEGREES",
                   help=f"horizontal field of view in ({FOV_RANGE_DEG[0]:g}, {FOV_RANGE_DEG[1]:g}) "
                        "degrees, principal point at the centre (instead of --intrinsics)")
    p.add_argument("--calibration", default=None, metavar="FILE[:ID]",
                   help="camera calibration of the input images (instead of --intrinsics) "
                        "from a COLMAP cameras.txt (PINHOLE, SIMPLE_PINHOLE, OPENCV, "
                        "FULL_OPENCV, SIMPLE_RADIAL, RADIAL), an ORB-SLAM2/3 settings YAML or "
                        "a Kalibr camchain YAML: its distortion is removed from the images, "
                        "its image size must be theirs; FILE:ID picks one camera of a file "
                        "holding several")


def add_vo_cli(subparsers) -> argparse.ArgumentParser:
    """Register ``spgeo vo`` on an argparse sub-parser collection."""
    p = subparsers.add_parser(
        "vo", help="monocular visual odometry on a data set -> trajectory, keyframes, ATE",
        description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", nargs=2, metavar=("KIND", "PATH"), required=True,
                   help=f"data-set kind ({', '.join(DATASET_KINDS)}) and sequence folder, "
                        "video file or camera index")
    p.add_argument("--frames", default=None, metavar="A:B[:STEP]",
                   help="frame numbers A <= n < B, every STEP-th (default: all; a camera "
                        "stops at B)")
    _add_camera_arguments(p)
    p.add_argument("--depth-scale", default=None, metavar="UNITS_PER_METRE", help=_DEPTH_SCALE)
    p.add_argument("--image-dir", default=None, metavar="NAME",
                   help="kitti: the image folder, i.e. the camera (image_0 ... image_3, image_l, "
                        "image_r; default the first of image_0, image_2, image_l present)")
    p.add_argument("--resolution", default=None, metavar="WxH",
                   help="processing resolution (default: the input's aspect ratio at about "
                        "320x240 = 76800 pixels, width and height multiples of 8; a 4:3 "
                        "input gives 320x240)")
    p.add_argument("--strict", action="store_true",
                   help="stop (exit code 2) at a frame whose file cannot be read; by "
                        "default it is skipped, marked 'skipped' and counted in report.json")
    p.add_argument("--frontend", default=None, choices=FRONTENDS,
                   help="classical (default, monocular), manhattan (monocular), onnx and "
                        "onnx-depth (need `spgeo models fetch`) or depth (reads the sensor "
                        "depth: RGB-D / oracle)")
    add_model_arguments(p)
    p.add_argument("--metric-scale", default=None, metavar="NAME|PATH",
                   help="write the outputs in metres: one global scale estimated after the "
                        "run from a metric-depth network against the keyframes' depths "
                        "(median over keyframes of the per-keyframe median ratio; an output "
                        "scale, never used by the VO); a model name (`spgeo models register "
                        "NAME PATH --preset fastdepth`) or an .onnx path (fastdepth preset). "
                        "Estimate and spread under \"metric_scale\" in report.json")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_rerun_argument(p, "the frames, keyframe clouds and trajectories live")
    _add_output_arguments(p)
    add_config_arguments(p, "VORunConfig / OdometryConfig", _default_run_config)
    p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="more logging (-v, -vv; also accepted before 'vo')")
    p.set_defaults(func=_run)
    return p
